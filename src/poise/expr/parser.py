"""Recursive-descent parser: expression text -> AST.

Grammar (lowest to highest precedence)::

    expr    := term (('+' | '-') term)*
    term    := unary (('*' | '/') unary)*
    unary   := ('-' | '+') unary | power
    power   := primary ('**' unary)?          # right associative; -2**2 == -4
    primary := NUM | NAME | NAME '(' args ')' | '(' expr ')'
    args    := expr (',' expr)*               # IF(e1: e2, e3, e4) uses a colon after e1
"""
from __future__ import annotations

from functools import lru_cache

from .ast import BinOp, Call, Name, Node, Num, Param, Unary
from .tokens import ExprSyntaxError, Token, tokenize

__all__ = ["parse", "ExprSyntaxError"]


def _describe(tok: Token) -> str:
    return "end of expression" if tok.kind == "eof" else repr(tok.text)


class _Parser:
    __slots__ = ("toks", "i")

    def __init__(self, toks: list[Token]):
        self.toks = toks
        self.i = 0

    def peek(self) -> Token:
        return self.toks[self.i]

    def expect(self, op: str) -> Token:
        t = self.toks[self.i]
        if t.kind != "op" or t.text != op:
            raise ExprSyntaxError(f"expected {op!r}", t.col)
        self.i += 1
        return t

    def expr(self) -> Node:
        left = self.term()
        while True:
            t = self.toks[self.i]
            if t.kind == "op" and (t.text == "+" or t.text == "-"):
                self.i += 1
                left = BinOp(t.text, left, self.term(), t.col)
            else:
                return left

    def term(self) -> Node:
        left = self.unary()
        while True:
            t = self.toks[self.i]
            if t.kind == "op" and (t.text == "*" or t.text == "/"):
                self.i += 1
                left = BinOp(t.text, left, self.unary(), t.col)
            else:
                return left

    def unary(self) -> Node:
        t = self.toks[self.i]
        if t.kind == "op" and (t.text == "-" or t.text == "+"):
            self.i += 1
            return Unary(t.text, self.unary(), t.col)
        return self.power()

    def power(self) -> Node:
        base = self.primary()
        t = self.toks[self.i]
        if t.kind == "op" and t.text == "**":
            self.i += 1
            return BinOp("**", base, self.unary(), t.col)
        return base

    def primary(self) -> Node:
        t = self.toks[self.i]
        if t.kind == "num":
            self.i += 1
            return Num(t.value, t.col)
        if t.kind == "param":
            self.i += 1
            return Param(int(t.value), t.col)
        if t.kind == "ident":
            self.i += 1
            nxt = self.toks[self.i]
            if nxt.kind == "op" and nxt.text == "(":
                self.i += 1
                return Call(t.text, self.args(t.text == "IF"), t.col)
            return Name(t.text, t.col)
        if t.kind == "op" and t.text == "(":
            self.i += 1
            e = self.expr()
            self.expect(")")
            return e
        raise ExprSyntaxError(f"expected an operand, found {_describe(t)}", t.col)

    def args(self, is_if: bool) -> tuple:
        t = self.toks[self.i]
        if t.kind == "op" and t.text == ")":
            self.i += 1
            return ()
        out = [self.expr()]
        if is_if:
            t = self.toks[self.i]
            if t.kind == "op" and t.text in (":", ","):
                self.i += 1
                out.append(self.expr())
            else:
                raise ExprSyntaxError("expected ':'", t.col)
        while True:
            t = self.toks[self.i]
            if t.kind == "op" and t.text == ",":
                self.i += 1
                out.append(self.expr())
            elif t.kind == "op" and t.text == ")":
                self.i += 1
                return tuple(out)
            else:
                raise ExprSyntaxError("expected ')'" if t.kind == "eof" or t.text != ":"
                                      else "unexpected ':' (only IF takes a colon)", t.col)


@lru_cache(maxsize=65536)
def parse(text: str, template: bool = False) -> Node:
    """Parse an expression text into an AST.

    Parameters
    ----------
    text : str
        Expression as written in the deck.
    template : bool
        Parse a template from :func:`poise.expr.tokens.make_template` (``#`` = parameter).

    Returns
    -------
    Node
        Root of the AST.

    Raises
    ------
    ExprSyntaxError
        With a message and the 1-based column of the problem.
    """
    toks = tokenize(text, template)
    if toks[0].kind == "eof":
        raise ExprSyntaxError("empty expression", 1)
    p = _Parser(toks)
    node = p.expr()
    t = p.peek()
    if t.kind != "eof":
        if t.kind == "op" and t.text == ")":
            raise ExprSyntaxError("unbalanced ')'", t.col)
        raise ExprSyntaxError(f"unexpected {_describe(t)}", t.col)
    return node
