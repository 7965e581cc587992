"""Frames of an Adams dataset: part reference frames and markers in global coordinates.

A part's reference frame (LPRF) is placed by ``QG`` (origin, global) and ``REULER`` (body-fixed
3-1-3 Euler angles, radians unless written with ``D``) or ``XG``/``ZG`` (a point on its z axis
and one in its x-z plane); a marker by ``QP`` and ``REULER`` or ``XP``/``ZP`` in its part's
frame. poise's XML markers are global, so the reader composes the two. Angles written in
degrees that are multiples of 90 get exact sines and cosines (0, +-1), so a frame turned by 90D
is the exact permutation a hand-written deck would give.
"""
from __future__ import annotations

import math

import numpy as np


def _cs(a: float, deg: bool) -> tuple[float, float]:
    if deg:
        d = math.degrees(a)
        q = round(d / 90.0)
        if abs(d - 90.0 * q) <= 1e-9 * max(1.0, abs(d)):
            return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[q % 4]
    return float(np.cos(a)), float(np.sin(a))      # as poise.elements.rotation.from_313


def euler313(angles, degs=(False, False, False)) -> np.ndarray:
    """Rotation matrix (columns = the rotated frame's axes) of body 3-1-3 angles."""
    (c1, s1), (c2, s2), (c3, s3) = (_cs(a, d) for a, d in zip(angles, degs))
    rz1 = np.array([[c1, -s1, 0.0], [s1, c1, 0.0], [0.0, 0.0, 1.0]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, c2, -s2], [0.0, s2, c2]])
    rz3 = np.array([[c3, -s3, 0.0], [s3, c3, 0.0], [0.0, 0.0, 1.0]])
    return rz1 @ rx @ rz3


def frame_from_points(origin, zp=None, xp=None, usexp: bool = False) -> tuple[np.ndarray | None, str]:
    """Axes of a frame from a point on its z axis (``zp``) and one in its x-z plane (``xp``),
    all in the parent frame; ``usexp``: x points at ``xp`` and z is made orthogonal to it.
    With ``zp`` alone, x is the parent's x axis (its y axis when z is within 45 degrees of
    x) made orthogonal to z. (None, message) for coincident or collinear points."""
    o = np.asarray(origin, float)

    def unit(v, what):
        n = float(np.linalg.norm(v))
        if not n > 1e-12 * max(1.0, float(np.linalg.norm(o))):
            return None, what
        return v / n, ""

    if usexp:       # x towards XP, z towards ZP made orthogonal (default: global z or x)
        first, second, names, k = xp, zp, ("XP", "ZP", "x"), 2
        refs = (np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    else:           # z towards ZP, x towards XP made orthogonal (default: global x or y)
        first, second, names, k = zp, xp, ("ZP", "XP", "z"), 0
        refs = (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    a, msg = unit(np.asarray(first, float) - o, f"{names[0]} coincides with the origin")
    if a is None:
        return None, msg
    if second is None:
        ref = refs[0] if abs(a[k]) < math.sqrt(0.5) else refs[1]
    else:
        ref = np.asarray(second, float) - o
    b, msg = unit(ref - (ref @ a) * a, f"{names[1]} lies on the {names[2]} axis given by "
                                        f"{names[0]}")
    if b is None:
        return None, msg
    x, z = (a, b) if usexp else (b, a)
    return np.column_stack([x, np.cross(z, x), z]), ""


def compose(parent_origin, parent_axes, local_origin, local_axes):
    """Global origin and axes of a frame given in a parent frame."""
    p = np.asarray(parent_origin, float) + np.asarray(parent_axes, float) @ np.asarray(local_origin, float)
    return p, np.asarray(parent_axes, float) @ np.asarray(local_axes, float)

