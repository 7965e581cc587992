"""Force families whose magnitudes/components are deck expressions (exact derivatives).

Expressions are evaluated at ``EvalContext.t`` (so quasi-static time drives them) and read the
marker kinematics ``EvalContext.P/A`` and continuous angles ``EvalContext.angle``.

Marker and slot layout, and the force laws of vector and scalar forces: :class:`ExprForce`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from poise.core.errors import EvaluationError
from poise.elements.base import ForceFamily, column_map, columns_array
from poise.elements.forces import N_SLOTS, S_PI, apply_two_body, S_PJ, S_XR, S_YR
from poise.elements.forces import S_ZJ, S_ZR, SLOT_KIND, SLOT_ML
from poise.elements.resolver import compile_batch_located

_I3 = np.eye(3)
VEC_ATTRS = ("fx", "fy", "fz", "tx", "ty", "tz")
ST_LINE, ST_AXIS, ST_TORQUE = 0, 1, 2


def sl(s):
    return slice(3 * s, 3 * s + 3)


@dataclass(frozen=True, eq=False, kw_only=True)
class ExprForce(ForceFamily):
    """Common part: expression batches, slot maps, evaluation of values and slot gradients.

    Marker layout per instance: ``[I, J, R, E_1, ..., E_X]`` where ``E_*`` are the further moving
    markers the instance's expressions read. Slots: the 11 two-body slots of ``forces.py``
    (``P_I x_I y_I z_I P_J x_J y_J z_J x_R y_R z_R``) followed by 4 slots (``P x y z``) per extra
    marker. A slot the expressions read on I or J reuses the standard slot; slots of ground markers
    (and of the global frame) are dropped because they carry no coordinates. Padding markers are the
    global frame (index 0).

    Each expression attribute is one :class:`poise.expr.Batch` over all instances of the family; its
    ``d_slot (n, S_e, 3)`` is scattered into the family's slot gradient ``(n, 3S)`` through a map
    fixed at compile time, then chained through the force law:

    * vector forces (``Force_Vector_OneBody/TwoBody`` with any ``*_expression`` not a number):
      ``F = A_R c_F``, ``T = A_R c_T`` (components along R's axes), applied at I; TwoBody reaction on
      the floating marker's body (``-F`` at ``P_J`` plus ``-T - (P_I - P_J) x F``), OneBody
      action-only;
    * scalar forces (``Force_Scalar_TwoBody val_expression``): FORCE two-body ``F = f u`` with ``u``
      the unit vector J->I (positive repels); FORCE action-only ``F = f z_J``; TORQUE ``T = tau z_J``
      (action-only when ``is_action_only``).
    """

    action_only: np.ndarray
    batches: tuple
    slot_maps: tuple                 # per batch: (rows, batch_slot, family_slot) index arrays
    scalar_maps: tuple | None = None     # per batch: (rows, batch_col, family_col) of scols
    reaction_maps: tuple | None = None   # per batch: (rows, batch_col, local_col) of rcols
    rcols: np.ndarray | None = None      # (n, Cr) reaction channels each instance reads

    def expr_values(self, ctx, need_jac):
        """Values (n, nb), slot gradients (n, nb, 3S), scalar gradients (n, nb, U) (None
        without scalar columns) and reaction-channel gradients (n, nb, Cr) (None unless the
        family reads reactions) of all batches."""
        t = ctx.t
        # one time per frame (frames evaluated together, model/frame_batch): one per instance
        t = np.repeat(np.asarray(t, float), self.n // len(t)) if np.ndim(t) else float(t)
        xc = replace(ctx, t=t)
        n, S = self.n, len(self.slot_ml)
        vals = np.zeros((n, len(self.batches)))
        grads = np.zeros((n, len(self.batches), S, 3)) if need_jac else None
        U = self.U
        sgrads = np.zeros((n, len(self.batches), U)) if (need_jac and U) else None
        smaps = self.scalar_maps or [None] * len(self.batches)
        dreac = []
        for k, (b, (r, bs, fs), sm) in enumerate(zip(self.batches, self.slot_maps, smaps)):
            out = b.evaluate(xc)
            dreac.append(out.d_reaction)
            vals[:, k] = out.value
            if need_jac and len(r):
                grads[r, k, fs] = out.d_slot[r, bs]
            if sgrads is not None and sm is not None and len(sm[0]):
                np.add.at(sgrads, (sm[0], k, sm[2]), out.d_scalar[sm[0], sm[1]])
        if need_jac:
            grads = grads.reshape(n, len(self.batches), 3 * S)
        rg = None
        if need_jac and self.reaction_maps is not None:
            # d value / d reaction channel per local channel column (ReactionFeed coupling)
            rg = np.zeros((n, len(self.batches), self.rcols.shape[1]))
            for k, (rows, bc, fc) in enumerate(self.reaction_maps):
                if len(rows):
                    np.add.at(rg, (rows, k, fc), dreac[k][rows, bc])
        return vals, grads, sgrads, rg

    def tile_fields(self, F, model) -> dict:
        """Expression batches and their slot / scalar maps repeated for ``F`` frames
        (:mod:`poise.model.frame_batch`)."""
        n = self.n

        def rows(a):
            return (a[None] + (n * np.arange(F))[:, None]).ravel()
        out = dict(
            batches=tuple(b.tiled(F, len(model.marker_id), len(model.angle_I), model.n_extra)
                          for b in self.batches),
            slot_maps=tuple((rows(r), np.tile(bs, F), np.tile(fs, F))
                            for r, bs, fs in self.slot_maps))
        if self.scalar_maps is not None:
            out["scalar_maps"] = tuple((rows(a), np.tile(b, F), np.tile(c, F))
                                       for a, b, c in self.scalar_maps)
        return out

    def forces(self, kin, ctx, need_jac=True):
        """``(rho, G[, ext])``; ``ext`` holds ``G_ys`` (scalar columns) and ``d_reaction``
        (n, nb, Cr), the values' derivatives w.r.t. the reaction channels read (reaction
        readers, :mod:`poise.elements.reaction_feed`)."""
        vals, grads, sgrads, rgrads = self.expr_values(ctx, need_jac)
        F, T, dF, dT = self.compute(kin.Y, vals, grads, need_jac)
        rho, G = apply_two_body(kin.Y, F, T, dF, dT, self.action_only, need_jac)
        ext = {}
        if rgrads is not None:
            ext["d_reaction"] = rgrads
        if self.U and need_jac:
            # rho is linear in (F, T) at fixed slots: d rho / d s_u = rho(dF/ds_u, dT/ds_u)
            dFs, dTs = self.scalar_chain(kin.Y, sgrads)                # (n, 3, U) each
            ext["G_ys"] = np.stack(
                [apply_two_body(kin.Y, dFs[:, :, u], dTs[:, :, u], None, None,
                                self.action_only, False)[0] for u in range(self.U)], axis=2)
        return (rho, G, ext) if (ext or self.U) else (rho, G)


class ExprVectorForce(ExprForce):
    """Vector force/torque with expression components along R's axes (see module doc)."""

    def compute(self, Y, c, dc, need_jac):
        """F, T (n, 3) and dF, dT (n, 3, W) from the component values ``c`` (n, 6) and
        their slot gradients ``dc`` (n, 6, W)."""
        AR = np.stack([Y[:, S_XR], Y[:, S_YR], Y[:, S_ZR]], axis=2)
        F = np.einsum("nik,nk->ni", AR, c[:, :3])
        T = np.einsum("nik,nk->ni", AR, c[:, 3:])
        dF = dT = None
        if need_jac:
            dF = np.matmul(AR, dc[:, :3])
            dT = np.matmul(AR, dc[:, 3:])
            for k, s in enumerate((S_XR, S_YR, S_ZR)):
                dF[:, :, sl(s)] += c[:, k][:, None, None] * _I3
                dT[:, :, sl(s)] += c[:, 3 + k][:, None, None] * _I3
        return F, T, dF, dT

    def scalar_chain(self, Y, sg):
        """dF/ds, dT/ds (n, 3, U) from the component gradients ``sg`` (n, 6, U)."""
        AR = np.stack([Y[:, S_XR], Y[:, S_YR], Y[:, S_ZR]], axis=2)
        return np.matmul(AR, sg[:, :3]), np.matmul(AR, sg[:, 3:])


