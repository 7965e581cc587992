"""Scalar-equation families: ``Control_Diff`` states and implicit / user ``Reference_Variable``s.

Each instance owns one scalar unknown ``s`` (``State.extra[scols[:, 0]]``) and contributes its
residual row ``rho_s[:, 0] = e(s, other scalars, y, t)``; it applies no force to bodies
(``rho = 0``). The tangent has the row blocks ``G_sy = de/dy`` (chained to body coordinates by
the kernel's B matrices) and ``G_ss = de/ds`` (own and other scalar columns). The *columns* of a
scalar (its effect on forces) come from the families that read it (expression forces).

The equation of each kind and the marker layout: :class:`ScalarEquation`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.deck.spec import Expr
from poise.elements.base import ForceFamily, column_map, columns_array
from poise.elements.registry import (ElementType, OutputGroup, batch_time_sources,
                                     not_conservative)
from poise.elements.resolver import compile_batch_located, held, is_user, scalar_unknown
from poise.elements.user import compile_user_variables


@dataclass(frozen=True, eq=False, kw_only=True)
class ScalarEquation(ForceFamily):
    """Residual rows of scalar unknowns from one expression batch (see module doc).

    * ``Control_Diff`` explicit ``y' = expr``: statics ``y' = 0`` so ``e = expr(y, q, t)``;
      implicit ``0 = expr(y, y', q, t)``: ``e = expr`` with ``DIF1 = 0``.
    * implicit ``Reference_Variable``: ``e = expr(v, q, t)`` (deck_format 6.1: the expression is the
      residual; ``VARVAL(id)`` returns ``v``).
    * ``ScalarEquation`` evaluates one expression :class:`poise.expr.Batch` over all instances;
      :class:`UserScalarEquation` (families/user.py) evaluates a Python user function
      ``e = v - varsub(...)``.

    Marker layout: ``[E_1, ..., E_X]``, the moving markers the expressions read (padding: the global
    frame, index 0, whose slots carry no coordinates); slots ``P x y z`` per marker.
    """

    batch: object                    # poise.expr.Batch
    slot_map: tuple                  # (rows, batch_slot, family_slot)
    sc_map: tuple                    # (rows, batch_col, family_col)

    def forces(self, kin, ctx, need_jac=True):
        n, S, U = self.n, len(self.slot_ml), self.U
        out = self.batch.evaluate(ctx)
        rho = np.zeros((n, 3 * S))
        rs = np.zeros((n, U))
        rs[:, 0] = out.value
        ext = {"rho_s": rs}
        if not need_jac:
            return rho, None, ext
        gy = np.zeros((n, S, 3))
        r, bs, fs = self.slot_map
        if len(r):
            gy[r, fs] = out.d_slot[r, bs]
        G_sy = np.zeros((n, U, 3 * S))
        G_sy[:, 0, :] = gy.reshape(n, 3 * S)
        G_ss = np.zeros((n, U, U))
        r, bc, fc = self.sc_map
        if len(r):
            np.add.at(G_ss, (r, np.zeros_like(r), fc), out.d_scalar[r, bc])
        ext["G_sy"] = G_sy
        ext["G_ss"] = G_ss
        return rho, None, ext


def layout(batch, own, ground, first=None):
    """Markers (n, X), scols (n, U) and the slot / scalar maps of one batch.

    ``own`` (n,) the scalar unknown each instance owns (column 0 of ``scols``; None: none);
    ``ground`` (nm,) bool marks markers without coordinates (their slots are dropped); ``first``
    (n,) a marker each instance puts first (marker 0), read or not.
    """
    n = batch.n
    mk = [dict() if first is None else {int(first[i]): 0} for i in range(n)]
    sc = [dict() if own is None else {int(own[i]): 0} for i in range(n)]
    rows, bs, fs = [], [], []
    for i in range(n):
        for s, (m, kind) in enumerate(zip(batch.slot_marker[i], batch.slot_kind[i])):
            m, kind = int(m), int(kind)
            if m < 0 or ground[m]:
                continue
            if m not in mk[i]:
                mk[i][m] = len(mk[i])
            rows.append(i)
            bs.append(s)
            fs.append(4 * mk[i][m] + kind)
    smap = column_map(batch.scalar_index, sc)
    markers = columns_array(mk, width=max(1, max(len(d) for d in mk)), fill=0)
    scols = columns_array(sc)
    ip = np.intp
    return markers, scols, (np.array(rows, ip), np.array(bs, ip), np.array(fs, ip)), smap


def build_scalar_equations(batch, own, ground, owner, locs, name="control:ScalarEquation"):
    markers, scols, smap, cmap = layout(batch, own, ground)
    n, X = markers.shape
    return ScalarEquation(name=name, markers=markers, slot_ml=np.repeat(np.arange(X), 4),
                          slot_kind=np.tile(np.tile([0, 1, 2, 3], X), (n, 1)),
                          owner=np.asarray(owner, int), scols=scols, batch=batch,
                          slot_map=smap, sc_map=cmap, element_locs=tuple(locs))


# ----------------------------------- compile
def compile_diff_vars(spec, ctx):
    """Element compiler (after the expression compiler): equations of the scalar unknowns.

    Statics (deck_format 6.5, 6.1):

    * ``Control_Diff`` (``type="EXPRESSION"``): unknown ``y`` seeded from ``ic``; equation
      ``expr(y, q, t) = 0`` (explicit ``y' = expr`` with ``y' = 0``) or ``expr(y, DIF1 = 0, q, t) = 0``
      (implicit). ``is_static_hold="TRUE"``: no unknown; ``DIF(id)`` is the constant ``ic`` (poise
      has no transient phase that could move a held state away from its initial value).
      ``DIF1(id)`` is 0 in statics.
    * implicit ``Reference_Variable``: unknown ``v`` seeded from ``ic`` (0), equation
      ``expr(v, q, t) = 0``; ``static_hold="TRUE"``: ``VARVAL(id)`` is the constant ``ic``.
    * ``Reference_Variable type="USERSUB"`` (Python VARSUB): unknown ``v`` with the equation
      ``v - varsub(...) = 0`` (families/user.py); ``static_hold``: constant ``ic``.

    Outputs: frame hook ``diffs/id`` (D,), ``diffs/value`` (F, D), ``variables/id`` (V,),
    ``variables/value`` (F, V) for every Control_Diff and every implicit / user variable (held ones
    report their constant).

    Compile ``Control_Diff`` and implicit / user ``Reference_Variable`` into scalar unknowns.

    Scalar unknowns are registered on demand (:func:`scalar_unknown`), either by the expression
    resolver when an expression reads ``DIF(id)`` / ``VARVAL(id)`` or by :func:`compile_diff_vars`
    (run after the expression compiler) for every remaining state, so expression forces compiled
    earlier already know their scalar columns.

    The static equations of each kind (deck_format 6.5, 6.1) and the outputs: :func:`compile_diff_vars`.
    """
    diffs = spec.elements("Control_Diff")
    vars_ = [e for e in spec.elements("Reference_Variable")
             if e.attrs.get("is_implicit") or is_user(e)]
    if not diffs and not vars_:
        return
    pc = ctx.pc
    res = ctx.resolver("Control_Diff / Reference_Variable expressions")
    ground = ctx.geometry.marker_on_ground
    items = []             # (el, unknown, expression) with expression equations
    user_items = []
    for el in diffs:
        if held(el):
            ctx.effect("Control_Diff:static_hold")
            continue
        if is_user(el):
            pc.error(el.loc, "Control_Diff with a user subroutine (DIFSUB) is not supported; "
                     "expected type=\"EXPRESSION\" with expr", "type")
            continue
        k = scalar_unknown(ctx, "diff", el.id)
        ex = el.attrs.get("expr")
        if ex is None:
            pc.error(el.loc, "Control_Diff needs expr", "expr")
            continue
        items.append((el, k, ex if isinstance(ex, Expr) else float(ex)))
        ctx.effect("Control_Diff:" + ("implicit" if el.attrs.get("is_implicit") else "explicit"))
    for el in vars_:
        if held(el):
            ctx.effect("Reference_Variable:static_hold")
            continue
        k = scalar_unknown(ctx, "var", el.id)
        if is_user(el):
            user_items.append((el, k))
            ctx.effect("Reference_Variable:USERSUB")
            continue
        ex = el.attrs.get("expr")
        if ex is None:
            pc.error(el.loc, "implicit Reference_Variable needs expr (its residual)", "expr")
            continue
        items.append((el, k, ex if isinstance(ex, Expr) else float(ex)))
        ctx.effect("Reference_Variable:implicit")
    if items:
        batch = compile_batch_located([it[2] for it in items], res, pc)
        if batch is not None:
            ctx.add_family(build_scalar_equations(
                batch, np.array([it[1] for it in items], int), ground, np.arange(len(items)),
                [it[0].loc for it in items]))
    if user_items:
        compile_user_variables(spec, ctx, user_items)
    ctx.add_frame_hook(_output_hook(ctx, diffs, spec.elements("Reference_Variable")))


def _output_hook(ctx, diffs, all_vars):
    vars_ = [e for e in all_vars if e.attrs.get("is_implicit") or is_user(e)]

    def spec_of(kind, els):
        ids = np.array([e.id for e in els], np.int64)
        return ids, tuple(scalar_unknown(ctx, kind, e.id) for e in els)

    return StateOutputs(*spec_of("diff", diffs), *spec_of("var", vars_))


@dataclass(frozen=True, eq=False)
class StateOutputs:
    """Frame hook: ``diffs/id|value`` and ``variables/id|value`` of every Control_Diff and
    implicit / user variable; ``*_src`` per element its index into ``State.extra`` or
    ``("const", value)`` (held states)."""

    d_ids: np.ndarray
    d_src: tuple
    v_ids: np.ndarray
    v_src: tuple

    @staticmethod
    def _values(src, extra):
        return np.array([s[1] if isinstance(s, tuple) else float(extra[s]) for s in src], float)

    def __call__(self, model, state):
        out = {}
        if len(self.d_ids):
            out["diffs/id"] = self.d_ids
            out["diffs/value"] = self._values(self.d_src, state.extra)
        if len(self.v_ids):
            out["variables/id"] = self.v_ids
            out["variables/value"] = self._values(self.v_src, state.extra)
        return out


def _time_sources(fam) -> list:
    """``time_dependent``: the scalar equations reading TIME."""
    return batch_time_sources([fam.batch])


ELEMENTS = (ElementType(
    "diff_vars", ("Control_Diff", "Reference_Variable"), compile_diff_vars,
    rank=90,                    # after the scalar unknowns expression forces registered
    kernels=lambda: (ScalarEquation,),
    potential_energy=not_conservative,  # its rows are no force of a potential: energy NaN
    time_dependent=_time_sources,
    outputs=(OutputGroup("diffs", "Dd", "diff", "Control_Diff", "`Control_Diff`", ("Control_Diff",),
                         ("id", "label", "value"), model_ids=False),
             OutputGroup("variables", "V", "reference_variable", "variable",
                         "implicit and user (`USERSUB`) `Reference_Variable`",
                         ("Reference_Variable",), ("id", "label", "value"), model_ids=False)),
    fd_tests="tests/kernels/test_extra_unknowns.py"),)
