"""Higher-pair constraints on parametric curves and surfaces (PTCV, CVCV, PTSF, CVSF, SFSF).

The curve/surface parameters are scalar unknowns (``Family.scols``). Every equation is a
polynomial in the slot vectors (marker origins and axes) and in the curve/surface points and
derivatives, so each family writes its rows once with second-order **jets**
(:class:`Jet`: value, gradient and Hessian with respect to the ``3S + U`` local variables). That
gives ``phi``, ``phi_y``, ``phi_s`` and the multiplier-weighted Hessian blocks ``G``, ``G_ys``,
``G_ss`` exactly (given the parameter derivatives of the geometry, see
:mod:`poise.elements.curve_data`).

Notation, the equations of each kind and friction: :class:`CurveFamily`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.elements.base import ConstraintFamily


class Jet:
    """Second-order jet: value ``v`` (n, *shape), gradient ``g`` (n, *shape, N), Hessian ``H``."""

    __slots__ = ("v", "g", "H")

    def __init__(self, v, g, H):
        self.v, self.g, self.H = v, g, H

    def __add__(self, o):
        return Jet(self.v + o.v, self.g + o.g, self.H + o.H)

    def __sub__(self, o):
        return Jet(self.v - o.v, self.g - o.g, self.H - o.H)

    def __mul__(self, o):
        if not isinstance(o, Jet):          # constant (broadcastable to v)
            o = np.asarray(o, float)
            return Jet(self.v * o, self.g * o[..., None], self.H * o[..., None, None])
        a, b = self, o
        g = a.v[..., None] * b.g + b.v[..., None] * a.g
        ab = a.g[..., :, None] * b.g[..., None, :]
        H = (a.v[..., None, None] * b.H + b.v[..., None, None] * a.H + ab
             + np.swapaxes(ab, -1, -2))
        return Jet(a.v * b.v, g, H)

    __rmul__ = __mul__

    def __getitem__(self, i):                # component of a vector jet (last value axis)
        return Jet(self.v[..., i], self.g[..., i, :], self.H[..., i, :, :])

    def sum(self):                           # sum over the last value axis
        return Jet(self.v.sum(-1), self.g.sum(-2), self.H.sum(-3))


def jstack(parts):
    return Jet(np.stack([p.v for p in parts], -1), np.stack([p.g for p in parts], -2),
               np.stack([p.H for p in parts], -3))


def dot(a, b):
    return (a * b).sum()


def cross(a, b):
    return jstack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                   a[0] * b[1] - a[1] * b[0]])


def variable(values, first, N):
    """Jet of independent variables ``values`` (n, k) occupying columns first..first+k-1."""
    n, k = values.shape
    g = np.zeros((n, k, N))
    g[:, np.arange(k), first + np.arange(k)] = 1.0
    return Jet(values.copy(), g, np.zeros((n, k, N, N)))


def curve_jet(d, col, N):
    """Jets of ``c^(m)(u)`` for m = 0 .. len(d) - 3, ``u`` the variable in column ``col``.

    ``d`` (M, n, 3): derivatives c, c', c'', ... at u."""
    out = []
    n = d.shape[1]
    for m in range(len(d) - 2):
        g = np.zeros((n, 3, N))
        g[:, :, col] = d[m + 1]
        H = np.zeros((n, 3, N, N))
        H[:, :, col, col] = d[m + 2]
        out.append(Jet(d[m].copy(), g, H))
    return out


def surface_jet(d, cu, cv, N, which=((0, 0), (1, 0), (0, 1))):
    """Jets of ``d^(i+j) s / du^i dv^j`` for (i, j) in ``which``; ``d`` from ``derivs``."""
    out = {}
    for (i, j) in which:
        v = d[(i, j)]
        n = v.shape[0]
        g = np.zeros((n, 3, N))
        g[:, :, cu] = d[(i + 1, j)]
        g[:, :, cv] = d[(i, j + 1)]
        H = np.zeros((n, 3, N, N))
        H[:, :, cu, cu] = d[(i + 2, j)]
        H[:, :, cv, cv] = d[(i, j + 2)]
        H[:, :, cu, cv] = d[(i + 1, j + 1)]
        H[:, :, cv, cu] = d[(i + 1, j + 1)]
        out[(i, j)] = Jet(v.copy(), g, H)
    return out


def rotate(ax, c):
    """``A c = c_1 x + c_2 y + c_3 z`` with axes jets ``ax`` = (x, y, z) and a 3-vector jet or
    constant array ``c`` (n, 3)."""
    if isinstance(c, Jet):
        return ax[0] * jstack([c[0]] * 3) + ax[1] * jstack([c[1]] * 3) + ax[2] * jstack([c[2]] * 3)
    return ax[0] * c[:, 0:1] + ax[1] * c[:, 1:2] + ax[2] * c[:, 2:3]