@dataclass(frozen=True, eq=False, kw_only=True)
class ExprScalarForce(ExprForce):
    """Scalar force along J->I / along z_J (action-only) or torque about z_J (module doc);
    ``stype`` (n,): ST_LINE, ST_AXIS or ST_TORQUE."""

    stype: np.ndarray

    def compute(self, Y, v, dv, need_jac):
        """F, T and their slot gradients from the magnitude ``v`` (n, 1), ``dv`` (n, 1, W)."""
        f = v[:, 0]
        n = Y.shape[0]
        W = Y.shape[1] * 3
        st = self.stype
        line, axis, torq = st == ST_LINE, st == ST_AXIS, st == ST_TORQUE
        d = Y[:, S_PI] - Y[:, S_PJ]
        L = np.linalg.norm(d, axis=1)
        if np.any(line & (L <= 1e-300)):
            i = int(np.argmax(line & (L <= 1e-300)))
            raise EvaluationError("the I and J markers coincide: the line of action is "
                                  "undefined", self.element_locs[i], "val_expression")
        Ls = np.where(line, L, 1.0)
        u = d / Ls[:, None]
        z = Y[:, S_ZJ]
        dirF = np.where(line[:, None], u, np.where(axis[:, None], z, 0.0))
        F = f[:, None] * dirF
        T = (f * torq)[:, None] * z
        dF = dT = None
        if need_jac:
            df = dv[:, 0]                                    # (n, W)
            dF = dirF[:, :, None] * df[:, None, :]
            uu = u[:, :, None] * u[:, None, :]
            Pm = (f / Ls)[:, None, None] * (_I3 - uu) * line[:, None, None]
            dF[:, :, sl(S_PI)] += Pm
            dF[:, :, sl(S_PJ)] -= Pm
            dF[:, :, sl(S_ZJ)] += (f * axis)[:, None, None] * _I3
            dT = (torq[:, None] * z)[:, :, None] * df[:, None, :]
            dT[:, :, sl(S_ZJ)] += (f * torq)[:, None, None] * _I3
            assert dF.shape == (n, 3, W)
        return F, T, dF, dT

    def scalar_chain(self, Y, sg):
        """dF/ds, dT/ds (n, 3, U) from the magnitude gradient ``sg`` (n, 1, U)."""
        st = self.stype
        line, axis, torq = st == ST_LINE, st == ST_AXIS, st == ST_TORQUE
        d = Y[:, S_PI] - Y[:, S_PJ]
        L = np.linalg.norm(d, axis=1)
        u = d / np.where(line & (L > 0), L, 1.0)[:, None]
        z = Y[:, S_ZJ]
        dirF = np.where(line[:, None], u, np.where(axis[:, None], z, 0.0))
        df = sg[:, 0]                                        # (n, U)
        return dirF[:, :, None] * df[:, None, :], (torq[:, None] * z)[:, :, None] * df[:, None, :]


