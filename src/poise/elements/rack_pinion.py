"""RACK_PINION joint (``Constraint_Joint type="RACK_PINION"``, Adams ``JOINT/id, RACKPIN, PD=``).

I marker on the pinion (its z axis the pinion axis), J marker on the rack (its z axis the rack's
direction of travel). One equation, measured from the input configuration like couplers and
gears: the rack travels ``PD/2`` along ``z_J`` per radian the pinion turns about ``z_I``,

    ``(P_J - P_I) . z_J - c0 = (PD/2) (theta - theta0)``,

``theta`` the rotation of I about its z axis relative to J (turns counted), ``c0, theta0`` their
input values: a positive rotation of the pinion moves the rack along +z_J relative to the pinion
(Adams: PD > 0 moves the rack in +z_J; the pinion's x axis along the rack's z axis, the axes PD/2
apart). ``theta = -phi`` with ``phi`` the continuous angle of ``z_J`` in I's x-y plane (kind 3 of
the angle table), so the row is ``d . z_J - (PD/2) phi + const`` with ``d = P_I - P_J``. Like
MotionSolve's joint it removes one freedom only: revolute and translational joints hold the
pinion and the rack. Its reaction joins the ``joints`` output group (``JOINT(id, ...)``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.elements.base import ConstraintFamily
from poise.elements.constraints import JOINTS
from poise.elements.context import num
from poise.elements.measures import (S_PI, S_PJ, S_XI, S_YI, S_ZJ, SLOT_KIND, SLOT_ML,
                                    atan2_term, dot_term)
from poise.elements.registry import ElementType, FDCase, static, workless
from poise.elements.screw import joint_layout

#: smallest |sin| of the angle between the pinion axis z_I and the rack direction z_J
AXIS_SIN_MIN = 1e-3


def _rows(Y, need_hess=True):
    """``d . z_J`` and ``phi = atan2(z_J . y_I, z_J . x_I)``: values, gradients, Hessians."""
    zi, gzi, Hzi = dot_term(Y, S_PI, S_ZJ, 1.0, need_hess)
    zj, gzj, Hzj = dot_term(Y, S_PJ, S_ZJ, -1.0, need_hess)
    ph, gph, Hph = atan2_term(dot_term(Y, S_ZJ, S_YI, 1.0, need_hess),
                              dot_term(Y, S_ZJ, S_XI, 1.0, need_hess))
    H = None if not need_hess else (Hzi + Hzj, Hph)
    return (zi + zj, gzi + gzj, ph, gph, H)


@dataclass(frozen=True, eq=False, kw_only=True)
class RackPinion(ConstraintFamily):
    """``d . z_J - r (phi - phi0) - c0 = 0`` with ``r = PD/2``, ``c0`` (n,) and ``angle_index``
    (n,) the angle table's phi. Slots: the 8 slots of :mod:`poise.elements.motions`
    ``[P_I, x_I, y_I, z_I, P_J, x_J, y_J, z_J]``."""

    r: np.ndarray
    c0: np.ndarray
    angle_index: np.ndarray

    @classmethod
    def build(cls, name, I, J, r, c0, angle_index, owner, **layout):
        n = len(I)
        return cls(name=name, markers=np.stack([I, J], 1).astype(int), slot_ml=SLOT_ML,
                   slot_kind=np.broadcast_to(SLOT_KIND, (n, len(SLOT_KIND))).copy(),
                   owner=np.asarray(owner, int), m=1, r=np.asarray(r, float),
                   c0=np.asarray(c0, float), angle_index=np.asarray(angle_index, int), **layout)

    def values(self, kin, ctx):
        z, _, _, _, _ = _rows(kin.Y, need_hess=False)
        return (z - self.r * ctx.angle[self.angle_index] - self.c0)[:, None]

    def constraints(self, kin, lam, ctx):
        r = self.r
        z, gz, _, gph, (Hz, Hph) = _rows(kin.Y)
        phi = (z - r * ctx.angle[self.angle_index] - self.c0)[:, None]
        phi_y = (gz - r[:, None] * gph)[:, None, :]
        G = lam[:, 0][:, None, None] * (Hz - r[:, None, None] * Hph)
        return phi, phi_y, G


def compile_rack_pinions(spec, ctx):
    els = [e for e in spec.elements("Constraint_Joint")
           if str(e.attrs.get("type", "")).upper() == "RACK_PINION"]
    if not els:
        return
    first = ctx.extend_output("joints", "Constraint_Joint", [e.id for e in els])
    I, J, r, c0, ang, rows = [], [], [], [], [], []
    for k, el in enumerate(els):
        i, j = ctx.marker(el, "i_marker_id"), ctx.marker(el, "j_marker_id")
        rk = 0.5 * float(num(el, "pitch_diameter", 0.0, ctx.pc) or 0.0)
        gi = ctx.marker_pose(el.attrs.get("i_marker_id"))
        gj = ctx.marker_pose(el.attrs.get("j_marker_id"))
        z0 = phi0 = 0.0
        if gi is not None and gj is not None:
            (pi, Ai), (pj, Aj) = gi, gj
            zj = Aj[:, 2]
            s = float(np.linalg.norm(np.cross(Ai[:, 2], zj)))
            if s < AXIS_SIN_MIN:
                ctx.pc.error(el.loc, "RACK_PINION joint whose rack direction (J marker z axis) "
                             f"is parallel to the pinion axis (I marker z axis; sin = {s:.2g}): "
                             "the pinion's rotation cannot drive the rack; expected z_J across "
                             "z_I (Adams: the pinion's x axis along the rack's z axis)",
                             "j_marker_id")
            z0 = float((pi - pj) @ zj)
            phi0 = float(np.arctan2(zj @ Ai[:, 1], zj @ Ai[:, 0]))
        I.append(i)
        J.append(j)
        r.append(rk)
        c0.append(z0 - rk * phi0)
        ang.append(ctx.angle(j, i, 3))          # direction of z_J in I's x-y plane
        rows.append([ctx.add_row(el, "rack-r*pinion", "trans", "joints", first + k)])
    ctx.effect("Constraint_Joint:RACK_PINION")
    ctx.add_family(RackPinion.build("joints:rack_pinion", np.array(I), np.array(J), r, c0, ang,
                                    np.arange(first, first + len(els)),
                                    **joint_layout(els, rows)))


ELEMENTS = (ElementType(
    "rack_pinion", ("Constraint_Joint",), compile_rack_pinions, types=("RACK_PINION",),
    rank=110,                             # its row and reaction follow the screws'
    kernels=lambda: (RackPinion,), potential_energy=workless, time_dependent=static,
    outputs=(JOINTS,),
    fd_cases=lambda: (FDCase("Constraint_Joint:RACK_PINION",
                             (("Constraint_Joint", {"type": "RACK_PINION",
                                                    "pitch_diameter": 0.7}),),
                             pairs=((21, 31), (22, 11)), point_b=(False,)),)),)