@dataclass(frozen=True, eq=False, kw_only=True)
class CurveFamily(ConstraintFamily):
    """Common machinery: slot/scalar jets, row jets -> kernel blocks.

    Subclasses set ``kind`` and implement ``rows(Y, s, N, memo) -> list of scalar Jets``.
    Fields: ``geo`` (per instance: tuple of curve/surface objects), ``plane`` (CVCV: (n, 3, 3)
    columns e1, e2, n in J axes; else None); ``geo_groups`` per geometry slot the instances
    sharing each object (:func:`geometry_groups`).

    Notation: ``A_K c = c_1 x_K + c_2 y_K + c_3 z_K`` for a marker K with axes ``x_K, y_K, z_K``;
    curve on body of marker K: ``r(u) = P_K + A_K c(u)``, tangent ``t = A_K c'(u)``; surface:
    ``r(u, v) = P_K + A_K s(u, v)``, tangents ``A_K s_u``, ``A_K s_v``.

    Equations (rows, unknowns, net freedoms removed):

    * PTCV ``P_I - P_J - A_J c(u) = 0`` (3 rows, u; removes 2).
    * CVCV (curves in parallel planes, msolve): with ``d = r_i(u_i) - r_j(u_j)`` and the in-plane
      basis ``e1, e2`` / normal ``n`` of curve J's plane (constant in J, found at compile time):
      ``d . e1 = 0``, ``d . e2 = 0``, ``(t_i x t_j) . n = 0`` (3 rows, u_i, u_j; removes 1). The
      out-of-plane offset is free.
    * PTSF ``P_I - P_J - A_J s(u, v) = 0`` (3 rows, u, v; removes 1).
    * CVSF ``r_c(u) - r_s(s, t) = 0`` (3 rows) and ``t_c . (A_J (s_s x s_t)) = 0`` (curve tangent in
      the surface's tangent plane) (4 rows, u, s, t; removes 1).
    * SFSF ``r_i(u_i, v_i) - r_j(u_j, v_j) = 0`` (3 rows) and the common normal
      ``n_i . (A_J s_j,u) = 0``, ``n_i . (A_J s_j,v) = 0`` with ``n_i = A_I (s_i,u x s_i,v)``
      (5 rows, u_i, v_i, u_j, v_j; removes 1).

    Frictionless: the reactions do no work along the parameters (the parameter rows of the residual
    are ``phi_s^T lam = 0``), added by the model.
    """

    kind = ""
    inertial_extras = True     # MKEAM carries the parameters with a fictitious mass

    geo: tuple
    geo_groups: tuple
    plane: np.ndarray | None = None

    def constraints(self, kin, lam, ctx):
        n = self.n
        S = kin.Y.shape[1]
        U = self.U
        N = 3 * S + U
        Y = [variable(kin.Y[:, k], 3 * k, N) for k in range(S)]
        s = ctx.extra[self.scols]
        rows = self.rows(Y, s, N, ctx.workspace)
        phi = np.stack([r.v for r in rows], 1)
        g = np.stack([r.g for r in rows], 1)               # (n, m, N)
        H = np.einsum("nm,nmab->nab", lam, np.stack([r.H for r in rows], 1))
        ext = {"phi_s": g[:, :, 3 * S:], "G_ys": H[:, :3 * S, 3 * S:], "G_ss": H[:, 3 * S:, 3 * S:]}
        assert phi.shape == (n, self.m)
        return phi, g[:, :, :3 * S], H[:, :3 * S, :3 * S], ext

    # geometry helpers: grouped evaluation over instances sharing a curve/surface object;
    # ``ws`` the solve's workspace (analytic geometry keeps its tiled programs there) or None
    def curve_derivs(self, which, u, order, ws=None):
        n = len(u)
        out = np.zeros((order + 1, n, 3))
        for obj, idx in self.geo_groups[which]:
            out[:, idx] = obj.derivs(u[idx], order, _memo(ws, obj))
        return out

    def surface_derivs(self, which, u, v, order, ws=None):
        n = len(u)
        out = {(i, j): np.zeros((n, 3)) for i in range(order + 1) for j in range(order + 1 - i)}
        for obj, idx in self.geo_groups[which]:
            d = obj.derivs(u[idx], v[idx], order, _memo(ws, obj))
            for k in out:
                out[k][idx] = d[k]
        return out

    def contact(self, kin, extra):
        """Global contact points (n, 3) (for outputs)."""
        raise NotImplementedError


def _memo(ws, obj):
    return None if ws is None else ws.scratch(obj, dict)


def geometry_groups(geo) -> tuple:
    """Per geometry slot ``which`` of ``geo`` (per instance a tuple of curve/surface objects):
    ``((object, instance indices), ...)`` of the instances sharing each object."""
    out = []
    for which in range(len(geo[0]) if geo else 0):
        objs = [g[which] for g in geo]
        out.append(tuple((obj, np.array([i for i, o in enumerate(objs) if o is obj]))
                         for obj in dict.fromkeys(objs)))
    return tuple(out)


# slots: PTCV/PTSF: P_I, P_J, x_J, y_J, z_J (S=5); CV*/SF*: P_I, x_I, y_I, z_I, P_J, x_J, y_J, z_J
SLOTS_PT = (np.array([0, 1, 1, 1, 1]), np.array([0, 0, 1, 2, 3]))
SLOTS_2 = (np.array([0, 0, 0, 0, 1, 1, 1, 1]), np.array([0, 1, 2, 3, 0, 1, 2, 3]))