# ====================================================================================== build
def layout_slots(batches, I, J, ground):
    """Extra marker columns and per-batch slot maps.

    Returns ``(extra (n, X) marker indices, slot_maps)``.
    """
    n = len(I)
    extras = [dict() for _ in range(n)]
    for b in batches:
        for i in range(n):
            for m in b.slot_marker[i]:
                m = int(m)
                if m < 0 or ground[m] or m == I[i] or m == J[i] or m in extras[i]:
                    continue
                extras[i][m] = len(extras[i])
    extra = columns_array(extras, fill=0)     # padding: global frame (index 0)
    maps = []
    for b in batches:
        rows, bs, fs = [], [], []
        for i in range(n):
            for s, (m, kind) in enumerate(zip(b.slot_marker[i], b.slot_kind[i])):
                m, kind = int(m), int(kind)
                if m < 0 or ground[m]:
                    continue
                if m == I[i]:
                    f = kind
                elif m == J[i]:
                    f = 4 + kind
                else:
                    f = N_SLOTS + 4 * extras[i][m] + kind
                rows.append(i)
                bs.append(s)
                fs.append(f)
        maps.append((np.array(rows, np.intp), np.array(bs, np.intp), np.array(fs, np.intp)))
    return extra, maps


def slot_layout(slots, I, J, R, ground):
    """``(markers (n, 3 + X), slot_ml, slot_kind (n, S), maps)`` of instances with markers
    ``I, J, R`` reading the slots of ``slots`` (expression batches, or objects with their
    ``slot_marker`` / ``slot_kind``, e.g. a user routine's): see :func:`layout_slots`."""
    I, J, R = (np.asarray(a, int) for a in (I, J, R))
    extra, maps = layout_slots(slots, I, J, ground)
    X = extra.shape[1]
    n = len(I)
    slot_ml = np.concatenate([SLOT_ML, np.repeat(3 + np.arange(X), 4)]).astype(int)
    slot_kind = np.concatenate([SLOT_KIND, np.tile([0, 1, 2, 3], X)]).astype(int)
    return (np.concatenate([np.stack([I, J, R], 1), extra], 1), slot_ml,
            np.broadcast_to(slot_kind, (n, len(slot_kind))).copy(), tuple(maps))


