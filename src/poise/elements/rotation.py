"""Rotation utilities, vectorised over leading axes.

Conventions: rotation matrices have the rotated frame's axes as columns (global components).
Rotation increments are *spatial* (global-frame) rotation vectors: ``R_new = expm(skew(w)) @ R``.
"""
from __future__ import annotations

import numpy as np

from poise.core.lean import concatenate, einsum, row_norms, take_along_last, where

def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix, ``skew(v) @ u == cross(v, u)``.

    Parameters
    ----------
    v : (..., 3) array

    Returns
    -------
    (..., 3, 3) array
    """
    v = np.asarray(v, dtype=float)
    if v.size <= 1 << 13:   # small: the nine entries gathered from (v, -v, 0) in one step
        e = concatenate([v, -v, np.zeros(v.shape[:-1] + (1,))], axis=-1)
        return e.take(_SKEW, -1).reshape(v.shape[:-1] + (3, 3))
    S = np.zeros(v.shape[:-1] + (3, 3))      # large: entry by entry (no gathered copies)
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


_SKEW = np.array([6, 5, 1, 2, 6, 3, 4, 0, 6])     # row-major entries: 0 -v2 v1 / v2 0 -v0 / ...


_I3 = np.eye(3)


def _axis_parts(w):
    """``(|w|, K, K @ K)`` with ``K = skew(w)``: what Rodrigues' formulas share."""
    K = skew(w)
    return row_norms(w), K, K @ K


def _expm(th, K, KK):
    small = th < 1e-8
    ths = where(small, 1.0, th)
    a = where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    return _I3 + a[..., None, None] * K + b[..., None, None] * KK


def _left_jacobian(th, K, KK):
    small = th < 1e-6
    ths = where(small, 1.0, th)
    b = where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    c = where(small, 1.0 / 6.0 - th**2 / 120.0, (ths - np.sin(ths)) / ths**3)
    return _I3 + b[..., None, None] * K + c[..., None, None] * KK


