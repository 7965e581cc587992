"""Gear constraint (``Constraint_Gear``, deck_format.md §3.4) as a position-level coupler.

Two joints (REVOLUTE, TRANSLATIONAL or CYLINDRICAL) mesh at the contact point C (origin of
``cv_marker_id``, on the carrier body common to both joints, z axis ``w`` the direction of the
common velocity). The velocity-level ADAMS GEAR integrates exactly, with constant signed levers
``s_k`` evaluated in the input configuration, to

    s_1 (q_1 - q_1,0) - s_2 (q_2 - q_2,0) = 0,

a :class:`poise.elements.couplers.Coupler` (one row, a length equation) whose multiplier is the
tangential contact force along ``w``. The levers: :func:`signed_lever` and :class:`Gear`.
"""
from __future__ import annotations

import numpy as np

from poise.elements.couplers import (add_coupler_family, joint_coordinate, marker_pose,
                                             user_routine_error)
from poise.elements.couplers import Coupler
from poise.elements.registry import ElementType, OutputGroup, static, workless


def signed_lever(rot: bool, sigma: float, zJ, pJ, c, w) -> float:
    """Velocity of the gear point at C along ``w`` per unit rate of the joint coordinate."""
    zJ, pJ, c, w = (np.asarray(v, float) for v in (zJ, pJ, c, w))
    if rot:
        return float(sigma * np.cross(zJ, c - pJ) @ w)
    return float(sigma * zJ @ w)


class Gear(Coupler):
    """A coupler whose coefficients are the signed levers ``(s_1, -s_2)`` (see module doc).

    Two joints (REVOLUTE, TRANSLATIONAL or CYLINDRICAL) whose bodies mesh at the contact point C
    (origin of ``cv_marker_id``); C's marker sits on the *carrier*, the body common to both joints,
    and its z axis ``w`` is the direction of the common velocity. ADAMS GEAR at velocity level: the
    velocity of the material point of gear 1 at C relative to the carrier equals that of gear 2,
    along ``w``. Through joint k with free coordinate q_k (rotation AZ about the joint axis ``z_J`` or
    translation DZ along ``z_J``) that velocity component is ``s_k q_k'`` with the signed lever

    * revolute (R): ``s_k = sigma_k (z_J x (C - P_J)) . w`` (``|s_k|`` = distance of C from the axis
      when ``w`` is tangential: the pitch radius);
    * translational (T, a rack): ``s_k = sigma_k z_J . w``;

    ``sigma_k = +1`` when the joint's J marker is on the carrier (q_k is the gear's motion relative to
    the carrier) and ``-1`` when its I marker is. The carrier holds the axes and C fixed relative to
    each other, so ``s_k`` is constant: it is evaluated once in the input configuration and the
    velocity equation integrates exactly to

        s_1 (q_1 - q_1,0) - s_2 (q_2 - q_2,0) = 0,

    a :class:`poise.elements.couplers.Coupler` with coefficients ``(s_1, -s_2)`` (one row, a length
    equation). The multiplier is the tangential contact force along ``w`` (up to sign).
    """


# ----------------------------------- compile
def compile_gears(spec, ctx):
    """Compile ``Constraint_Gear`` into one coupler row per gear (see :mod:`poise.elements.gears`).

    The levers ``s_k`` are computed from the input configuration: contact point and common-velocity
    direction from ``cv_marker_id`` (origin, z axis), joint axes from the joints' J markers. The
    cv marker must be on the carrier, the body common to both joints (either marker of each joint
    may be on it; the sign follows). Output group ``gears``: force and torque of the gear's
    multiplier acting through joint 1's I marker on its body (torque about that marker's origin,
    global axes) — for a revolute gear 1 whose I marker is on the gear, the torque the mesh applies
    to gear 1.
    """
    els = spec.elements("Constraint_Gear")
    if not els:
        return
    pc = ctx.pc
    items = []
    for el in els:
        if user_routine_error(pc, el, "gear"):
            continue
        cv = el.attrs.get("cv_marker_id")
        if ctx.marker_pose(cv) is None:
            pc.error(el.loc, f"cv_marker_id {cv} is not a Reference_Marker; expected the "
                     "contact-point marker on the carrier", "cv_marker_id")
            continue
        c, Rc = marker_pose(ctx, el, "cv_marker_id")
        w = Rc[:, 2]
        carrier = ctx.marker_body(cv)
        js = []
        for j in (1, 2):
            jid = el.attrs.get(f"joint{j}_id")
            jel0 = ctx.element("Constraint_Joint", jid)
            # a gear on a CYLINDRICAL joint turns with it (rotational freedom), as in Adams GEAR
            fr = "R" if (jel0 is not None and
                         str(jel0.attrs.get("type", "")).upper() == "CYLINDRICAL") else None
            jd = joint_coordinate(ctx, el, jid, fr, f"joint{j}_id", "joint")
            if jd is None:
                break
            jel = jd["jel"]
            bi = ctx.marker_body(jel.attrs.get("i_marker_id"))
            bj = ctx.marker_body(jel.attrs.get("j_marker_id"))
            if bj == carrier:
                sigma = 1.0
            elif bi == carrier:
                sigma = -1.0
            else:
                pc.error(el.loc, f"joint {jel.id} does not connect to body {carrier} of the cv "
                         "marker; expected the cv marker on the carrier (the body common to both "
                         "joints)", "cv_marker_id")
                break
            jd["s"] = signed_lever(jd["rot"], sigma, jd["RJ"][:, 2], jd["pJ"], c, w)
            if abs(jd["s"]) <= 1e-12 * max(1.0, ctx.L):
                pc.error(el.loc, f"joint {jel.id} gives no velocity at the contact point along "
                         "the cv marker's z axis (zero lever); expected z tangential to the "
                         "pitch circle", "cv_marker_id")
                break
            js.append(jd)
        if len(js) != 2:
            continue
        coef = [js[0]["s"], -js[1]["s"]]
        items.append((el, js, coef, "trans"))
        ctx.effect("Constraint_Gear")
    pc.raise_if_any()
    if not items:
        return
    add_coupler_family(ctx, "gears", "Constraint_Gear", items, cls=Gear)


ELEMENTS = (ElementType(
    "gears", ("Constraint_Gear",), compile_gears,
    rank=50,                    # gear rows after the coupler rows
    kernels=lambda: (Gear,), potential_energy=workless, time_dependent=static,
    outputs=(OutputGroup("gears", "G", "gear", "gear", "`Constraint_Gear`", ("Constraint_Gear",),
                         load="as for couplers: the mesh load on joint 1's I body through its "
                         "I marker"),),
    fd_tests="tests/kernels/test_couplers_gears_fields_beams.py"),)
