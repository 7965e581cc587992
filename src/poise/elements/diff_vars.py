"""Scalar-equation families: ``Control_Diff`` states and implicit / user ``Reference_Variable``s.

Each instance owns one scalar unknown ``s`` (``State.extra[scols[:, 0]]``) and contributes its
residual row ``rho_s[:, 0] = e(s, other scalars, y, t)``; it applies no force to bodies
(``rho = 0``). The tangent has the row blocks ``G_sy = de/dy`` (chained to body coordinates by
the kernel's B matrices) and ``G_ss = de/ds`` (own and other scalar columns). The *columns* of a
scalar (its effect on forces) come from the families that read it (expression forces).

The equation of each kind and the marker layout: :class:`ScalarEquation`.
"""
from __future__ import annotations

import numpy as np

from poise.elements.base import ForceFamily, column_map, columns_array
from poise.expr import EvalContext as XC


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

    batch = None
    slot_map = None          # (rows, batch_slot, family_slot)
    sc_map = None            # (rows, batch_col, family_col)

    def depends_on_time(self) -> bool:
        return bool(self.batch.depends_on_time)

    def forces(self, kin, ctx, need_jac=True):
        n, S, U = self.n, len(self.slot_ml), self.U
        xc = XC(time=float(ctx.t), P=ctx.P, A=ctx.A, angle_ref=ctx.angle,
                scalars=ctx.extra, static=True)
        out = self.batch.evaluate(xc)
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


def layout(batch, own, ground):
    """Markers (n, X), scols (n, U) and the slot / scalar maps of one batch.

    ``own`` (n,) the scalar unknown each instance owns (column 0 of ``scols``); ``ground`` (nm,)
    bool marks markers without coordinates (their slots are dropped).
    """
    n = len(own)
    mk = [dict() for _ in range(n)]
    sc = [{int(own[i]): 0} for i in range(n)]
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
    fam = ScalarEquation(name=name, markers=markers, slot_ml=np.repeat(np.arange(X), 4),
                         slot_kind=np.tile(np.tile([0, 1, 2, 3], X), (n, 1)),
                         owner=np.asarray(owner, int))
    fam.scols = scols
    fam.batch = batch
    fam.slot_map = smap
    fam.sc_map = cmap
    fam.element_locs = locs
    return fam
