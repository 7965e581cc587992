"""Evaluation of ``Reference_ParamCurve`` / ``Reference_ParamSurface`` with parameter derivatives.

Two forms (docs/elements.md "Curves and surfaces"): **analytic** (``x/y/z_expression`` of the
parameters ``U``, ``V`` in the deck expression language, exact first derivatives from
:mod:`poise.expr`, higher ones central differences of those) and **spline data** (points in the
element text; cubic / bicubic splines, derivatives exact). ``curve.derivs(u, order)`` returns
``(order + 1, k, 3)``: ``c, c', c'', ...``; ``surface.derivs(u, v, order)`` a dict
``{(i, j): (k, 3)}`` of ``d^(i+j) s / du^i dv^j``. Details: :class:`_AnalyticBase`.
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError
from poise.expr import EvalContext, compile_batch


class _ParamResolver:
    """Expression resolver that only knows the curve/surface parameters (scalars 0, 1)."""

    def __init__(self, npar):
        self.names = ("U", "V")[:npar]

    def symbol(self, name):
        if name in self.names:
            return self.names.index(name)
        raise KeyError(name)

    def marker_index(self, i):
        raise KeyError(i)

    def variable(self, vid):
        raise KeyError(vid)

    def diff_state(self, i):
        raise KeyError(i)

    def diff_derivative(self, i):
        raise KeyError(i)

    def spline(self, i):
        raise KeyError(i)

    def array(self, i):
        raise KeyError(i)

    def reaction(self, *a):
        raise NotImplementedError("curve/surface expressions may only use U, V and constants")

    def angle_key(self, *a):
        raise NotImplementedError("curve/surface expressions may only use U, V and constants")


class _AnalyticBase:
    """Two forms (docs/elements.md "Curves and surfaces"):

    * **analytic** (poise extension of the CURSUB form): ``x_expression``, ``y_expression``,
      ``z_expression`` written in the deck expression language as functions of the parameter ``U``
      (surfaces: ``U`` and ``V``), with ``u_start``/``u_end`` (``v_start``/``v_end``). Each
      expression is compiled by :mod:`poise.expr` with ``U``/``V`` bound to scalar unknowns
      (``Resolver.symbol``; messages quote the deck text), which gives the value and the **exact
      first derivatives**; an evaluation failure names the parameter values. Second and third derivatives are central
      differences of the exact first derivatives (step ``h = 1e-4 * max(1, u_end - u_start)``;
      truncation error ``O(h^2)``), used only in Jacobian/Hessian terms and in the tangency rows'
      parameter derivatives.
    * **spline data**: the element text holds ``num_pts`` points ``x y z`` (curves) or
      ``num_u * num_v`` points (surfaces, u-major: the v index runs fastest). Curves: cubic spline
      (``scipy.interpolate.CubicSpline``, not-a-knot; ``is_u_closed="TRUE"``: periodic, the first
      point is appended when the data do not repeat it), parametrised by cumulative chord length
      mapped to ``[u_start, u_end]`` (defaults 0 and 1); derivatives up to order 3 exact. Surfaces:
      bicubic ``RectBivariateSpline`` on a uniform ``[u_start, u_end] x [v_start, v_end]`` grid.

    Closed curves: u is wrapped into the period before evaluation (the unknown itself may run on
    through any number of turns).

    ``curve.derivs(u, order)`` returns an array ``(order + 1, k, 3)``: ``c, c', c'', ...`` at the k
    parameter values; ``surface.derivs(u, v, order)`` a dict ``{(i, j): (k, 3)}`` of
    ``d^(i+j) s / du^i dv^j`` for ``i + j <= order``.
    """
    npar = 1

    def __init__(self, el, exprs):
        self.el = el
        self.exprs = exprs             # 3 Expr or float
        self.batch = compile_batch(list(exprs), _ParamResolver(self.npar))   # DeckError: located

    def _batch(self, k, memo):
        """The three expressions repeated for k parameter points (kept in ``memo``, a dict of
        the solve's workspace, when given)."""
        if k == 1:
            return self.batch
        b = None if memo is None else memo.get(k)
        if b is None:
            b = self.batch.tiled(k, 0, 0, self.npar)
            if memo is not None:
                memo[k] = b
        return b

    def _eval(self, params, memo=None):
        """params (k, npar) -> value (k, 3), d (k, 3, npar)."""
        k = params.shape[0]
        b = self._batch(k, memo)
        try:
            out = b.evaluate(EvalContext(extra=np.asarray(params, float).ravel()))
        except EvaluationError as e:
            i = getattr(e, "instance", None)
            if i is None:
                raise
            at = ", ".join(f"{n} = {x:.9g}" for n, x in zip("UV", params[i // 3]))
            raise EvaluationError(f"{e.detail} at {at}", e.loc, e.attr) from None
        val = out.value.reshape(k, 3)
        d = np.zeros((k * 3, self.npar))
        si = out.scalar_index
        for c in range(si.shape[1]):
            col = si[:, c]
            ok = col >= 0
            d[np.nonzero(ok)[0], col[ok] % self.npar] += out.d_scalar[ok, c]
        return val, d.reshape(k, 3, self.npar)


class AnalyticCurve(_AnalyticBase):
    def __init__(self, el, exprs, u0, u1, closed):
        super().__init__(el, exprs)
        self.u0, self.u1, self.closed = u0, u1, closed
        self.h = 1e-4 * max(1.0, abs(u1 - u0))

    def derivs(self, u, order=2, memo=None):
        u = np.atleast_1d(np.asarray(u, float))
        k = len(u)
        h = self.h
        P = np.stack([u, u + h, u - h])[..., None].reshape(3 * k, 1)
        v, d = self._eval(P, memo)
        v = v.reshape(3, k, 3)
        d = d[..., 0].reshape(3, k, 3)
        out = [v[0], d[0], (d[1] - d[2]) / (2 * h), (d[1] - 2 * d[0] + d[2]) / h / h]
        return np.array(out[:order + 1])


class AnalyticSurface(_AnalyticBase):
    npar = 2

    def __init__(self, el, exprs, u0, u1, v0, v1):
        super().__init__(el, exprs)
        self.u0, self.u1, self.v0, self.v1 = u0, u1, v0, v1
        self.h = 1e-4 * max(1.0, abs(u1 - u0), abs(v1 - v0))

    def derivs(self, u, v, order=2, memo=None):
        u = np.atleast_1d(np.asarray(u, float))
        v = np.atleast_1d(np.asarray(v, float))
        k = len(u)
        h = self.h
        us = np.stack([u, u + h, u - h, u, u])
        vs = np.stack([v, v, v, v + h, v - h])
        val, d = self._eval(np.stack([us.ravel(), vs.ravel()], 1), memo)
        val = val.reshape(5, k, 3)
        du = d[..., 0].reshape(5, k, 3)
        dv = d[..., 1].reshape(5, k, 3)
        o = {(0, 0): val[0], (1, 0): du[0], (0, 1): dv[0]}
        if order >= 2:
            o[(2, 0)] = (du[1] - du[2]) / (2 * h)
            o[(0, 2)] = (dv[3] - dv[4]) / (2 * h)
            o[(1, 1)] = 0.5 * ((du[3] - du[4]) + (dv[1] - dv[2])) / (2 * h)
        if order >= 3:
            o[(3, 0)] = (du[1] - 2 * du[0] + du[2]) / h / h
            o[(2, 1)] = (dv[1] - 2 * dv[0] + dv[2]) / h / h
            o[(1, 2)] = (du[3] - 2 * du[0] + du[4]) / h / h
            o[(0, 3)] = (dv[3] - 2 * dv[0] + dv[4]) / h / h
        return o


class SplineCurve:
    def __init__(self, pts, u0, u1, closed):
        from scipy.interpolate import CubicSpline
        pts = np.asarray(pts, float)
        if closed and np.linalg.norm(pts[0] - pts[-1]) > 1e-12 * max(1.0, np.abs(pts).max()):
            pts = np.vstack([pts, pts[:1]])
        if closed:
            pts[-1] = pts[0]
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        if np.any(seg <= 0):
            raise ValueError("consecutive curve points coincide")
        s = np.concatenate([[0.0], np.cumsum(seg)])
        self.knots = u0 + (u1 - u0) * s / s[-1]
        self.u0, self.u1, self.closed = u0, u1, closed
        self.sp = CubicSpline(self.knots, pts, bc_type="periodic" if closed else "not-a-knot")

    def derivs(self, u, order=2, memo=None):
        u = np.atleast_1d(np.asarray(u, float))
        if self.closed:
            u = self.u0 + np.mod(u - self.u0, self.u1 - self.u0)
        return np.array([self.sp(u, nu) if nu <= 3 else np.zeros((len(u), 3))
                         for nu in range(order + 1)])


class SplineSurface:
    def __init__(self, pts, nu, nv, u0, u1, v0, v1):
        from scipy.interpolate import RectBivariateSpline
        pts = np.asarray(pts, float).reshape(nu, nv, 3)
        self.u0, self.u1, self.v0, self.v1 = u0, u1, v0, v1
        ug = np.linspace(u0, u1, nu)
        vg = np.linspace(v0, v1, nv)
        kx, ky = min(3, nu - 1), min(3, nv - 1)
        self.sp = [RectBivariateSpline(ug, vg, pts[:, :, c], kx=kx, ky=ky, s=0) for c in range(3)]

    def derivs(self, u, v, order=2, memo=None):
        u = np.atleast_1d(np.asarray(u, float))
        v = np.atleast_1d(np.asarray(v, float))
        o = {}
        for i in range(order + 1):
            for j in range(order + 1 - i):
                o[(i, j)] = np.stack([s(u, v, dx=i, dy=j, grid=False) for s in self.sp], 1)
        return o


# ---------------------------------------------------------------- projections (seeding)
def project_curve(curve, p, n_samples=721):
    """Parameter of the point of ``curve`` closest to ``p`` (3,): sampling + Newton polish."""
    us = np.linspace(curve.u0, curve.u1, n_samples)
    c = curve.derivs(us, 0)[0]
    u = float(us[np.argmin(np.linalg.norm(c - p, axis=1))])
    return _polish_curve(curve, p, u)


def _polish_curve(curve, p, u):
    for _ in range(30):
        c, c1, c2 = (a[0] for a in curve.derivs([u], 2))
        g = np.dot(c - p, c1)
        H = np.dot(c1, c1) + np.dot(c - p, c2)
        if H <= 0:
            break
        du = -g / H
        u += du
        if abs(du) < 1e-13 * max(1.0, abs(curve.u1 - curve.u0)):
            break
    return u


def project_surface(surf, p, n=61):
    """Parameters (u, v) of the point of ``surf`` closest to ``p`` (3,)."""
    U, V = np.meshgrid(np.linspace(surf.u0, surf.u1, n), np.linspace(surf.v0, surf.v1, n),
                       indexing="ij")
    s = surf.derivs(U.ravel(), V.ravel(), 0)[(0, 0)]
    k = int(np.argmin(np.linalg.norm(s - p, axis=1)))
    uv = np.array([U.ravel()[k], V.ravel()[k]])
    for _ in range(30):
        d = surf.derivs([uv[0]], [uv[1]], 2)
        r = d[(0, 0)][0] - p
        su, sv = d[(1, 0)][0], d[(0, 1)][0]
        g = np.array([r @ su, r @ sv])
        H = np.array([[su @ su + r @ d[(2, 0)][0], su @ sv + r @ d[(1, 1)][0]],
                      [su @ sv + r @ d[(1, 1)][0], sv @ sv + r @ d[(0, 2)][0]]])
        try:
            step = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        uv = uv + step
        if np.abs(step).max() < 1e-13:
            break
    return uv


def sample_curve(curve, n=361):
    us = np.linspace(curve.u0, curve.u1, n)
    return us, curve.derivs(us, 0)[0]


def sample_surface(surf, n=41):
    U, V = np.meshgrid(np.linspace(surf.u0, surf.u1, n), np.linspace(surf.v0, surf.v1, n),
                       indexing="ij")
    return U.ravel(), V.ravel(), surf.derivs(U.ravel(), V.ravel(), 0)[(0, 0)]