def build_family(cls, name, I, J, R, owner, action_only, batches, ground, locs, **fields):
    """A family of ``cls`` for the elements ``locs`` with markers ``I, J, R`` reading the
    expression ``batches``, in output group ``forces``."""
    markers, slot_ml, slot_kind, maps = slot_layout(batches, I, J, R, ground)
    scols, smaps = _scalar_layout(batches, len(markers))
    return cls(name=name, markers=markers, slot_ml=slot_ml, slot_kind=slot_kind,
               owner=np.asarray(owner, int), action_only=np.asarray(action_only, bool),
               batches=tuple(batches), slot_maps=maps, scols=scols, scalar_maps=smaps,
               element_locs=tuple(locs), group="forces", **fields)


def build_vector_family(items, ctx, res, ground, **fields):
    """Family for expression ``Force_Vector_OneBody/TwoBody`` elements ``[(owner, el), ...]``
    (the batches compiled; ``fields``: e.g. the reaction layout), or None (problems)."""
    mk = ctx.marker
    I, J, R, ao, comps = [], [], [], [], []
    for _, el in items:
        one = el.tag.endswith("OneBody")
        I.append(mk(el, "marker_id" if one else "i_marker_id"))
        J.append(0 if one else mk(el, "j_floating_marker_id"))
        R.append(mk(el, "ref_marker_id", required=False))
        ao.append(one)
        t = str(el.attrs.get("type", "FORCEANDTORQUE")).upper()
        row = []
        for k, nm in enumerate(VEC_ATTRS):
            v = el.attrs.get(f"{nm}_expression", el.attrs.get(nm, 0.0))
            if (t == "FORCEONLY" and k >= 3) or (t == "TORQUEONLY" and k < 3):
                v = 0.0
            row.append(v if hasattr(v, "text") else float(v or 0.0))
        comps.append(row)
    batches = [compile_batch_located([c[k] for c in comps], res, ctx.pc) for k in range(6)]
    if any(bt is None for bt in batches):
        return None
    return build_family(ExprVectorForce, "forces:ExprVectorForce", I, J, R,
                        [o for o, _ in items], ao, batches, ground, [el.loc for _, el in items],
                        **reaction_layout(batches, len(items)))


def build_scalar_family(items, ctx, res, ground):
    """Family for ``Force_Scalar_TwoBody`` elements with ``val_expression``, or None."""
    I, J, ao, st, vals = [], [], [], [], []
    for _, el in items:
        I.append(ctx.marker(el, "i_marker_id"))
        J.append(ctx.marker(el, "j_marker_id"))
        a_o = bool(el.attrs.get("is_action_only", False))
        t = str(el.attrs.get("type", "FORCE")).upper()
        ao.append(a_o)
        st.append(ST_TORQUE if t == "TORQUE" else (ST_AXIS if a_o else ST_LINE))
        vals.append(el.attrs.get("val", el.attrs.get("val_expression", 0.0)))
    batch = compile_batch_located(vals, res, ctx.pc)
    if batch is None:
        return None
    return build_family(ExprScalarForce, "forces:ExprScalarForce", I, J, [0] * len(I),
                        [o for o, _ in items], ao, [batch], ground, [el.loc for _, el in items],
                        stype=np.asarray(st, int), **reaction_layout([batch], len(items)))


def _scalar_layout(batches, n):
    """``(scols (n, U), maps)``: the scalar unknowns (Control_Diff states, implicit variables)
    the instances' expressions read and per batch the map (rows, batch_col, family_col);
    ``(None, None)`` when they read none."""
    cols = [dict() for _ in range(n)]
    empty = (np.zeros(0, np.intp),) * 3
    maps = [column_map(b.scalar_index, cols) if getattr(b, "scalar_index", None) is not None
            else empty for b in batches]
    U = max((len(c) for c in cols), default=0)
    if not U:
        return None, None
    return columns_array(cols), tuple(maps)


def reaction_layout(batches, n) -> dict:
    """``reads_reactions``, and for a family reading reaction channels ``rcols`` (n, Cr) (the
    channels each instance reads) and per batch the map ``reaction_maps`` (rows, batch_col,
    local_col) gathering ``d_reaction`` (:mod:`poise.elements.reaction_feed`)."""
    if not any(b.C and (b.reaction_index >= 0).any() for b in batches):
        return {}
    cols = [dict() for _ in range(n)]
    empty = (np.zeros(0, np.intp),) * 3
    maps = tuple(column_map(b.reaction_index, cols) if b.C else empty for b in batches)
    return dict(reads_reactions=True, reaction_maps=maps, rcols=columns_array(cols))
