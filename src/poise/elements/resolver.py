"""The model-side resolver of ``poise.expr`` (see ``poise/expr/CONTRACT.md``) and scalar unknowns.

:class:`ModelResolver` maps deck ids to compiled indices: marker id -> compiled marker index
(id 0 -> index 0, the global frame), explicit ``Reference_Variable`` -> shared (DAG) expression,
``Reference_Spline`` / ``Reference_Array`` -> data parsed from the element text, ``AX/AY/AZ`` ->
the continuous-angle table, element-force functions (the registry's reaction kinds) and
resultants (FM, FX, ..., TZ) -> *reaction channels*. One resolver lives on the compile context
(:meth:`poise.elements.context.CompileContext.resolver`, one per use: where the expressions are
and whether they may read reactions); implicit and user ``Reference_Variable`` and
``Control_Diff`` states are scalar unknowns registered on demand (:func:`scalar_unknown`).
"""
from __future__ import annotations

import copy
import re

import numpy as np

from poise.core.errors import DeckError, Problem
from poise.deck.spec import Expr
from poise.elements.base import GLOBAL
from poise.elements.registry import reaction_kinds
from poise.expr import compile_batch

RESULTANTS = ("FM", "FX", "FY", "FZ", "TM", "TX", "TY", "TZ")

_SPLIT = re.compile(r"[\s,;]+")


def _numbers(el):
    txt = (el.text or "").strip()
    if not txt:
        return np.zeros(0)
    try:
        return np.array([float(t.replace("D", "E").replace("d", "e"))
                         for t in _SPLIT.split(txt) if t], float)
    except ValueError as e:
        raise DeckError(Problem(el.loc, f"element text is not a list of numbers ({e})")) from None


class ModelResolver:
    """Model-side resolver for :func:`poise.expr.compile_batch` (see ``poise/expr/CONTRACT.md``).

    ``allow_reactions`` False makes element-force functions a located DeckError (gravity,
    states, constraints); True registers reaction channels on the compile context (forces,
    requests). ``where`` names the expressions in messages. :meth:`use` gives the resolver of
    another use, sharing the parsed data.
    """

    def __init__(self, spec, ctx, where: str = "forces", allow_reactions: bool = False):
        self.spec = spec
        self.ctx = ctx
        self.allow_reactions = allow_reactions
        self.where = where
        self.vars = {e.id: e for e in spec.elements("Reference_Variable")}
        self.splines = {e.id: e for e in spec.elements("Reference_Spline")}
        self.arrays = {e.id: e for e in spec.elements("Reference_Array")}
        self._spline_cache: dict = {}

    def use(self, where: str, reactions: bool) -> "ModelResolver":
        """This resolver for expressions of ``where``, reading reactions or not."""
        if where == self.where and reactions == self.allow_reactions:
            return self
        r = copy.copy(self)
        r.where, r.allow_reactions = where, reactions
        return r

    @property
    def channels(self) -> tuple:
        """The reaction channels registered so far (on the compile context)."""
        return self.ctx.channels

    # ------------------------------------------------------------------ contract
    def marker_index(self, id: int) -> int:
        return self.ctx.geometry.marker_index[int(id)]   # 0 -> 0: the global frame; KeyError else

    def variable(self, id: int):
        el = self.vars[int(id)]
        if el.attrs.get("is_implicit") or \
                str(el.attrs.get("type", "EXPRESSION")).upper() == "USERSUB":
            # scalar unknown (elements/diff_vars.py); held: the constant ic
            k = scalar_unknown(self.ctx, "var", int(id))
            return ("explicit", k[1]) if isinstance(k, tuple) else ("implicit", k)
        return ("explicit", el.attrs.get("expr", 0.0))

    def diff_state(self, id: int):
        """Scalar index of Control_Diff ``id`` or ``("const", ic)`` when statically held."""
        return scalar_unknown(self.ctx, "diff", int(id))

    def diff_derivative(self, id: int):
        self.ctx.elements_by_id("Control_Diff")[int(id)]     # KeyError for unknown ids
        return None                                           # DIF1 = 0 in statics

    def spline(self, id: int):
        id = int(id)
        if id in self._spline_cache:
            return self._spline_cache[id]
        el = self.splines[id]
        v = _numbers(el)
        a = el.attrs
        lin = bool(a.get("linear_extrap", False))
        nx, nz = a.get("num_x"), a.get("num_z")
        if nz and nx and int(nz) > 1:
            nx, nz = int(nx), int(nz)
            if len(v) != nz + nx * (nz + 1):
                raise DeckError(Problem(el.loc, f"surface spline text has {len(v)} numbers; "
                                        f"expected num_z + num_x*(num_z+1) = "
                                        f"{nz + nx * (nz + 1)}"))
            z = v[:nz]
            rows = v[nz:].reshape(nx, nz + 1)
            out = (rows[:, 0], rows[:, 1:].T.copy(), z, lin)
        else:
            n = a.get("num_xy_pair")
            if len(v) % 2:
                raise DeckError(Problem(el.loc, f"spline text has {len(v)} numbers; expected "
                                        "x y pairs"))
            if n is not None and int(n) != len(v) // 2:
                raise DeckError(Problem(el.loc, f"num_xy_pair={n} but the text has "
                                        f"{len(v) // 2} x y pairs", "num_xy_pair"))
            xy = v.reshape(-1, 2)
            out = (xy[:, 0], xy[:, 1], None, lin)
        self._spline_cache[id] = out
        return out

    def array(self, id: int):
        el = self.arrays[int(id)]
        v = _numbers(el)
        n = el.attrs.get("num_element")
        if n is not None and int(n) != len(v):
            raise DeckError(Problem(el.loc, f"num_element={n} but the text has {len(v)} values",
                                    "num_element"))
        return v

    def plant_variables(self, tag: str, id: int) -> list:
        """Variable ids of a ``Control_PlantInput`` / ``Control_PlantOutput`` (PINVAL/POUVAL)."""
        el = self.ctx.element(tag, int(id))
        if el is None:
            raise KeyError(id)
        v = el.attrs.get("variable_id_list")
        v = [] if v is None else (list(v) if isinstance(v, (list, tuple)) else [v])
        return [int(x) for x in v]

    def reaction(self, kind: str, id: int, jflag: int, comp: int, rm: int) -> int:
        return self.ctx.register_channel(self._reaction_key(kind, id, jflag, comp, rm))

    def _reaction_key(self, kind: str, id: int, jflag: int, comp: int, rm: int) -> tuple:
        """The channel key of an element-force function or resultant (raises
        NotImplementedError or KeyError with the problem)."""
        kind = kind.upper()
        if not self.allow_reactions:
            raise NotImplementedError(
                f"{kind}() is not supported in {self.where} yet (reaction and element-force "
                "functions are available in Post_Request and force expressions)")
        if kind in RESULTANTS:
            if not 1 <= comp <= 8:
                raise NotImplementedError(f"{kind}: component {comp} outside 1..8")
            key = ("RES", self.marker_index(id), self.marker_index(jflag) if jflag else -1,
                   comp, self.marker_index(rm), int(jflag) != 0)
        elif kind in reaction_kinds():
            if not 1 <= comp <= 8:
                raise NotImplementedError(f"{kind}: component {comp} outside 1..8; expected "
                                          "1 |F|, 2-4 Fx Fy Fz, 5 |T|, 6-8 Tx Ty Tz")
            if jflag not in (0, 1):
                raise NotImplementedError(f"{kind}: jflag {jflag}; expected 0 or 1")
            group, tags = reaction_kinds()[kind]
            el = next((e for e in (self.ctx.element(t, id) for t in tags) if e is not None),
                      None)
            if el is None:
                raise KeyError(id)
            key = ("EL", group, el.tag, int(id), int(jflag), int(comp),
                   self.marker_index(rm))
        else:
            raise NotImplementedError(f"{kind}() is not supported yet")
        return key

    def angle_key(self, i_idx: int, j_idx: int, axis: int) -> int:
        return self.ctx.angle(int(i_idx) if i_idx >= 0 else GLOBAL,
                              int(j_idx) if j_idx >= 0 else GLOBAL, int(axis))

