"""Rotation utilities, vectorised over leading axes.

Conventions: rotation matrices have the rotated frame's axes as columns (global components).
Rotation increments are *spatial* (global-frame) rotation vectors: ``R_new = expm(skew(w)) @ R``.
"""
from __future__ import annotations

import numpy as np


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
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


def expm_so3(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation matrices of rotation vectors ``w`` (..., 3) [rad]."""
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    K = skew(w)
    I = np.broadcast_to(np.eye(3), K.shape)
    return I + a[..., None, None] * K + b[..., None, None] * (K @ K)


def se3_left_jacobian(w: np.ndarray) -> np.ndarray:
    """``V(w) = I + (1-cos t)/t^2 K + (t - sin t)/t^3 K^2`` (K = skew(w), t = |w|), (..., 3, 3).

    ``exp`` of a spatial twist (w, v0) moves a point p to ``expm(w) p + V(w) v0``.
    """
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    c = np.where(small, 1.0 / 6.0 - th**2 / 120.0, (ths - np.sin(ths)) / ths**3)
    K = skew(w)
    I = np.broadcast_to(np.eye(3), K.shape)
    return I + b[..., None, None] * K + c[..., None, None] * (K @ K)


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
