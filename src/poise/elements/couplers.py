"""Coupler constraint between the free coordinates of up to three joints (also used by gears).

``Constraint_Coupler`` (deck_format.md §3.3) and ``Constraint_Gear`` (§3.4, position-level form,
see :mod:`poise.elements.gears`) are one scalar equation

    sum_k c_k (q_k - q0_k) = 0,   k = 1..3

where ``q_k`` is joint k's free coordinate between its I and J markers (freedom ``R``: the
continuous angle ``AZ(I_k, J_k)``; ``T``: ``DZ(I_k, J_k, J_k)``) and ``q0_k`` its value in the
input configuration. The coordinates, the two-joint form and the slot layout: :class:`Coupler`.
"""
from __future__ import annotations

import numpy as np

from poise.elements.base import ConstraintFamily
from poise.elements.motions import measure

N_JOINTS = 3
N_SLOTS = 8 * N_JOINTS
W = 3 * N_SLOTS
SLOT_ML = np.repeat(np.arange(2 * N_JOINTS), 4)
SLOT_KIND = np.tile(np.array([0, 1, 2, 3]), 2 * N_JOINTS)


class Coupler(ConstraintFamily):
    """``sum_k c_k (q_k - q0_k) = 0``.

    Attributes (set by :meth:`build`)
    ----------
    coef : (n, 3) coefficients c_k (0 for an absent third joint)
    rot : (n, 3) bool, freedom R (True) or T (False) per joint
    q0 : (n, 3) values in the input configuration
    angle_index : (n, 3) int, continuous-angle table entry of R joints (-1 for T joints)

    where ``q_k`` is joint k's free coordinate measured between its I and J markers:

    * freedom ``R``: the continuous angle ``AZ(I_k, J_k)`` (angle table, full turns counted);
    * freedom ``T``: ``DZ(I_k, J_k, J_k) = (P_I - P_J) . z_J``;

    and ``q0_k`` its value in the input configuration (so the input configuration satisfies the
    coupler; see docs/DESIGN.md "Couplers and gears"). A two-joint coupler has ``c_3 = 0`` and a
    dummy third joint on the global frame (ground markers: no coordinates).

    Slot layout (markers ``[I1, J1, I2, J2, I3, J3]``): per joint k the 8 slots
    ``[P_I, x_I, y_I, z_I, P_J, x_J, y_J, z_J]`` of :mod:`poise.elements.motions` (24 slots, W = 72).
    Gradient and multiplier-weighted Hessian are the exact ones of the motion measures
    (:func:`poise.elements.motions.measure`), placed in joint k's block.
    """

    @classmethod
    def build(cls, name, markers, coef, rot, q0, owner):
        markers = np.asarray(markers, int).reshape(-1, 2 * N_JOINTS)
        n = markers.shape[0]
        fam = cls(name=name, markers=markers, slot_ml=SLOT_ML,
                  slot_kind=np.broadcast_to(SLOT_KIND, (n, N_SLOTS)).copy(),
                  owner=np.asarray(owner, int), m=1)
        fam.coef = np.asarray(coef, float).reshape(n, N_JOINTS)
        fam.rot = np.asarray(rot, bool).reshape(n, N_JOINTS)
        fam.q0 = np.asarray(q0, float).reshape(n, N_JOINTS)
        fam.angle_index = -np.ones((n, N_JOINTS), int)
        return fam

    def joint_values(self, kin, ctx):
        """Current q_k, (n, 3)."""
        n = self.n
        q = np.zeros((n, N_JOINTS))
        for k in range(N_JOINTS):
            Yk = kin.Y[:, 8 * k:8 * k + 8]
            r = self.rot[:, k]
            if (~r).any():
                v, _, _ = measure(Yk, "Z", need_hess=False)
                q[~r, k] = v[~r]
            if r.any():
                q[r, k] = ctx.angle[self.angle_index[r, k]]
        return q

    def constraints(self, kin, lam, ctx):
        n = self.n
        q = self.joint_values(kin, ctx)
        phi = np.sum(self.coef * (q - self.q0), axis=1)[:, None]
        phi_y = np.zeros((n, 1, W))
        G = np.zeros((n, W, W))
        lv = lam[:, 0]
        for k in range(N_JOINTS):
            c = self.coef[:, k]
            if not np.any(c != 0):
                continue
            Yk = kin.Y[:, 8 * k:8 * k + 8]
            blk = slice(24 * k, 24 * k + 24)
            r = self.rot[:, k]
            for name, mask in (("AZ", r), ("Z", ~r)):
                if not mask.any():
                    continue
                _, g, H = measure(Yk[mask], name, need_hess=True)
                idx = np.nonzero(mask)[0]
                phi_y[idx, 0, blk] = c[mask, None] * g
                G[idx, blk, blk] = (lv[mask] * c[mask])[:, None, None] * H
        return phi, phi_y, G
