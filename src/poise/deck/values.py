"""Attribute values: deck text -> typed values per the schema kind (numbers, enums, expressions).

One place for the number syntax of a deck (Fortran/C notation: ``1.E-3``, ``1.5D0``) and for
the column-wise typing the element builder uses on batches (one float()/int() map per column
where every value is a plain number). A value that cannot be typed stays the raw string, which
validation reports.
"""
from __future__ import annotations

import re
from typing import Any

from poise.deck.schema import ENUM_ALIASES
from poise.deck.schema_types import Attr
from poise.deck.spec import Expr
from poise.core.errors import SourceLoc

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eEdD][+-]?\d+)?$")
_TRUE = {"TRUE", "YES", "1", "T", "ON"}
_FALSE = {"FALSE", "NO", "0", "F", "OFF"}


_PLAIN = frozenset("0123456789.+-eE")


def parse_number(text: str) -> float | None:
    """Plain number in Fortran/C notation (``1.E-3``, ``1.5D0``, ``-9810.``) or None."""
    t = text.strip()
    # fast path: over these characters float() accepts exactly what _NUMBER accepts
    if t and _PLAIN.issuperset(t):
        try:
            return float(t)
        except ValueError:
            return None
    if not _NUMBER.match(t):
        return None
    return float(t.replace("d", "e").replace("D", "e"))


def parse_int(text: str) -> int | None:
    v = parse_number(text)
    if v is None or not abs(v) < 2.0 ** 63 or v != int(v):   # NaN, inf, beyond int64: invalid
        return None
    return int(v)


def coerce(attr: Attr, raw: str, loc: SourceLoc) -> Any:
    """Type one attribute value per its schema kind.

    Parameters
    ----------
    attr : Attr
        Schema of the attribute.
    raw : str
        Text as written in the deck.
    loc : SourceLoc
        Location of the owning element (for :class:`Expr`).

    Returns
    -------
    Any
        The typed value, or the raw string when it cannot be typed (validation reports it).
    """
    k = attr.kind
    text = raw.strip()
    if k == "real":
        v = parse_number(text)
        return raw if v is None else v
    if k == "int":
        v = parse_int(text)
        return raw if v is None else v
    if k == "bool":
        u = text.upper()
        return True if u in _TRUE else False if u in _FALSE else raw
    if k == "enum":
        u = " ".join(text.upper().split())
        return ENUM_ALIASES.get(u, u)
    if k == "str":
        return raw
    if k == "real_or_expr":
        if not text:
            return raw
        v = parse_number(text)
        return Expr(text, loc, attr.name) if v is None else v
    if k == "expr":
        return Expr(text, loc, attr.name)
    if k in ("int_list", "real_list"):
        parts = [p for p in re.split(r"[\s,]+", text) if p]
        conv = parse_int if k == "int_list" else parse_number
        vals = [conv(p) for p in parts]
        return raw if any(v is None for v in vals) else tuple(vals)
    raise ValueError(f"unknown attribute kind {k!r}")  # schema bug, not a deck problem


_PLAIN_BYTES = b"0123456789.+-eE"


def _shared(col: list, conv) -> list:
    """``conv`` of every value, one object per distinct text: a big deck repeats its zeros,
    ones and ids thousands of times (the parsed deck is held while the model compiles)."""
    memo = dict.fromkeys(col)
    if len(memo) == len(col):
        return list(map(conv, col))
    for k in memo:
        memo[k] = conv(k)
    return list(map(memo.__getitem__, col))


def reals(col: list) -> list:
    """``parse_number`` of every value (the raw string where it is not a number)."""
    try:
        j = "".join(col)
        # over these characters float() accepts exactly what parse_number accepts
        if j.isascii() and not j.encode("ascii").translate(None, _PLAIN_BYTES):
            return _shared(col, float)
    except ValueError:
        pass
    out = []
    for v in col:
        x = parse_number(v)
        out.append(v if x is None else x)
    return out


def ints(col: list, keep_raw: bool = True) -> list:
    """``parse_int`` of every value (the raw string, or None without ``keep_raw``, where it is
    not an integer). Plain digit strings of up to 15 digits (exact in a float) go through int()."""
    j = "".join(col)
    if j.isascii() and j.isdigit() and all(col) and max(map(len, col)) <= 15:
        return _shared(col, int)
    out = []
    for v in col:
        x = parse_int(v)
        out.append(v if x is None and keep_raw else x)
    return out
