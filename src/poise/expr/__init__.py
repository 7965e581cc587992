"""MotionSolve expression language: parser, function library and batch compiler.

See ``CONTRACT.md`` (interface) and ``README.md`` (language summary).
"""
from __future__ import annotations

from typing import Protocol

from .batch import Batch, EvalContext, EvalResult, compile_batch
from .parser import parse
from .tokens import ExprSyntaxError

__all__ = ["compile_batch", "Batch", "EvalContext", "EvalResult", "ExprSyntaxError", "Resolver",
           "parse"]


class Resolver(Protocol):
    """Model-side name resolution used by :func:`compile_batch` (see CONTRACT.md)."""

    def marker_index(self, id: int) -> int: ...

    def variable(self, id: int) -> tuple: ...

    def diff_state(self, id: int) -> int: ...

    def diff_derivative(self, id: int) -> int | None: ...

    def spline(self, id: int) -> tuple: ...

    def array(self, id: int): ...

    def reaction(self, kind: str, id: int, jflag: int, comp: int, rm: int) -> int: ...

    def angle_key(self, i_idx: int, j_idx: int, axis: int) -> int: ...
