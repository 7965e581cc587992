"""Spline interpolation for AKISPL / CUBSPL / LINSPL / FITSPL (deck_format.md §6.2, §8.4).

``AKISPL``: Akima spline (local, scipy ``Akima1DInterpolator``); ``CUBSPL``: global cubic
spline with **not-a-knot** end conditions (scipy ``CubicSpline`` default); ``LINSPL``: linear;
``FITSPL``: FITPACK's interpolating quadratic B-spline (MotionSolve: order 3, at least 4 points).

Every curve is stored as piecewise cubic coefficients ``(4, nseg)`` (highest power first) and
evaluated with Horner's rule, so the value, the requested derivative order (0..2) and its
derivative w.r.t. x (order + 1) are exact.

Outside ``[x[0], x[-1]]``: with ``linear_extrap`` the curve continues as a straight line with the
end slope (orders 1 and 2 then give the slope and 0); otherwise the end polynomial piece is
continued.

2-D families ``y(x, z)`` are interpolated linearly in z (see :class:`PreparedSpline`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["PreparedSpline", "SPLINE_KINDS"]

SPLINE_KINDS = ("AKISPL", "CUBSPL", "LINSPL", "FITSPL")


def _fitspl(x: np.ndarray, y: np.ndarray):
    """FITSPL: FITPACK's interpolating B-spline of order 3 (quadratic pieces, knots between the
    data points, Dierckx ``curfit`` with s = 0, scipy ``splrep(k=2, s=0)``) as piecewise
    polynomials ``(4, nseg)`` on their own breakpoints."""
    from scipy.interpolate import PPoly, splrep       # lazy: only decks with FITSPL curves
    pp = PPoly.from_spline(splrep(x, y, k=2, s=0))
    bx = np.asarray(pp.x, float)
    keep = np.flatnonzero(np.diff(bx) > 0)             # drop the repeated end knots
    c = np.zeros((4, len(keep)))
    c[1:] = pp.c[:, keep]
    return c, np.concatenate([bx[keep], bx[keep[-1] + 1:keep[-1] + 2]])


def _coefs(kind: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    if kind == "LINSPL" or len(x) < 3:
        c = np.zeros((4, len(x) - 1))
        c[2] = np.diff(y) / np.diff(x)
        c[3] = y[:-1]
        return c
    # scipy.interpolate (with scipy.optimize/spatial/special: ~0.1-0.7 s) only when a deck has
    # an AKISPL/CUBSPL curve of 3+ points, not whenever the expression language is loaded
    if kind == "AKISPL":
        from scipy.interpolate import Akima1DInterpolator
        return np.array(Akima1DInterpolator(x, y).c, dtype=float)
    from scipy.interpolate import CubicSpline
    return np.array(CubicSpline(x, y).c, dtype=float)


def _horner(c, t, order):
    """Derivative ``order`` (0..3) of ``c0 t^3 + c1 t^2 + c2 t + c3``; ``c`` is (4, ...)."""
    if order == 0:
        return ((c[0] * t + c[1]) * t + c[2]) * t + c[3]
    if order == 1:
        return (3.0 * c[0] * t + 2.0 * c[1]) * t + c[2]
    if order == 2:
        return 6.0 * c[0] * t + 2.0 * c[1]
    return 6.0 * c[0] + 0.0 * t


class PreparedSpline:
    """A Reference_Spline prepared for one interpolation kind.

    2-D families ``y(x, z)`` (one curve per z value, ``y`` shaped ``(nz, nx)``; an ``(nx, nz)`` table
    is transposed) are interpolated **linearly in z** between the two neighbouring curves (and
    extrapolated linearly from the two end curves outside the z range).

    Parameters
    ----------
    kind : str
        ``"AKISPL"``, ``"CUBSPL"`` or ``"LINSPL"``.
    x : (nx,) array_like
        Strictly increasing abscissae (nx >= 2).
    y : (nx,) or (nz, nx) array_like
        Ordinates (one row per z curve for a family).
    z : (nz,) array_like or None
        Strictly increasing z values of a family (nz >= 2), else None.
    linear_extrap : bool
        Extrapolate linearly with the end slope outside the x range.

    Raises
    ------
    ValueError
        On inconsistent data (message suitable for a deck error).
    """

    def __init__(self, kind, x, y, z=None, linear_extrap=False):
        x = np.asarray(x, dtype=float).ravel()
        y = np.asarray(y, dtype=float)
        if len(x) < 2:
            raise ValueError("spline needs at least 2 points")
        if not np.all(np.diff(x) > 0):
            raise ValueError("spline x values must be strictly increasing")
        if z is not None and np.ndim(y) == 2:
            z = np.asarray(z, dtype=float).ravel()
            if y.shape == (len(x), len(z)) and y.shape != (len(z), len(x)):
                y = y.T
            if y.shape != (len(z), len(x)):
                raise ValueError(f"spline table shape {y.shape} does not match "
                                 f"{len(z)} z values x {len(x)} x values")
            if len(z) < 2:
                y, z = y[0], None
            elif not np.all(np.diff(z) > 0):
                raise ValueError("spline z values must be strictly increasing")
        else:
            z = None
            y = y.ravel()
            if y.shape != x.shape:
                raise ValueError(f"spline has {len(x)} x values but {y.size} y values")
        self.kind = kind
        self.x = x
        self.z = z
        self.linear_extrap = bool(linear_extrap)
        ys = y[None, :] if z is None else y
        self.bx = x                                        # breakpoints of the pieces
        if kind == "FITSPL":
            if len(x) < 4:
                raise ValueError("FITSPL needs at least 4 points")
            fits = [_fitspl(x, row) for row in ys]
            self.bx = fits[0][1]
            self.c = np.stack([f[0] for f in fits])
        else:
            self.c = np.stack([_coefs(kind, x, row) for row in ys])       # (nc, 4, nseg)
        self.y0 = ys[:, 0]
        self.yn = ys[:, -1]
        self.s0 = self.c[:, 2, 0]
        h = self.bx[-1] - self.bx[-2]
        self.sn = _horner(self.c[:, :, -1].T, h, 1)

    def _curve(self, k, xq, order):
        """Value of derivative ``order`` and its x-derivative on curve(s) ``k`` ((m,) ints)."""
        x = self.bx
        idx = np.clip(np.searchsorted(x, xq, side="right") - 1, 0, len(x) - 2)
        t = xq - x[idx]
        c = self.c[k, :, idx].T                                            # (4, m)
        v = _horner(c, t, order)
        dv = _horner(c, t, order + 1)
        if self.linear_extrap:
            for mask, xe, ye, se in ((xq < x[0], x[0], self.y0[k], self.s0[k]),
                                     (xq > x[-1], x[-1], self.yn[k], self.sn[k])):
                if mask.any():
                    lin = (ye + se * (xq - xe), se, 0.0)[order]
                    v = np.where(mask, lin, v)
                    dv = np.where(mask, se if order == 0 else 0.0, dv)
        return v, dv

    def evaluate(self, xq, zq, order: int = 0):
        """Evaluate at ``m`` points.

        Parameters
        ----------
        xq, zq : (m,) ndarray
            Query x and z (z ignored for a single curve).
        order : int
            0 value, 1 dy/dx, 2 d2y/dx2.

        Returns
        -------
        value, d_dx, d_dz : (m,) ndarray
        """
        xq = np.asarray(xq, dtype=float)
        if self.z is None:
            k = np.zeros(xq.shape, dtype=np.intp)
            v, dv = self._curve(k, xq, order)
            return v, dv, np.zeros_like(xq)
        z = self.z
        kz = np.clip(np.searchsorted(z, zq, side="right") - 1, 0, len(z) - 2)
        dz = z[kz + 1] - z[kz]
        w = (zq - z[kz]) / dz
        v0, d0 = self._curve(kz, xq, order)
        v1, d1 = self._curve(kz + 1, xq, order)
        return (1.0 - w) * v0 + w * v1, (1.0 - w) * d0 + w * d1, (v1 - v0) / dz
