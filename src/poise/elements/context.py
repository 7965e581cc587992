"""What element compilers build on: the compile context, the global-frame index, numbers.

``compile(spec, ctx)`` of every registered element type (:mod:`poise.elements.registry`) adds
constraint rows, families, output groups and continuous angles to a :class:`CompileContext`;
``ctx.b`` is the model builder (markers, bodies, problem collector) of
:mod:`poise.model.compile`, reached through its methods only, so this package stays below
``poise.model``.
"""
from __future__ import annotations

from poise.deck.spec import Element, Expr
from poise.elements.base import GLOBAL
from poise.elements.resolver import ModelResolver
from poise.core.errors import ProblemCollector

__all__ = ["GLOBAL", "CompileContext", "num"]



def num(el: Element, name: str, default=None, pc: ProblemCollector | None = None):
    v = el.attrs.get(name, default)
    if isinstance(v, Expr):
        if pc is not None:
            pc.error(el.loc, f"expression {v.text!r} is not supported here yet; expected a number",
                     name)
        return default if default is not None else 0.0
    return v


class CompileContext:
    """What element compilers add to: constraint rows, families, output groups, angles.

    Element compilers are the ``compile(spec, ctx)`` of the registered element types, run in
    dependency order; each only runs work for elements present in the deck.
    """

    def __init__(self, builder):
        self.b = builder
        self.pc = builder.pc
        self.rows: list[dict] = []
        self.families: list = []
        self.outputs: dict = {}
        self.angles: list[tuple[int, int, int]] = []
        self.extra_names: list[str] = []
        self.extra0: list[float] = []
        self.expr_forces: list = []      # (owner, el) of expression forces (compile_expr)
        self.user_forces: list = []      # (force row, el) of Python user forces (elements.user)
        self.frame_hooks: list = []      # per-frame output hooks (requests, ...)
        self._resolver = None

    def resolver(self) -> ModelResolver:
        """The expression resolver of this model (``poise/expr/CONTRACT.md``), one for all
        element compilers so scalar unknowns and reaction channels are registered once."""
        if self._resolver is None:
            self._resolver = ModelResolver(self.b.spec, self)
        return self._resolver

    def body_centres(self):
        """Compiled CG marker index (nb,) and effective mass (nb,) of the moving bodies."""
        return self.b.body_centres()

    def angle(self, I: int, J: int, axis: int) -> int:
        """Register a continuous angle of marker I about marker J's axis (0 x, 1 y, 2 z)."""
        self.angles.append((I, J, axis))
        return len(self.angles) - 1

    def marker(self, el, attr, required=True) -> int:
        return self.b.mk(el, attr, required)

    def effect(self, name: str) -> None:
        self.b.effects.append(name)

    def add_row(self, el, equation: str, kind: str, group: str, owner: int) -> int:
        self.rows.append(_row(el, equation, kind, group, owner))
        return len(self.rows) - 1

    def add_extra(self, name: str, initial: float = 0.0) -> int:
        """Register a scalar unknown (appended after the bodies' coordinates); returns its index
        into ``State.extra``. ``name`` labels it in messages (e.g. ``"<Control_Diff id=3> y"``).
        Families read it through ``Family.scols``."""
        self.extra_names.append(name)
        self.extra0.append(float(initial))
        return len(self.extra_names) - 1


def row_where(ri: dict) -> str:
    """``FILE:LINE: <Tag id=N>`` (or ``FILE:LINE: JOINT/3`` for an Adams dataset) of a
    constraint row's element."""
    w = ri.get("where")
    return w if w else f"{ri['file']}:{ri['line']}: <{ri['tag']} id={ri['id']}>"


def _row(el: Element, equation: str, kind: str, group: str, owner: int) -> dict:
    return dict(tag=el.tag, id=el.id, equation=equation, line=el.loc.line, file=el.loc.file,
                kind=kind, group=group, owner=owner, label=str(el.attrs.get("label") or ""),
                where=el.loc.prefix()[:-1])
