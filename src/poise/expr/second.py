"""Second partial derivatives of the function library (:mod:`poise.expr.functions`).

``SECOND[name](args) -> {(i, j): d2 value / d args[i] d args[j]}`` for ``i <= j``, only the
entries that can be non-zero; ``(m,)`` arrays or floats. The value and the first partials stay
those of :data:`poise.expr.functions.FUNCTIONS` (the exact forward mode), so a second-order
evaluation (:mod:`poise.expr.hessian`) agrees with the first-order one. Piecewise-linear
functions (ABS, AINT, ANINT, MAX, MIN, MOD, DIM, SIGN, IF) have none: their second derivative is
0 on the branch the value selects, the convention of the first derivatives. IMPACT and BISTOP
are force laws and have no entry (:data:`NO_SECOND`).
"""
from __future__ import annotations

import numpy as np

from .functions import profile_havsin, profile_step, profile_step5

__all__ = ["SECOND", "NO_SECOND"]

NO_SECOND = frozenset({"IMPACT", "BISTOP"})
_LN10 = np.log(10.0)


def _u1(f2):
    return lambda a: {(0, 0): f2(a[0])}


def _atan2(a):
    y, x = a
    r2 = x * x + y * y
    ok = r2 > 0
    q = np.where(ok, 1.0 / np.where(ok, r2, 1.0) ** 2, 0.0)
    return {(0, 0): -2.0 * x * y * q, (1, 1): 2.0 * x * y * q, (0, 1): (y * y - x * x) * q}


def _step_family(pp):
    """``h0 + (h1 - h0) f(u)``, ``u = (x - x0)/(x1 - x0)`` clipped to [0, 1]; ``pp(u)`` gives
    ``f'`` and ``f''`` (both zero outside the open interval)."""
    def fn(a):
        x, x0, h0, x1, h1 = a
        dx = x1 - x0
        raw = (x - x0) / dx
        inside = (raw > 0.0) & (raw < 1.0)
        u = np.clip(raw, 0.0, 1.0)
        fp, fpp = pp(u)
        fp = np.where(inside, fp, 0.0)
        fpp = np.where(inside, fpp, 0.0)
        amp = h1 - h0
        gu = [1.0 / dx, (u - 1.0) / dx, 0.0, -u / dx, 0.0]          # du / d args
        hu = {(0, 1): 1.0 / dx ** 2, (0, 3): -1.0 / dx ** 2,          # d2u / d args d args
              (1, 1): 2.0 * (u - 1.0) / dx ** 2, (1, 3): (1.0 - 2.0 * u) / dx ** 2,
              (3, 3): 2.0 * u / dx ** 2}
        out = {}
        for i in (0, 1, 3):
            for j in (0, 1, 3):
                if j >= i:
                    out[(i, j)] = amp * (fpp * gu[i] * gu[j] + fp * hu.get((i, j), 0.0))
            out[(min(i, 2), max(i, 2))] = -fp * gu[i]           # d amp / d h0 = -1
            out[(i, 4)] = fp * gu[i]                             # d amp / d h1 = +1
        return out
    return fn


def _pp_step(u):
    return profile_step(u)[1], 6.0 - 12.0 * u


def _pp_step5(u):
    return profile_step5(u)[1], 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u)


def _pp_havsin(u):
    return profile_havsin(u)[1], 0.5 * np.pi ** 2 * np.cos(np.pi * u)


def _shf(a):
    x, x0, amp, w, phi, b = a
    u = x - x0
    th = w * u - phi
    s, c = np.sin(th), np.cos(th)
    gt = {0: w, 1: -w, 3: u, 4: -1.0}                                 # d theta / d args
    ht = {(0, 3): 1.0, (1, 3): -1.0}
    out = {}
    keys = sorted(gt)
    for ii, i in enumerate(keys):
        for j in keys[ii:]:
            out[(i, j)] = -amp * s * gt[i] * gt[j] + amp * c * ht.get((i, j), 0.0)
    for i in keys:
        out[(min(i, 2), max(i, 2))] = c * gt[i]                        # d2 / d amp d theta
    return out


