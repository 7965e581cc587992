"""Recursive-descent parser: expression text -> AST.

Grammar (lowest to highest precedence)::

    expr    := term (('+' | '-') term)*
    term    := unary (('*' | '/') unary)*
    unary   := ('-' | '+') unary | power
    power   := primary ('**' unary)?          # right associative; -2**2 == -4
    primary := NUM | NAME | NAME '(' args ')' | '(' expr ')'
    args    := expr (',' expr)*               # IF(e1: e2, e3, e4) uses a colon after e1

Recursive calls are yielded to :func:`poise.expr.trampoline.run`, so any nesting depth
(parentheses, ``**`` chains, signs) parses without hitting the recursion limit; long ``+``/``*``
chains are loops.
"""
from __future__ import annotations

from functools import lru_cache

from .ast import BinOp, Call, Name, Node, Num, Param, Unary
from .tokens import ExprSyntaxError, Token, tokenize
from .trampoline import run

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

    def expr(self):
        """expr and term in one loop (generator; yields sub-parses)."""
        toks = self.toks
        total = None
        pend = None                   # pending '+'/'-' token
        term = yield self.unary()
        while True:
            t = toks[self.i]
            if t.kind == "op":
                op = t.text
                if op == "*" or op == "/":
                    self.i += 1
                    term = BinOp(op, term, (yield self.unary()), t.col)
                    continue
                total = term if pend is None else BinOp(pend.text, total, term, pend.col)
                if op == "+" or op == "-":
                    self.i += 1
                    pend = t
                    term = yield self.unary()
                    continue
                return total
            return term if pend is None else BinOp(pend.text, total, term, pend.col)

    def unary(self):
        """Signs, then power := primary ('**' unary)?."""
        toks = self.toks
        signs = []
        t = toks[self.i]
        while t.kind == "op" and (t.text == "-" or t.text == "+"):
            signs.append(t)
            self.i += 1
            t = toks[self.i]
        kind = t.kind
        if kind == "num":
            self.i += 1
            base = Num(t.value, t.col)
        elif kind == "param":
            self.i += 1
            base = Param(int(t.value), t.col)
        elif kind == "ident":
            self.i += 1
            nxt = toks[self.i]
            if nxt.kind == "op" and nxt.text == "(":
                self.i += 1
                base = Call(t.text, (yield self.args(t.text == "IF")), t.col)
            else:
                base = Name(t.text, t.col)
        elif kind == "op" and t.text == "(":
            self.i += 1
            base = yield self.expr()
            self.expect(")")
        else:
            raise ExprSyntaxError(f"expected an operand, found {_describe(t)}", t.col)
        t = toks[self.i]
        if t.kind == "op" and t.text == "**":
            self.i += 1
            base = BinOp("**", base, (yield self.unary()), t.col)
        for s in reversed(signs):
            base = Unary(s.text, base, s.col)
        return base

    def args(self, is_if: bool):
        t = self.toks[self.i]
        if t.kind == "op" and t.text == ")":
            self.i += 1
            return ()
        out = [(yield self.expr())]
        if is_if:
            t = self.toks[self.i]
            if t.kind == "op" and t.text in (":", ","):
                self.i += 1
                out.append((yield self.expr()))
            else:
                raise ExprSyntaxError("expected ':'", t.col)
        while True:
            t = self.toks[self.i]
            if t.kind == "op" and t.text == ",":
                self.i += 1
                out.append((yield self.expr()))
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
    node = run(p.expr())
    t = p.peek()
    if t.kind != "eof":
        if t.kind == "op" and t.text == ")":
            raise ExprSyntaxError("unbalanced ')'", t.col)
        raise ExprSyntaxError(f"unexpected {_describe(t)}", t.col)
    return node
