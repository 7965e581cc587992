"""The two-body force layout and the application of a force and torque to both bodies.

Every two-body force element shares one slot layout (markers I, J, R):
``[P_I, x_I, y_I, z_I, P_J, x_J, y_J, z_J, x_R, y_R, z_R]`` (slots 0..10), where R is the
reference marker of vector-force components. A family computes the force ``F`` and torque ``T``
on the body of I at the I origin; :func:`apply_two_body` applies them to I and, unless the
element is action-only, the equal and opposite action to J: ``-F`` at ``P_J`` plus the torque
``-T - (P_I - P_J) x F`` (with the derivatives, when a Jacobian is asked for).
"""
from __future__ import annotations

import numpy as np

from poise.elements.base import add_force_at_point, add_torque_via_axes
from poise.elements.kernel import cross3
from poise.elements.rotation import skew


S_PI, S_XI, S_YI, S_ZI, S_PJ, S_XJ, S_YJ, S_ZJ, S_XR, S_YR, S_ZR = range(11)
N_SLOTS = 11
SLOT_ML = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2])
SLOT_KIND = np.array([0, 1, 2, 3, 0, 1, 2, 3, 1, 2, 3])
# angle measure (about axis k of J): (u slot, e1 slot, e2 slot): theta = atan2(u.e2, u.e1)
ANGLE_SLOTS = {0: (S_YI, S_YJ, S_ZJ), 1: (S_ZI, S_ZJ, S_XJ), 2: (S_XI, S_XJ, S_YJ)}


def sl(s):
    return slice(3 * s, 3 * s + 3)


def angle_gradient(Y, axis):
    """Gradient of the angle about J axis ``axis`` (0=x: AX, 1=y: AY, 2=z: AZ), (n, 33)."""
    su, s1, s2 = ANGLE_SLOTS[axis]
    u, e1, e2 = Y[:, su], Y[:, s1], Y[:, s2]
    c = np.einsum("ni,ni->n", u, e1)
    s = np.einsum("ni,ni->n", u, e2)
    r2 = c * c + s * s
    g = np.zeros((Y.shape[0], 3 * N_SLOTS))
    g[:, sl(su)] = (c[:, None] * e2 - s[:, None] * e1) / r2[:, None]
    g[:, sl(s1)] = -s[:, None] * u / r2[:, None]
    g[:, sl(s2)] = c[:, None] * u / r2[:, None]
    return g


def principal_angle(Y, axis):
    su, s1, s2 = ANGLE_SLOTS[axis]
    u, e1, e2 = Y[:, su], Y[:, s1], Y[:, s2]
    return np.arctan2(np.einsum("ni,ni->n", u, e2), np.einsum("ni,ni->n", u, e1))


def apply_two_body(Y, F, T, dF, dT, action_only, need_jac):
    """Assemble ``rho`` (n, 33) and ``G`` (n, 33, 33) from the action (F, T) on I.

    ``action_only`` (n,) bool (or None: all react): no reaction on J for those instances.
    ``T`` (and ``dT``) None: no torque on I (the line forces); ``F`` (and ``dF``) None: no force
    (the torques): nothing is added for it, the same values as a zero torque or force.
    """
    n, S = Y.shape[:2]              # any slot count >= 11: extra slots enter only through dF, dT
    W = 3 * S
    rho = np.zeros((n, W))
    G = np.zeros((n, W, W)) if need_jac else None
    if F is not None:
        add_force_at_point(rho, G, S_PI, F, dF)
    if T is not None:
        add_torque_via_axes(rho, G, (S_XI, S_YI, S_ZI), T, dT, Y)
    # x * 1.0 is x: every instance reacting multiplies by nothing
    react = (None if action_only is None or not np.logical_or.reduce(action_only, axis=None)
             else ~np.asarray(action_only, bool))
    if react is None or np.logical_or.reduce(react):
        Fj = dFj = dTj = None
        if F is None:                       # a pure torque: no offset moment
            Tj = -T
            if need_jac:
                dTj = -dT
        else:
            d = Y[:, S_PI] - Y[:, S_PJ]
            # -0 - x is -x: a missing torque subtracts nothing
            Tj = -cross3(d, F) if T is None else -T - cross3(d, F)
            Fj = -F
        if need_jac and F is not None:
            dFj = -dF
            # d(d x F) = -[F]x dd + [d]x dF, dd = I / -I on P_I / P_J: -[F]x dd added exactly
            dcross = np.matmul(skew(d), dF)
            sF = skew(F)
            dcross[:, :, sl(S_PI)] -= sF
            dcross[:, :, sl(S_PJ)] += sF
            dTj = -dcross if dT is None else -dT - dcross
        if react is not None:
            Tj = Tj * react[:, None]
            Fj = None if Fj is None else Fj * react[:, None]
            if need_jac:
                dTj = dTj * react[:, None, None]
                dFj = None if dFj is None else dFj * react[:, None, None]
        if Fj is not None:
            add_force_at_point(rho, G, S_PJ, Fj, dFj)
        add_torque_via_axes(rho, G, (S_XJ, S_YJ, S_ZJ), Tj, dTj, Y)
    return rho, G
