"""SCREW joint (``Constraint_Joint type="SCREW"``): translation along J's z tied to rotation.

One equation (deck_format.md §3.1): ``(P_I - P_J) . z_J - pitch * AZ(I, J) / (2 pi) = 0``, where
``AZ(I, J)`` is the continuous angle of I about J's z axis (full turns counted, principal value
at the input configuration) and ``pitch`` the translation per full revolution (MotionView's
ScrewJoint): a positive pitch is a right-handed screw, I advances along +z_J as it turns
positively about z_J. Like MotionSolve's screw it removes one freedom only; a CYLINDRICAL joint
on the same markers keeps the axes aligned. Its reaction joins the ``joints`` output group (after
the other joints) and ``JOINT(id, ...)`` reads it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.elements.base import ConstraintFamily
from poise.elements.constraints import JOINTS
from poise.elements.context import num
from poise.elements.measures import SLOT_KIND, SLOT_ML, measure
from poise.elements.registry import ElementType, FDCase, static, workless


@dataclass(frozen=True, eq=False, kw_only=True)
class Screw(ConstraintFamily):
    """``d . z_J - c AZ(I, J) = 0`` with ``c = pitch / (2 pi)`` (n,), ``angle_index`` (n,) the
    angle table's AZ(I, J). Slots: the 8 slots of :mod:`poise.elements.motions`
    ``[P_I, x_I, y_I, z_I, P_J, x_J, y_J, z_J]``."""

    c: np.ndarray
    angle_index: np.ndarray

    @classmethod
    def build(cls, name, I, J, c, angle_index, owner, **layout):
        n = len(I)
        return cls(name=name, markers=np.stack([I, J], 1).astype(int), slot_ml=SLOT_ML,
                   slot_kind=np.broadcast_to(SLOT_KIND, (n, len(SLOT_KIND))).copy(),
                   owner=np.asarray(owner, int), m=1, c=np.asarray(c, float),
                   angle_index=np.asarray(angle_index, int), **layout)

    def constraints(self, kin, lam, ctx):
        c = self.c
        z, gz, Hz = measure(kin.Y, "Z", need_hess=True)
        _, ga, Ha = measure(kin.Y, "AZ", need_hess=True)
        phi = (z - c * ctx.angle[self.angle_index])[:, None]
        phi_y = (gz - c[:, None] * ga)[:, None, :]
        G = lam[:, 0][:, None, None] * (Hz - c[:, None, None] * Ha)
        return phi, phi_y, G


def compile_screws(spec, ctx):
    els = [e for e in spec.elements("Constraint_Joint")
           if str(e.attrs.get("type", "")).upper() == "SCREW"]
    if not els:
        return
    first = ctx.extend_output("joints", "Constraint_Joint", [e.id for e in els])
    I, J, c, ang, rows = [], [], [], [], []
    for k, el in enumerate(els):
        i, j = ctx.marker(el, "i_marker_id"), ctx.marker(el, "j_marker_id")
        I.append(i)
        J.append(j)
        c.append(float(num(el, "pitch", 0.0, ctx.pc) or 0.0) / (2.0 * np.pi))
        ang.append(ctx.angle(i, j, 2))
        rows.append([ctx.add_row(el, "d.zJ-pitch*AZ/2pi", "trans", "joints", first + k)])
    ctx.effect("Constraint_Joint:SCREW")
    ctx.add_family(Screw.build("joints:screw", np.array(I), np.array(J), c, ang,
                               np.arange(first, first + len(els)),
                               **joint_layout(els, rows)))


def joint_layout(els, rows) -> dict:
    """Layout fields of a one-row-per-joint family of ``Constraint_Joint`` elements ``els``
    (rows ``rows``) after the other joints: its rows, the ``joints`` group, the elements."""
    return dict(crow=np.array(rows, int), group="joints", element_locs=tuple(e.loc for e in els))


ELEMENTS = (ElementType(
    "screw", ("Constraint_Joint",), compile_screws, types=("SCREW",),
    rank=100,                             # its row and reaction follow the other joints'
    kernels=lambda: (Screw,), potential_energy=workless, time_dependent=static,
    outputs=(JOINTS,),
    fd_cases=lambda: (FDCase("Constraint_Joint:SCREW",
                             (("Constraint_Joint", {"type": "SCREW", "pitch": 0.3}),),
                             pairs=((21, 31), (22, 11)), point_b=(False,)),)),)