class CheckingResolver(ModelResolver):
    """A resolver that checks names and ids but registers nothing (no scalar unknown, angle or
    reaction channel): for expressions nothing evaluates, e.g. a variable no element reads."""

    def __init__(self, spec, ctx):
        super().__init__(spec, ctx, "variables", True)

    def variable(self, id: int):
        el = self.vars[int(id)]
        if el.attrs.get("is_implicit") or is_user(el):
            return ("implicit", 0)
        return ("explicit", el.attrs.get("expr", 0.0))

    def diff_state(self, id: int):
        self.ctx.elements_by_id("Control_Diff")[int(id)]      # KeyError for unknown ids
        return ("const", 0.0)

    def reaction(self, kind, id, jflag, comp, rm):
        self._reaction_key(kind, id, jflag, comp, rm)
        return 0

    def angle_key(self, i_idx, j_idx, axis):
        return 0


def check_variables(spec, ctx):
    """Every explicit ``Reference_Variable`` compiled once more, so that a problem in one that
    no element reads (an unknown function, a missing marker) is a located error like anywhere
    else; problems already reported are not repeated. Runs after every element compiler."""
    vs = [e for e in spec.elements("Reference_Variable")
          if not e.attrs.get("is_implicit") and not is_user(e)
          and isinstance(e.attrs.get("expr"), Expr)]
    if not vs:
        return
    from poise.expr.lower import Lowering       # lazy: names only, no evaluation program
    low = Lowering(CheckingResolver(spec, ctx))
    try:
        for e in vs:
            low.lower_expr(e.attrs["expr"])
        problems = low.var_problems + low.problems
    except DeckError as e:                        # malformed spline / array data
        problems = list(e.problems)
    pc = ctx.pc
    seen = {str(p) for p in pc.problems}
    for p in problems:
        if isinstance(p, Problem) and str(p) not in seen:
            seen.add(str(p))
            pc.problems.append(p)


def compile_batch_located(exprs, resolver, pc):
    """``compile_batch`` whose DeckError problems are added to the collector (None on error)."""
    try:
        return compile_batch(exprs, resolver)
    except DeckError as e:
        for p in e.problems:
            if isinstance(p, Problem):
                pc.problems.append(p)
            else:
                pc.error(exprs[0].loc if hasattr(exprs[0], "loc") else None, str(p))
        return None


def is_user(el) -> bool:
    return str(el.attrs.get("type", "EXPRESSION")).upper() == "USERSUB"


def held(el) -> bool:
    return bool(el.attrs.get("is_static_hold" if el.tag == "Control_Diff" else "static_hold"))


def scalar_unknown(ctx, kind: str, id: int):
    """Index into ``State.extra`` of the unknown of ``Control_Diff`` (kind ``"diff"``) or
    ``Reference_Variable`` (kind ``"var"``) ``id``, or ``("const", value)`` for held states.
    Raises KeyError for unknown ids."""
    tag = "Control_Diff" if kind == "diff" else "Reference_Variable"
    el = ctx.elements_by_id(tag)[int(id)]
    ic = float(el.attrs.get("ic", 0.0) or 0.0)
    if held(el):
        return ("const", ic)
    return ctx.scalar_unknown((kind, int(id)),
                              f"{el.loc.prefix()[:-1]} {'y' if kind == 'diff' else 'v'}", ic)
