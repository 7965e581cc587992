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

from poise.elements.couplers import Coupler


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
