"""Families driven by Python user routines (``poise.core.user_routines``), one instance each.

* :class:`UserConstraint` (``Constraint_UserConstr``, UCOSUB style): ``phi`` = the function's
  values, ``phi_y`` its derivatives w.r.t. the marker vectors it reads (user-given or central
  differences), ``G = sum lam_r d2 phi_r / dy2`` by central differences of the gradient.
  Markers: the distinct markers read; slots: the vectors read.
* :class:`UserScalarForce` / :class:`UserVectorForce` (``Force_Scalar_TwoBody`` SFOSUB,
  ``Force_Vector_*`` GFOSUB): the expression-force families of ``expr_forces.py`` with the
  expression batches replaced by the user function (same force laws and slot layout
  ``[I, J, R, extra markers...]``), so values and slot gradients chain exactly the same way.
* :class:`UserScalarEquation` (``Reference_Variable`` VARSUB): the variable is a scalar unknown v
  with residual row ``v - f(q, t)``.
"""
from __future__ import annotations

import numpy as np

from poise.elements.base import ConstraintFamily, ForceFamily
from poise.elements.expr_forces import ExprScalarForce, ExprVectorForce


def _vectors_from_slots(routine, Y, slot_of):
    """Recorded vectors of instance 0 from the kernel's slot vectors ``Y`` (n, S, 3)."""
    vec = {}
    for key in routine.slots:
        s = slot_of.get(key)
        if s is not None:
            vec[key] = Y[0, s]
    return vec


class UserConstraint(ConstraintFamily):
    routine = None
    slot_of = None            # (marker_id, kind) -> family slot

    def depends_on_time(self) -> bool:
        return bool(self.routine.time_dependent)

    def _vec(self, kin, ctx):
        vec = _vectors_from_slots(self.routine, kin.Y, self.slot_of)
        for key in self.routine.slots:            # ground / global vectors: constants
            if key not in vec:
                vec[key] = self.const_vec[key]
        return vec

    def constraints(self, kin, lam, ctx):
        r = self.routine
        vec = self._vec(kin, ctx)
        t = float(ctx.t)
        v, D = r.evaluate(t, vec, True)
        S = len(self.slot_ml)
        phy = np.zeros((1, self.m, 3 * S))
        Hf = None
        if np.any(lam):
            Hf = r.hessian(t, vec, lam[0])
        G = np.zeros((1, 3 * S, 3 * S))
        for a, ka in enumerate(r.slots):
            sa = self.slot_of.get(ka)
            if sa is None:
                continue
            phy[0, :, 3 * sa:3 * sa + 3] = D[:, a]
            if Hf is None:
                continue
            for b, kb in enumerate(r.slots):
                sb = self.slot_of.get(kb)
                if sb is None:
                    continue
                G[0, 3 * sa:3 * sa + 3, 3 * sb:3 * sb + 3] = Hf[3 * a:3 * a + 3, 3 * b:3 * b + 3]
        return v[None, :], phy, G


class _UserForceMixin:
    """Replaces the expression batches of an expression-force family by a user function."""

    tile_frames = None          # a user routine is called per frame (model/frame_batch.py)

    routine = None
    n_comp = 1
    comp_index = None          # positions of the user's values among the family components
    user_map = None            # (user slot index, family slot) pairs of moving-marker vectors

    def depends_on_time(self) -> bool:
        return bool(self.routine.time_dependent)

    def _expr_values(self, ctx, need_jac):
        r = self.routine
        vec = {key: (ctx.P[r.mi[key[0]]] if key[1] == 0 else ctx.A[r.mi[key[0]]][:, key[1] - 1])
               for key in r.slots}
        v, D = r.evaluate(float(ctx.t), vec, need_jac)
        S = len(self.slot_ml)
        vals = np.zeros((1, self.n_comp))
        vals[0, self.comp_index] = v
        grads = None
        if need_jac:
            g = np.zeros((1, self.n_comp, S, 3))
            for us, fs in self.user_map:
                g[0, self.comp_index, fs] = D[:, us]
            grads = g.reshape(1, self.n_comp, 3 * S)
        self._sgrads = None
        return vals, grads


class UserScalarForce(_UserForceMixin, ExprScalarForce):
    n_comp = 1


class UserVectorForce(_UserForceMixin, ExprVectorForce):
    n_comp = 6


class UserScalarEquation(ForceFamily):
    """Residual ``v - f(q, t)`` of a user-defined variable v (VARSUB)."""

    routine = None
    slot_of = None

    def depends_on_time(self) -> bool:
        return bool(self.routine.time_dependent)

    def forces(self, kin, ctx, need_jac=True):
        r = self.routine
        vec = _vectors_from_slots(r, kin.Y, self.slot_of)
        for key in r.slots:
            if key not in vec:
                vec[key] = self.const_vec[key]
        f, D = r.evaluate(float(ctx.t), vec, need_jac)
        S = len(self.slot_ml)
        rho = np.zeros((1, 3 * S))
        v = ctx.extra[self.scols[0, 0]]
        ext = {"rho_s": np.array([[v - f[0]]])}
        if need_jac:
            G_sy = np.zeros((1, 1, 3 * S))
            for a, key in enumerate(r.slots):
                s = self.slot_of.get(key)
                if s is not None:
                    G_sy[0, 0, 3 * s:3 * s + 3] = -D[0, a]
            ext["G_sy"] = G_sy
            ext["G_ss"] = np.ones((1, 1, 1))
        return rho, None, ext
