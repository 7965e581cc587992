"""General constraints: ``Constraint_General`` (Adams ``GCON``), an expression held at zero.

``<Constraint_General id= expr="DM(1,2) - 100" [i_marker_id=M]/>``: one row ``e(y, s, t) = 0``
per element, ``e`` any expression of the language (markers, scalar unknowns, TIME). The row's
gradient comes from the expression's exact forward mode and the multiplier-weighted Hessian
``lam d2e/dy2`` from its exact second-order evaluation (:mod:`poise.expr.hessian`), so the Newton
matrix is complete. Expressions reading element forces (``JOINT``, ``FX``, ...) or IMPACT/BISTOP
are refused (located): they have no second derivatives here, and a constraint on its own
reaction is not a static problem. An expression that reads no marker or state (velocity
measures are 0 at rest) constrains nothing in statics: it is left out with a warning.

Reactions: output group ``gcons``; ``i_marker_id`` names the reaction marker (MotionSolve: the
marker that extracts the reaction force): the row's load on that marker's body, reduced to its
origin (a ground marker: minus the load on the moving bodies, as Adams reports it). Without
``i_marker_id`` MotionSolve gives no reaction: force and torque are NaN.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.deck.spec import Expr
from poise.elements.base import GLOBAL, ConstraintFamily
from poise.elements.kernel import cross3
from poise.elements.diff_vars import layout
from poise.elements.registry import ElementType, OutputGroup, expressions_of_time, workless
from poise.elements.resolver import compile_batch_located

TAG = "Constraint_General"


@dataclass(frozen=True, eq=False, kw_only=True)
class GeneralConstraint(ConstraintFamily):
    """``e = 0`` for one expression batch. Marker layout per instance ``[I, E_1, ..., E_X]``:
    the reaction marker (the global frame when absent) then the moving markers the expression
    reads; slots ``P x y z`` per marker; scalar columns ``scols`` for the scalar unknowns.
    ``yy``, ``ys``, ``ss``: index pairs moving the batch Hessian into ``G``, ``G_ys``, ``G_ss``
    (:func:`hessian_pairs`); ``has_i`` (n,) the element names a reaction marker, ``i_ground``
    (n,) that marker is on ground, ``on_i_body`` (n, S) the slot's marker is on that marker's
    body."""

    batch: object                    # poise.expr.Batch
    slot_map: tuple                  # (rows, batch slot, family slot)
    sc_map: tuple                    # (rows, batch column, family column)
    yy: tuple
    ys: tuple
    ss: tuple
    has_i: np.ndarray
    i_ground: np.ndarray
    on_i_body: np.ndarray

    @property
    def batches(self) -> tuple:
        """The expression batches (``registry.expressions_of_time``)."""
        return (self.batch,)

    def values(self, kin, ctx):
        return self.batch.evaluate(ctx).value[:, None]

    def phi_t(self, kin, ctx):
        if not self.batch.depends_on_time:
            return None
        return self.batch.evaluate(ctx).d_time[:, None]

    def constraints(self, kin, lam, ctx):
        n, S, U = self.n, len(self.slot_ml), self.U
        out = self.batch.evaluate(ctx)
        H = self.batch.hessian(ctx)
        r, bs, fs = self.slot_map
        gy = np.zeros((n, S, 3))
        gy[r, fs] = out.d_slot[r, bs]
        phi_y = gy.reshape(n, 1, 3 * S)
        # Hessian: batch variables (3 batch slot + c, 3 S_b + batch column) -> family ones,
        # through the index pairs fixed at compile time (_pairs)
        lam0 = lam[:, 0]
        Hl = H * lam0[:, None, None]
        G = np.zeros((n, 3 * S, 3 * S))
        i, sa, sb, da, db = self.yy
        G[i, da, db] = Hl[i, sa, sb]
        if not U:
            return out.value[:, None], phi_y, G
        phi_s = np.zeros((n, 1, U))
        cr, cb, cf = self.sc_map
        phi_s[cr, 0, cf] = out.d_scalar[cr, cb]
        Gys = np.zeros((n, 3 * S, U))
        Gss = np.zeros((n, U, U))
        i, sa, sb, da, db = self.ys
        Gys[i, da, db] = Hl[i, sa, sb]
        i, sa, sb, da, db = self.ss
        Gss[i, da, db] = Hl[i, sa, sb]
        return out.value[:, None], phi_y, G, {"phi_s": phi_s, "G_ys": Gys, "G_ss": Gss}

    def reaction_on_i(self, kin, rho):
        """Force and torque (n, 3) of the row on the reaction marker's body at its origin (slot
        0 is that marker's origin); NaN without a reaction marker. A reaction marker on ground
        (no coordinates) gets minus the row's load on the moving bodies (a measure between
        markers is unchanged by a rigid motion of everything, so the loads balance), as Adams
        reports a GCON whose I marker is on ground."""
        n, S = kin.Y.shape[0], len(self.slot_ml)
        reps = n // len(self.has_i)            # frames evaluated together: instances repeated
        on = np.tile(self.on_i_body, (reps, 1))
        on_ground = np.tile(self.i_ground, reps)
        on[on_ground] = ~on[on_ground]
        Y = kin.Y
        r3 = rho.reshape(n, S, 3)
        F = np.zeros((n, 3))
        T = np.zeros((n, 3))
        kind = np.tile(np.tile([0, 1, 2, 3], S // 4), (n, 1))
        for s in range(S):
            m = on[:, s]
            pt = m & (kind[:, s] == 0)
            ax = m & (kind[:, s] != 0)
            F[pt] -= r3[pt, s]
            T[pt] -= cross3(Y[pt, s] - Y[pt, 0], r3[pt, s])
            T[ax] -= cross3(Y[ax, s], r3[ax, s])
        F[on_ground] *= -1.0
        T[on_ground] *= -1.0
        none = np.tile(~self.has_i, reps)
        F[none] = np.nan
        T[none] = np.nan
        return F, T


def compile_general(spec, ctx):
    els = spec.elements(TAG)
    if not els:
        return
    pc = ctx.pc
    res = ctx.resolver("Constraint_General expressions")
    keep, exprs = [], []
    for el in els:
        a = el.attrs
        if str(a.get("type", "EXPRESSION")).upper() == "USERSUB" or any(
                a.get(k) for k in ("usrsub_dll_name", "script_name", "usrsub_fnc_name")):
            pc.error(el.loc, "user-subroutine general constraints (GCOSUB) are not supported; "
                     "expected type=\"EXPRESSION\" with expr", "type")
            continue
        ex = a.get("expr")
        if ex is None:
            pc.error(el.loc, "Constraint_General needs expr (the expression held at zero)",
                     "expr")
            continue
        keep.append(el)
        exprs.append(ex if isinstance(ex, Expr) else float(ex))
    if not keep:
        return
    batch = compile_batch_located(exprs, res, pc)
    if batch is None:
        return
    from poise.expr.hessian import NoHessian, build_hessian   # lazy: only decks with GCONs
    ok = np.ones(len(keep), bool)
    for g in batch.groups:
        try:
            build_hessian(g.key, g.S, g.U)
        except NoHessian as e:
            for i in np.arange(len(keep))[g.rows]:
                ok[i] = False
                pc.error(keep[i].loc, f"{e} in a Constraint_General expression: not supported "
                         "(a constraint needs second derivatives; element forces and IMPACT/"
                         "BISTOP have none here)", "expr")
    for i in np.flatnonzero(ok & ~batch.state_mask):
        ok[i] = False
        pc.warn(keep[i].loc, "Constraint_General expression reads no marker or state "
                "(velocity measures are 0 at rest): it constrains nothing in statics and is "
                "left out", "expr")
    if not ok.all():
        sel = np.flatnonzero(ok)
        keep = [keep[i] for i in sel]
        if not keep:
            return
        batch = compile_batch_located([exprs[i] for i in sel], res, pc)
        if batch is None:
            return
    _build(ctx, keep, batch.with_second_order(), ctx.geometry.marker_on_ground)


def _build(ctx, els, batch, ground):
    n = len(els)
    first = np.array([ctx.marker(el, "i_marker_id") if el.attrs.get("i_marker_id") is not None
                      else GLOBAL for el in els], int)
    markers, scols, smap, cmap = layout(batch, None, ground, first)
    K = markers.shape[1]
    yy, ys, ss = hessian_pairs(batch, smap, cmap, n)
    has_i = np.array([el.attrs.get("i_marker_id") is not None for el in els])
    body = _marker_bodies(ctx)
    on_i_body = np.array([[has_i[i] and body.get(int(m), -1) == body.get(int(first[i]), -2)
                           for m in np.repeat(markers[i], 4)] for i in range(n)], bool)
    crow = np.array([[ctx.add_row(el, "expr", "trans", "gcons", k)]
                     for k, el in enumerate(els)], int)
    ctx.add_family(GeneralConstraint(
        name="gcons:expression", markers=markers, slot_ml=np.repeat(np.arange(K), 4),
        slot_kind=np.tile(np.tile([0, 1, 2, 3], K), (n, 1)), owner=np.arange(n), m=1,
        scols=scols if scols.shape[1] else None, batch=batch, slot_map=smap, sc_map=cmap,
        yy=yy, ys=ys, ss=ss, has_i=has_i, i_ground=has_i & ground[first], on_i_body=on_i_body,
        crow=crow, group="gcons",
        element_locs=tuple(el.loc for el in els)))
    ctx.output("gcons", TAG, [el.id for el in els])
    ctx.effect(f"{TAG}:EXPRESSION")


def hessian_pairs(batch, smap, cmap, n):
    """Index arrays ``(instance, batch row, batch column, family row, family column)`` that move
    the batch Hessian's slot-slot, slot-scalar and scalar-scalar entries into the family's
    ``G``, ``G_ys`` and ``G_ss`` (compile time)."""
    r, bs, fs = smap
    cr, cb, cf = cmap
    y_src = [np.concatenate([3 * bs[r == i, None] + np.arange(3)]).ravel() for i in range(n)]
    y_dst = [np.concatenate([3 * fs[r == i, None] + np.arange(3)]).ravel() for i in range(n)]
    s_src = [3 * batch.S + cb[cr == i] for i in range(n)]
    s_dst = [cf[cr == i] for i in range(n)]

    def cross(a_src, a_dst, b_src, b_dst):
        out = [[], [], [], [], []]
        for i in range(n):
            A, B = np.meshgrid(np.arange(len(a_src[i])), np.arange(len(b_src[i])),
                               indexing="ij")
            A, B = A.ravel(), B.ravel()
            for k, v in enumerate((np.full(len(A), i), a_src[i][A], b_src[i][B], a_dst[i][A],
                                   b_dst[i][B])):
                out[k].append(v)
        return tuple(np.concatenate(x).astype(np.intp) if x else np.zeros(0, np.intp)
                     for x in out)
    return (cross(y_src, y_dst, y_src, y_dst), cross(y_src, y_dst, s_src, s_dst),
            cross(s_src, s_dst, s_src, s_dst))


def _marker_bodies(ctx):
    """Compiled marker index -> body id (ground markers share the ground's id)."""
    g = ctx.geometry
    return {g.marker_index[e.attrs.get("id")]: e.attrs.get("body_id")
            for e in g.marker_elements if e.attrs.get("id") in g.marker_index}


ELEMENTS = (ElementType(
    "gcons", (TAG,), compile_general,
    rank=120,                             # rows after the joints', unknowns after the states'
    kernels=lambda: (GeneralConstraint,), potential_energy=workless,
    time_dependent=expressions_of_time,
    outputs=(OutputGroup("gcons", "Gc", "gcon", "general constraint",
                         "`Constraint_General`", (TAG,),
                         load="the constraint's load on the body of its `i_marker_id`, reduced "
                         "to that marker's origin, global axes; NaN when the element names no "
                         "`i_marker_id` (MotionSolve gives no reaction then)"),),
    fd_tests="tests/reference/test_general_constraint.py"),)
