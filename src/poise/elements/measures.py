"""Measures between two markers with exact gradients and Hessians (motions, screws, racks,
couplers).

Slot layout (markers I, J): ``[P_I, x_I, y_I, z_I, P_J, x_J, y_J, z_J]`` (slots 0..7). Every
measure is built from *dot terms* ``a . b`` of two slot vectors, whose gradient and Hessian with
respect to the slots are exact and cheap: :func:`dot_term`, combined by :func:`atan2_term` and
:func:`asin_term` into the measures X, Y, Z, AZ and B1..B3 of :func:`measure`.
"""
from __future__ import annotations

import numpy as np

S_PI, S_XI, S_YI, S_ZI, S_PJ, S_XJ, S_YJ, S_ZJ = range(8)
N_SLOTS = 8
W = 3 * N_SLOTS
SLOT_ML = np.array([0, 0, 0, 0, 1, 1, 1, 1])
SLOT_KIND = np.array([0, 1, 2, 3, 0, 1, 2, 3])
_I3 = np.eye(3)
_AXJ = {"X": S_XJ, "Y": S_YJ, "Z": S_ZJ}
_AXI = (S_XI, S_YI, S_ZI)
_AXJL = (S_XJ, S_YJ, S_ZJ)


def _sl(s):
    return slice(3 * s, 3 * s + 3)


def dot_term(Y, a, b, sign=1.0, need_hess=True):
    """``sign * (y_a . y_b)``: value (n,), gradient (n, W), Hessian (n, W, W) or None."""
    n = Y.shape[0]
    v = sign * np.einsum("ni,ni->n", Y[:, a], Y[:, b])
    g = np.zeros((n, W))
    g[:, _sl(a)] += sign * Y[:, b]
    g[:, _sl(b)] += sign * Y[:, a]
    H = None
    if need_hess:
        H = np.zeros((W, W))
        H[_sl(a), _sl(b)] += sign * _I3
        H[_sl(b), _sl(a)] += sign * _I3
        H = np.broadcast_to(H, (n, W, W))
    return v, g, H


def _sum(*terms):
    v = sum(t[0] for t in terms)
    g = sum(t[1] for t in terms)
    H = None if terms[0][2] is None else sum(t[2] for t in terms)
    return v, g, H


def atan2_term(s, c):
    """``atan2(s, c)`` of two dot-term expressions, with exact gradient and Hessian."""
    (sv, gs, Hs), (cv, gc, Hc) = s, c
    r2 = sv * sv + cv * cv
    num = cv[:, None] * gs - sv[:, None] * gc
    g = num / r2[:, None]
    H = None
    if Hs is not None:
        A = (gs[:, :, None] * gc[:, None, :] - gc[:, :, None] * gs[:, None, :]
             + cv[:, None, None] * Hs - sv[:, None, None] * Hc)
        dr2 = 2.0 * (cv[:, None] * gc + sv[:, None] * gs)
        H = A / r2[:, None, None] - num[:, :, None] * dr2[:, None, :] / (r2 ** 2)[:, None, None]
    return np.arctan2(sv, cv), g, H


def asin_term(u):
    uv, gu, Hu = u
    uc = np.clip(uv, -1.0, 1.0)
    q = np.sqrt(np.maximum(1.0 - uc * uc, 1e-300))
    g = gu / q[:, None]
    H = None
    if Hu is not None:
        H = Hu / q[:, None, None] + (uc / q ** 3)[:, None, None] * gu[:, :, None] * gu[:, None, :]
    return np.arcsin(uc), g, H


def measure(Y, name, need_hess=True):
    """Value (n,), gradient (n, W), Hessian (n, W, W) of a motion measure (principal angles).

    * ``X``, ``Y``, ``Z``: ``DX/DY/DZ(I,J,J) = (P_I - P_J) . a_J`` (a_J = x_J, y_J, z_J);
    * ``AZ``: continuous ``AZ(I,J)`` (angle table, turns counted); derivatives of
      ``atan2(x_I . y_J, x_I . x_J)``;
    * ``B1, B2, B3``: the angles of a **body-fixed 1-2-3 sequence** of I relative to J,
      ``R = A_J^T A_I = Rx(b1) Ry(b2) Rz(b3)``: ``b2 = asin(R_02)``,
      ``b1 = atan2(-R_12, R_22)``, ``b3 = atan2(-R_01, R_00)`` with ``R_ij = a_J,i . a_I,j``
      (principal values; b2 in [-pi/2, pi/2]).

    The multiplier-weighted Hessian ``G = lam d2 phi / dy2`` is exact (FD-checked in
    ``tests/reference/test_motions.py``).
    """
    if name in _AXJ:
        a = _AXJ[name]
        return _sum(dot_term(Y, S_PI, a, 1.0, need_hess), dot_term(Y, S_PJ, a, -1.0, need_hess))
    if name == "AZ":
        return atan2_term(dot_term(Y, S_XI, S_YJ, 1.0, need_hess),
                          dot_term(Y, S_XI, S_XJ, 1.0, need_hess))

    def R(i, j, sign=1.0):        # R_ij = a_J,i . a_I,j
        return dot_term(Y, _AXJL[i], _AXI[j], sign, need_hess)
    if name == "B1":
        return atan2_term(R(1, 2, -1.0), R(2, 2))
    if name == "B2":
        return asin_term(R(0, 2))
    if name == "B3":
        return atan2_term(R(0, 1, -1.0), R(0, 0))
    raise ValueError(name)
