"""Kinematic measures (deck_format.md §8.2) with exact derivatives w.r.t. marker vectors.

A measure reads *slot vectors*: a marker origin ``P_I`` (slot kind 0) or one axis column of a
marker (kind 1/2/3 = x/y/z axis), all ``(m, 3)`` in global components. Each measure declares
which vectors it reads (:data:`MEASURE_SLOTS`) and :func:`eval_measure` returns the value and
``d value / d vector`` for every declared vector.

Marker index -1 is the global frame (origin 0, identity axes); derivatives w.r.t. its vectors
are computed but discarded by the caller. The angle conventions (AX/AY/AZ, PSI/THETA/PHI,
YAW/PITCH/ROLL, gimbal lock) are documented at :func:`eval_measure`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["MEASURE_SLOTS", "MEASURE_ARITY", "CONTINUOUS", "VELOCITY_MEASURES", "eval_measure"]

# slot spec: tuple of (which marker argument: 0=I, 1=J, 2=K, kind)
MEASURE_SLOTS = {
    "DX": ((0, 0), (1, 0), (2, 1)),
    "DY": ((0, 0), (1, 0), (2, 2)),
    "DZ": ((0, 0), (1, 0), (2, 3)),
    "DM": ((0, 0), (1, 0)),
    # generic atan2(u.s, sign * u.c): slots (u, c, s)
    "AX": ((0, 2), (1, 2), (1, 3)),
    "AY": ((0, 3), (1, 3), (1, 1)),
    "AZ": ((0, 1), (1, 1), (1, 2)),
    "YAW": ((0, 1), (1, 1), (1, 2)),
    "PSI": ((0, 3), (1, 2), (1, 1), (0, 1)),      # z_I, y_J, x_J, x_I (lock branch)
    "PHI": ((1, 3), (0, 2), (0, 1)),
    "ROLL": ((1, 3), (0, 3), (0, 2)),
    # hypot forms: slots (u, a, b, c)
    "THETA": ((0, 3), (1, 1), (1, 2), (1, 3)),
    "PITCH": ((0, 1), (1, 1), (1, 2), (1, 3)),
    # the included angle at J between the lines to I and to K: slots (P_I, P_J, P_K)
    "INCANG": ((0, 0), (1, 0), (2, 0)),
}
# AXU/AYU/AZU: MotionSolve's unwrapped AX/AY/AZ; poise's AX/AY/AZ already count turns
for _a in ("AX", "AY", "AZ"):
    MEASURE_SLOTS[_a + "U"] = MEASURE_SLOTS[_a]
MEASURE_ARITY = {"DX": (1, 3), "DY": (1, 3), "DZ": (1, 3), "DM": (1, 3), "INCANG": (3, 3)}
MEASURE_ARITY.update({k: (1, 2) for k in ("AX", "AY", "AZ", "AXU", "AYU", "AZU", "YAW", "PSI",
                                          "PHI", "ROLL", "THETA", "PITCH")})
CONTINUOUS = {"AX": 0, "AY": 1, "AZ": 2, "AXU": 0, "AYU": 1, "AZU": 2}
"""Angle measures made continuous through ``ctx.angle``; value = axis code for angle_key."""

VELOCITY_MEASURES = {}
for _n in ("VX", "VY", "VZ", "ACCX", "ACCY", "ACCZ", "WDTX", "WDTY", "WDTZ"):
    VELOCITY_MEASURES[_n] = (1, 4)
for _n in ("VM", "VR", "ACCM", "WX", "WY", "WZ", "WM", "WDTM"):
    VELOCITY_MEASURES[_n] = (1, 4 if _n in ("ACCM", "WDTM") else 3)
"""Velocity / acceleration measures: identically 0 in static analyses (arguments validated)."""

_CSIGN = {"PSI": -1.0}
EULER_LOCK_TOL = 1e-10
"""|sin(theta)| at or below which PSI/PHI use the gimbal-lock convention phi = 0."""
_TWO_PI = 2.0 * np.pi


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _atan2_grad(s, c):
    r2 = s * s + c * c
    ok = r2 > 0
    inv = np.where(ok, 1.0 / np.where(ok, r2, 1.0), 0.0)
    return np.arctan2(s, c), c * inv, -s * inv


def wrap_to_ref(p, ref):
    """``ref + wrap(p - ref)`` with wrap to (-pi, pi]."""
    d = p - ref
    return ref + (np.pi - np.mod(np.pi - d, _TWO_PI))


def eval_measure(name: str, vecs: list, ref=None):
    """Evaluate one measure for m instances.

    Angles
    ------
    * ``AX/AY/AZ(I, J)`` – ``AZ = atan2(xI.yJ, xI.xJ)``, ``AX = atan2(yI.zJ, yI.yJ)``,
      ``AY = atan2(zI.xJ, zI.zJ)``; made continuous with a reference value (``ref + wrap(p - ref)``).
    * ``PSI/THETA/PHI(I, J)`` – body-fixed 3-1-3 Euler angles of ``R = A_J^T A_I``:
      ``psi = atan2(R13, -R23)``, ``theta = atan2(hypot(R13, R23), R33)``, ``phi = atan2(R31, R32)``.
      At gimbal lock (``sin(theta) = hypot(R13, R23)`` resp. ``hypot(R31, R32)`` at most
      :data:`EULER_LOCK_TOL`: theta = 0 or pi, every planar rotation about a common z axis) the
      split of the rotation between psi and phi is undefined; the convention is ``phi = 0``,
      ``psi = atan2(R21, R11)`` (so ``R = Rz(psi) Rx(theta)``), with the derivative of that branch
      (psi reads x_I as a fourth slot; phi's gradient is 0 there).
    * ``YAW/PITCH/ROLL(I, J)`` – ``R = Rz(yaw) Ry(-pitch) Rx(roll)``:
      ``yaw = atan2(R21, R11)``, ``pitch = atan2(R31, hypot(R11, R21))``, ``roll = atan2(R32, R33)``.

    Included angle
    --------------
    * ``INCANG(I, J, K)`` – the angle at J between the lines J-I and J-K,
      ``atan2(|a x b|, a . b)`` with ``a = P_I - P_J``, ``b = P_K - P_J``: in [0, pi].

    At singular points (zero distance for ``DM``, gimbal lock for THETA/YAW/PITCH/ROLL,
    collinear or coincident points for ``INCANG``) the gradient is set to 0 instead of NaN.

    Parameters
    ----------
    name : str
        Measure name (key of :data:`MEASURE_SLOTS`).
    vecs : list of (m, 3) ndarray
        Slot vectors in the order of ``MEASURE_SLOTS[name]``.
    ref : (m,) ndarray or None
        Continuity reference for AX/AY/AZ (None -> principal value in (-pi, pi]).

    Returns
    -------
    value : (m,) ndarray
    grads : list of (m, 3) ndarray
        d value / d vecs[k].
    """
    if name in ("DX", "DY", "DZ"):
        pi, pj, e = vecs
        d = pi - pj
        return _dot(d, e), [e, -e, d]
    if name == "DM":
        pi, pj = vecs
        d = pi - pj
        r = np.sqrt(_dot(d, d))
        ok = r > 0
        g = d * np.where(ok, 1.0 / np.where(ok, r, 1.0), 0.0)[:, None]
        return r, [g, -g]
    if name == "INCANG":
        return _incang(*vecs)
    if name in ("THETA", "PITCH"):
        u, a, b, c = vecs
        sa, sb, sc = _dot(u, a), _dot(u, b), _dot(u, c)
        h = np.sqrt(sa * sa + sb * sb)
        ok = h > 0
        hinv = np.where(ok, 1.0 / np.where(ok, h, 1.0), 0.0)
        if name == "THETA":          # atan2(h, sc)
            v, dy, dx = _atan2_grad(h, sc)
            dh, dc = dy, dx
        else:                        # atan2(sc, h)
            v, dy, dx = _atan2_grad(sc, h)
            dh, dc = dx, dy
        dsa = (dh * sa * hinv)[:, None]
        dsb = (dh * sb * hinv)[:, None]
        dcc = dc[:, None]
        gu = dsa * a + dsb * b + dcc * c
        return v, [gu, dsa * u, dsb * u, dcc * u]
    if name == "PSI":
        return _psi(*vecs)
    u, cv, sv = vecs
    sg = _CSIGN.get(name, 1.0)
    s = _dot(u, sv)
    c = sg * _dot(u, cv)
    v, ds, dc = _atan2_grad(s, c)
    ds2, dc2 = ds[:, None], (sg * dc)[:, None]
    grads = [ds2 * sv + dc2 * cv, dc2 * u, ds2 * u]
    if name == "PHI":                # sin(theta) = hypot(R31, R32): lock -> phi = 0
        lock = np.hypot(s, c) <= EULER_LOCK_TOL
        if lock.any():
            v = np.where(lock, 0.0, v)
            grads = [np.where(lock[:, None], 0.0, g) for g in grads]
    if ref is not None:
        v = wrap_to_ref(v, ref)
    return v, grads


def _incang(pi, pj, pk):
    """``atan2(|a x b|, a . b)``: d|n|/da = b x n^, d|n|/db = n^ x a (n = a x b)."""
    a, b = pi - pj, pk - pj
    n = np.cross(a, b)
    s = np.sqrt(_dot(n, n))
    ok = s > 0
    nh = n * np.where(ok, 1.0 / np.where(ok, s, 1.0), 0.0)[:, None]
    v, ds, dc = _atan2_grad(s, _dot(a, b))
    ga = ds[:, None] * np.cross(b, nh) + dc[:, None] * b
    gb = ds[:, None] * np.cross(nh, a) + dc[:, None] * a
    ga = np.where(ok[:, None], ga, 0.0)
    gb = np.where(ok[:, None], gb, 0.0)
    return v, [ga, -(ga + gb), gb]


def _psi(zI, yJ, xJ, xI):
    """PSI = atan2(R13, -R23); at gimbal lock atan2(R21, R11) (``R_ij = a_J,i . a_I,j``)."""
    r13, r23 = _dot(zI, xJ), _dot(zI, yJ)
    v, ds, dc = _atan2_grad(r13, -r23)
    ds2, dc2 = ds[:, None], dc[:, None]
    g = [ds2 * xJ - dc2 * yJ, -dc2 * zI, ds2 * zI, np.zeros_like(xI)]
    lock = np.hypot(r13, r23) <= EULER_LOCK_TOL
    if lock.any():
        vl, dsl, dcl = _atan2_grad(_dot(yJ, xI), _dot(xJ, xI))
        dsl, dcl = dsl[:, None], dcl[:, None]
        gl = [np.zeros_like(zI), dsl * xI, dcl * xI, dsl * yJ + dcl * xJ]
        L = lock[:, None]
        v = np.where(lock, vl, v)
        g = [np.where(L, b, a) for a, b in zip(g, gl)]
    return v, g
