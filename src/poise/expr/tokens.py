"""Tokenizer for the MotionSolve expression language.

Numbers follow Fortran/C notation (``1.``, ``.5``, ``1.E-3``, ``1.5D0``, ``2e3``). A number
immediately followed by ``D``/``d`` that is *not* the start of an exponent (``D`` followed by
digits, or a sign and digits) and not followed by a letter, digit or underscore is a value in
degrees and is converted to radians (``180D`` -> pi, ``10D*TIME``).
"""
from __future__ import annotations

import math
import re
from typing import NamedTuple

__all__ = ["Token", "tokenize", "ExprSyntaxError", "make_template"]


class ExprSyntaxError(Exception):
    """A syntax error inside one expression text.

    Attributes
    ----------
    message : str
        Human readable message (e.g. ``"expected ')'"``).
    col : int
        1-based column inside the expression text (``len(text) + 1`` means "at the end").
    """

    def __init__(self, message: str, col: int):
        self.message = message
        self.col = col
        super().__init__(f"col {col}: {message}")


class Token(NamedTuple):
    """One token.

    Attributes
    ----------
    kind : str
        ``"num"``, ``"ident"``, ``"op"`` or ``"eof"``.
    text : str
        Source text (identifiers upper-cased).
    value : float
        Numeric value for ``num`` tokens (radians when a degree suffix was given).
    col : int
        1-based column of the first character.
    """

    kind: str
    text: str
    value: float
    col: int


_TOKEN_RE = re.compile(
    r"(?P<ws>\s+)"
    r"|(?P<num>(?:\d+\.?\d*|\.\d+)(?:[EeDd][+-]?\d+)?)"
    r"|(?P<ident>[A-Za-z_][A-Za-z0-9_]*)"
    r"|(?P<op>\*\*|[-+*/(),:])"
    r"|(?P<param>\#)"
    r"|(?P<bad>.)",
    re.S,
)
_DEG = math.pi / 180.0


def _range_message(num: str) -> str:
    return f"number {num} is out of range (the largest finite double is about 1.8e308)"


def tokenize(text: str, template: bool = False) -> list[Token]:
    """Split ``text`` into tokens (whitespace dropped) ending with an ``eof`` token.

    With ``template=True`` each ``#`` is a parameter token (see :func:`make_template`);
    otherwise ``#`` is an invalid character.

    Raises
    ------
    ExprSyntaxError
        On a character that cannot start a token, or a number that overflows a double.
    """
    toks: list[Token] = []
    append = toks.append
    n = len(text)
    skip = 0
    n_param = 0
    for m in _TOKEN_RE.finditer(text):
        kind = m.lastgroup
        if kind == "ws":
            continue
        pos = m.start()
        if pos < skip:               # consumed as a degree suffix
            continue
        if kind == "ident":
            append(Token("ident", m.group().upper(), 0.0, pos + 1))
        elif kind == "op":
            append(Token("op", m.group(), 0.0, pos + 1))
        elif kind == "num":
            s = m.group()
            end = m.end()
            value = float(s.replace("D", "E").replace("d", "e")) if ("D" in s or "d" in s) \
                else float(s)
            if end < n and text[end] in "Dd":
                nxt = text[end + 1] if end + 1 < n else ""
                if not (nxt.isalnum() or nxt == "_"):
                    value *= _DEG
                    end += 1
                    skip = end
            if not math.isfinite(value):
                raise ExprSyntaxError(_range_message(text[pos:end]), pos + 1)
            append(Token("num", text[pos:end], value, pos + 1))
        elif kind == "param" and template:
            append(Token("param", "#", float(n_param), pos + 1))
            n_param += 1
        else:
            raise ExprSyntaxError(f"invalid character {m.group()!r}", pos + 1)
    toks.append(Token("eof", "", 0.0, n + 1))
    return toks


_NUM_RE = re.compile(r"(?<![A-Za-z0-9_.#])((?:\d+\.?\d*|\.\d+)(?:[EeDd][+-]?\d+)?)"
                     r"([Dd](?![A-Za-z0-9_]))?")


def make_template(text: str) -> tuple[str, list[float]]:
    """Replace every number by ``#`` (a parameter token) and return the numbers.

    Structurally identical texts then share one cached parse. Columns in a template differ
    from the original text, so errors are always reported from a parse of the original.
    A number that overflows a double raises :class:`ExprSyntaxError` (as :func:`tokenize`).

    Returns
    -------
    template : str
    values : list of float
        Values of the numbers in order (radians for a degree suffix).
    """
    vals: list[float] = []
    add = vals.append

    def rep(m):
        s = m.group(1)
        v = float(s.replace("D", "E").replace("d", "e")) if ("D" in s or "d" in s) else float(s)
        v = v * _DEG if m.group(2) else v
        if not math.isfinite(v):
            raise ExprSyntaxError(_range_message(s), m.start() + 1)
        add(v)
        return "#"

    return _NUM_RE.sub(rep, text), vals