def _poly(a):
    x, x0, coef = a[0], a[1], a[2:]
    u = x - x0
    d2 = np.zeros_like(u)
    for j in range(2, len(coef)):
        d2 = d2 + j * (j - 1) * coef[j] * u ** (j - 2)
    out = {(0, 0): d2, (0, 1): -d2, (1, 1): d2}
    for j in range(1, len(coef)):
        dj = j * u ** (j - 1)
        out[(0, 2 + j)] = dj
        out[(1, 2 + j)] = -dj
    return out


def _cheby(a):
    x, x0, coef = a[0], a[1], a[2:]
    u = x - x0
    one, zero = np.ones_like(u), np.zeros_like(u)
    t, d, e = [one, u], [zero, one], [zero, zero]                    # T_j, T_j', T_j''
    for _ in range(2, len(coef)):
        t.append(2.0 * u * t[-1] - t[-2])
        e.append(4.0 * d[-1] + 2.0 * u * e[-1] - e[-2])
        d.append(2.0 * t[-2] + 2.0 * u * d[-1] - d[-2])
    d2 = sum(c * e[j] for j, c in enumerate(coef))
    out = {(0, 0): d2, (0, 1): -d2, (1, 1): d2}
    for j in range(len(coef)):
        out[(0, 2 + j)] = d[j]
        out[(1, 2 + j)] = -d[j]
    return out


def _fourier(use_sin):
    def fn(a):
        x, x0, w, coef = a[0], a[1], a[2], a[3:]
        u = x - x0
        th = w * u
        v1 = np.zeros_like(u)                    # d value / d theta
        v2 = np.zeros_like(u)                    # d2 value / d theta2
        vc = {}
        for j in range(1, len(coef)):
            s, c = np.sin(j * th), np.cos(j * th)
            if use_sin:
                v1, v2, vc[j] = v1 + coef[j] * j * c, v2 - coef[j] * j * j * s, j * c
            else:
                v1, v2, vc[j] = v1 - coef[j] * j * s, v2 - coef[j] * j * j * c, -j * s
        gt = {0: w, 1: -w, 2: u}
        ht = {(0, 2): 1.0, (1, 2): -1.0}
        out = {}
        for i in range(3):
            for k in range(i, 3):
                out[(i, k)] = v2 * gt[i] * gt[k] + v1 * ht.get((i, k), 0.0)
            for j, dj in vc.items():
                out[(i, 3 + j)] = dj * gt[i]
        return out
    return fn


def _none(a):
    return {}


SECOND = {
    "ABS": _none, "AINT": _none, "ANINT": _none, "MAX": _none, "MIN": _none, "MOD": _none,
    "DIM": _none, "SIGN": _none, "IF": _none,
    "ACOS": _u1(lambda x: -x / (1.0 - x * x) ** 1.5),
    "ASIN": _u1(lambda x: x / (1.0 - x * x) ** 1.5),
    "ATAN": _u1(lambda x: -2.0 * x / (1.0 + x * x) ** 2),
    "COS": _u1(lambda x: -np.cos(x)), "COSH": _u1(np.cosh), "EXP": _u1(np.exp),
    "LOG": _u1(lambda x: -1.0 / (x * x)), "LOG10": _u1(lambda x: -1.0 / (x * x * _LN10)),
    "SIN": _u1(lambda x: -np.sin(x)), "SINH": _u1(np.sinh),
    "SQRT": _u1(lambda x: -0.25 / (x * np.sqrt(x))),
    "TAN": _u1(lambda x: 2.0 * np.tan(x) * (1.0 + np.tan(x) ** 2)),
    "TANH": _u1(lambda x: -2.0 * np.tanh(x) * (1.0 - np.tanh(x) ** 2)),
    "ATAN2": _atan2,
    "STEP": _step_family(_pp_step), "STEP5": _step_family(_pp_step5),
    "HAVSIN": _step_family(_pp_havsin), "SHF": _shf, "POLY": _poly, "CHEBY": _cheby,
    "FORCOS": _fourier(False), "FORSIN": _fourier(True),
}