class PointOnCurve(CurveFamily):
    kind = "PTCV"

    def rows(self, Y, s, N, ws=None):
        c = curve_jet(self.curve_derivs(0, s[:, 0], 2, ws), 15, N)[0]
        d = Y[0] - Y[1] - rotate(Y[2:5], c)
        return [d[0], d[1], d[2]]

    def contact(self, kin, extra):
        s = extra[self.scols]
        c = self.curve_derivs(0, s[:, 0], 0)[0]
        return kin.Y[:, 1] + np.einsum("nci,nc->ni", kin.Y[:, 2:5], c)


class PointOnSurface(CurveFamily):
    kind = "PTSF"

    def rows(self, Y, s, N, ws=None):
        d = self.surface_derivs(0, s[:, 0], s[:, 1], 2, ws)
        sj = surface_jet(d, 15, 16, N, which=((0, 0),))[(0, 0)]
        r = Y[0] - Y[1] - rotate(Y[2:5], sj)
        return [r[0], r[1], r[2]]

    def contact(self, kin, extra):
        s = extra[self.scols]
        c = self.surface_derivs(0, s[:, 0], s[:, 1], 0)[(0, 0)]
        return kin.Y[:, 1] + np.einsum("nci,nc->ni", kin.Y[:, 2:5], c)


class CurveOnCurve(CurveFamily):
    kind = "CVCV"

    def rows(self, Y, s, N, ws=None):
        ci, ti = curve_jet(self.curve_derivs(0, s[:, 0], 3, ws), 24, N)
        cj, tj = curve_jet(self.curve_derivs(1, s[:, 1], 3, ws), 25, N)
        AI, AJ = Y[1:4], Y[5:8]
        d = Y[0] + rotate(AI, ci) - Y[4] - rotate(AJ, cj)
        e1 = rotate(AJ, self.plane[:, :, 0])
        e2 = rotate(AJ, self.plane[:, :, 1])
        nJ = rotate(AJ, self.plane[:, :, 2])
        tg = dot(cross(rotate(AI, ti), rotate(AJ, tj)), nJ)
        return [dot(d, e1), dot(d, e2), tg]

    def contact(self, kin, extra):
        s = extra[self.scols]
        c = self.curve_derivs(0, s[:, 0], 0)[0]
        return kin.Y[:, 0] + np.einsum("nci,nc->ni", kin.Y[:, 1:4], c)


class CurveOnSurface(CurveFamily):
    kind = "CVSF"

    def rows(self, Y, s, N, ws=None):
        cc, tc = curve_jet(self.curve_derivs(0, s[:, 0], 3, ws), 24, N)
        d = self.surface_derivs(1, s[:, 1], s[:, 2], 3, ws)
        sj = surface_jet(d, 25, 26, N)
        AI, AJ = Y[1:4], Y[5:8]
        r = Y[0] + rotate(AI, cc) - Y[4] - rotate(AJ, sj[(0, 0)])
        nrm = rotate(AJ, cross(sj[(1, 0)], sj[(0, 1)]))
        return [r[0], r[1], r[2], dot(rotate(AI, tc), nrm)]

    def contact(self, kin, extra):
        s = extra[self.scols]
        c = self.curve_derivs(0, s[:, 0], 0)[0]
        return kin.Y[:, 0] + np.einsum("nci,nc->ni", kin.Y[:, 1:4], c)


class SurfaceOnSurface(CurveFamily):
    kind = "SFSF"

    def rows(self, Y, s, N, ws=None):
        di = self.surface_derivs(0, s[:, 0], s[:, 1], 3, ws)
        dj = self.surface_derivs(1, s[:, 2], s[:, 3], 3, ws)
        si = surface_jet(di, 24, 25, N)
        sj = surface_jet(dj, 26, 27, N)
        AI, AJ = Y[1:4], Y[5:8]
        r = Y[0] + rotate(AI, si[(0, 0)]) - Y[4] - rotate(AJ, sj[(0, 0)])
        ni = rotate(AI, cross(si[(1, 0)], si[(0, 1)]))
        return [r[0], r[1], r[2], dot(ni, rotate(AJ, sj[(1, 0)])), dot(ni, rotate(AJ, sj[(0, 1)]))]

    def contact(self, kin, extra):
        s = extra[self.scols]
        c = self.surface_derivs(0, s[:, 0], s[:, 1], 0)[(0, 0)]
        return kin.Y[:, 0] + np.einsum("nci,nc->ni", kin.Y[:, 1:4], c)


FAMILIES = {"PTCV": (PointOnCurve, SLOTS_PT, 3, 1), "PTSF": (PointOnSurface, SLOTS_PT, 3, 2),
            "CVCV": (CurveOnCurve, SLOTS_2, 3, 2), "CVSF": (CurveOnSurface, SLOTS_2, 4, 3),
            "SFSF": (SurfaceOnSurface, SLOTS_2, 5, 4)}
