"""Abstract syntax tree of an expression (plain immutable nodes with 1-based columns)."""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Node", "Num", "Param", "Name", "Unary", "BinOp", "Call"]


class Node:
    """Base class of all AST nodes. Every node has a 1-based ``col``."""

    __slots__ = ()


@dataclass(slots=True)
class Num(Node):
    """Numeric literal (already converted to radians when written with a ``D`` suffix)."""

    value: float
    col: int


@dataclass(slots=True)
class Param(Node):
    """Placeholder for the ``index``-th number of a template text (see ``make_template``)."""

    index: int
    col: int


@dataclass(slots=True)
class Name(Node):
    """Bare identifier (``TIME``, ``PI``, ``DTOR``, ``RTOD``), upper case."""

    name: str
    col: int


@dataclass(slots=True)
class Unary(Node):
    """Unary ``-``/``+``."""

    op: str
    arg: Node
    col: int


@dataclass(slots=True)
class BinOp(Node):
    """Binary operator ``+ - * / **`` (``col`` is the operator's column)."""

    op: str
    left: Node
    right: Node
    col: int


@dataclass(slots=True)
class Call(Node):
    """Function call ``NAME(args)``; ``IF(a: b, c, d)`` is ``Call("IF", (a, b, c, d))``."""

    name: str
    args: tuple
    col: int