def expm_so3(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation matrices of rotation vectors ``w`` (..., 3) [rad]."""
    return _expm(*_axis_parts(np.asarray(w, dtype=float)))


def se3_left_jacobian(w: np.ndarray) -> np.ndarray:
    """``V(w) = I + (1-cos t)/t^2 K + (t - sin t)/t^3 K^2`` (K = skew(w), t = |w|), (..., 3, 3).

    ``exp`` of a spatial twist (w, v0) moves a point p to ``expm(w) p + V(w) v0``.
    """
    return _left_jacobian(*_axis_parts(np.asarray(w, dtype=float)))


def screw_exp(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(expm_so3(w), se3_left_jacobian(w))`` (bitwise), sharing ``|w|``, ``skew(w)`` and its
    square: the rotation and translation of a spatial twist's exponential."""
    th, K, KK = parts = _axis_parts(np.asarray(w, dtype=float))
    if not np.logical_and.reduce(th >= 1e-6, axis=None):   # a small angle: the series there
        return _expm(*parts), _left_jacobian(*parts)
    # no angle small (the usual step): the closed forms alone, sin and cos taken once
    th = np.asarray(th)                   # an array like the series' (its powers, ufuncs)
    s = np.sin(th)
    a, b, c = s / th, (1.0 - np.cos(th)) / th**2, (th - s) / th**3
    b = b[..., None, None]
    # (I + a K) + b KK and (I + b K) + c KK, the same operations into two arrays (at 10^5
    # bodies each temporary is 7 MB)
    E = a[..., None, None] * K
    E += _I3
    E += b * KK
    V = np.multiply(b, K, out=K)
    V += _I3
    V += np.multiply(c[..., None, None], KK, out=KK)
    return E, V


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrices (polar decomposition via SVD), (..., 3, 3)."""
    U, _, Vt = np.linalg.svd(R)
    D = np.linalg.det(U @ Vt)
    U[..., :, 2] *= D[..., None]
    return U @ Vt


def from_euler_parameters(e0, e1, e2, e3) -> np.ndarray:
    """Rotation matrix of Euler parameters (unit quaternion, e0 scalar part)."""
    q = np.array([e0, e1, e2, e3], dtype=float)
    n = np.linalg.norm(q)
    if n == 0:
        raise ValueError("Euler parameters are all zero")
    e0, e1, e2, e3 = q / n
    return np.array([
        [e0**2 + e1**2 - e2**2 - e3**2, 2 * (e1 * e2 - e0 * e3), 2 * (e1 * e3 + e0 * e2)],
        [2 * (e1 * e2 + e0 * e3), e0**2 - e1**2 + e2**2 - e3**2, 2 * (e2 * e3 - e0 * e1)],
        [2 * (e1 * e3 - e0 * e2), 2 * (e2 * e3 + e0 * e1), e0**2 - e1**2 - e2**2 + e3**2],
    ])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def from_313(psi, theta, phi) -> np.ndarray:
    """Body-fixed 3-1-3 Euler angles [rad]: rotate psi about z, theta about new x, phi about new z."""
    return _rz(psi) @ _rx(theta) @ _rz(phi)


def from_ypr(yaw, pitch, roll) -> np.ndarray:
    """Body-fixed yaw (about z), pitch (about the *negative* new y), roll (about new x) [rad]."""
    return _rz(yaw) @ _ry(-pitch) @ _rx(roll)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap to (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


_DIAG = np.array([0, 4, 8])
_SG = np.array([[1.0, 1.0, -1.0, -1.0], [1.0, -1.0, 1.0, -1.0], [1.0, -1.0, -1.0, 1.0]])
_OFF_A = np.array([7, 2, 3, 1, 2, 5])              # R21, R02, R10, R01, R02, R12
_OFF_B = np.array([5, 6, 1, 3, 6, 7])              # R12, R20, R01, R10, R20, R21
_OFF_SG = np.array([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0])
# M row-major from (t0, t1, t2, t3, s21, s02, s10, p01, p02, p12)
_M16 = np.array([0, 4, 5, 6, 4, 1, 7, 8, 5, 7, 2, 9, 6, 8, 9, 3])
_ROWS = np.arange(16).reshape(4, 4)


def euler_parameters(R: np.ndarray) -> np.ndarray:
    """Euler parameters (unit quaternion ``e0, e1, e2, e3``) of rotation matrices (..., 3, 3).

    Inverse of :func:`from_euler_parameters` (Shepperd's method: the largest of the four
    squares is taken from the diagonal, so it is accurate at every angle). Sign convention:
    ``e0 >= 0``; at exactly 180 deg (``e0 == 0``) the first non-zero of ``e1, e2, e3`` is > 0.
    """
    R = np.asarray(R, float)
    R9 = R.reshape(R.shape[:-2] + (9,))
    D = R9.take(_DIAG, -1)
    # the diagonal of M = 4 q q^T: 1 +- d0 +- d1 +- d2 (a sign times an entry is exact: the
    # sums of the formulas, in their order); off the diagonal s21, s02, s10 (R_ij - R_ji) and
    # p01, p02, p12 (R_ij + R_ji)
    T = ((1 + D[..., 0:1] * _SG[0]) + D[..., 1:2] * _SG[1]) + D[..., 2:3] * _SG[2]
    X = R9.take(_OFF_A, -1) + R9.take(_OFF_B, -1) * _OFF_SG
    M = concatenate([T, X], -1).take(_M16, -1)            # (..., 16), row-major
    # its row with the largest diagonal is q times the largest |q_k|
    q = take_along_last(M, _ROWS[T.argmax(axis=-1)])
    # sign: e0 > 0, else the first non-zero vector component > 0 (deterministic at 180 deg)
    lead = take_along_last(q, (q != 0).argmax(axis=-1)[..., None])[..., 0]
    q = where((lead < 0)[..., None], -q, q)
    return q / row_norms(q)[..., None]


def euler_313(R: np.ndarray, singular_tol: float = 1e-14) -> np.ndarray:
    """Body-fixed 3-1-3 angles ``(psi, theta, phi)`` [rad] of rotation matrices (..., 3, 3).

    ``R = Rz(psi) Rx(theta) Rz(phi)`` (:func:`from_313`, the MotionSolve convention),
    ``theta`` in [0, pi], ``psi`` and ``phi`` in (-pi, pi]. ``psi + phi`` (for theta <= pi/2)
    or ``psi - phi`` (theta > pi/2) is taken from the well-conditioned 2x2 block, so the angles
    reconstruct ``R`` to rounding at any tilt. Gimbal lock (``sin(theta) <= singular_tol``):
    only ``psi +- phi`` is defined; then ``phi = 0`` and ``psi`` carries the whole turn.
    """
    R = np.asarray(R, float)
    st = np.hypot(R[..., 0, 2], R[..., 1, 2])
    theta = np.arctan2(st, R[..., 2, 2])
    psi_d = np.arctan2(R[..., 0, 2], -R[..., 1, 2])
    phi_d = np.arctan2(R[..., 2, 0], R[..., 2, 1])
    up = R[..., 2, 2] >= 0
    sig = np.arctan2(R[..., 1, 0] - R[..., 0, 1], R[..., 0, 0] + R[..., 1, 1])   # psi + phi
    dif = np.arctan2(R[..., 1, 0] + R[..., 0, 1], R[..., 0, 0] - R[..., 1, 1])   # psi - phi
    sing = st <= singular_tol
    locked = bool(np.logical_or.reduce(sing, axis=None))
    if locked:
        psi_d = where(sing, 0.0, psi_d)
        phi_d = where(sing, 0.0, phi_d)
    # the well-conditioned sum (or difference) less the one of the direct angles, wrapped
    # (elementwise: the branch of each entry's tilt, one wrap for both)
    sd = where(up, sig, dif)
    c = wrap_angle(sd - where(up, psi_d + phi_d, psi_d - phi_d))
    psi = psi_d + 0.5 * c
    phi = phi_d + where(up, 0.5, -0.5) * c
    if locked:
        psi = where(sing, sd, psi)
        phi = where(sing, 0.0, phi)
    return np.stack([wrap_angle(psi), theta, wrap_angle(phi)], -1)


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """Principal rotation vectors (..., 3) of rotation matrices, ``|v|`` in [0, pi]
    (``expm_so3(v) == R``), from the Euler parameters (accurate at every angle)."""
    q = euler_parameters(R)
    s = row_norms(q[..., 1:])
    th = 2.0 * np.arctan2(s, q[..., 0])
    f = where(s > 0, th / where(s > 0, s, 1.0), 2.0)
    return f[..., None] * q[..., 1:]


def lift_rotation_vector(v: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """The rotation vector equivalent to ``v`` (same rotation: ``n (|v| + 2 pi k)``, k any
    integer, n = v/|v|) whose signed length along n is nearest ``guess``'s; (..., 3). Unwraps rotation vectors along a path
    (turns counted) given a prediction closer than pi to the answer."""
    v = np.asarray(v, float)
    g = np.asarray(guess, float)
    a = row_norms(v)
    gn = row_norms(g)
    small = a < 1e-300
    n = where(small[..., None], g / where(gn > 0, gn, 1.0)[..., None],
                 v / where(small, 1.0, a)[..., None])
    # signed length of the guess: the angle |v| moves by n.w to first order for any increment
    # w, so this stays right when the axis tilts (a projection g.n would shrink)
    p = where(einsum("...i,...i->...", g, n) < 0, -gn, gn)
    k = np.round((p - a) / (2.0 * np.pi))
    return (a + 2.0 * np.pi * k)[..., None] * n
