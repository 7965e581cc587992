"""Vectorised scalar function library with exact first derivatives (forward mode).

Every function has the signature ``fn(args, need) -> (value, partials)``:

* ``args`` – list of ``(m,)`` float arrays (one per argument, m instances).
* ``need`` – list of bools; ``partials[i]`` is only required when ``need[i]`` is True.
* ``value`` – ``(m,)`` array; ``partials`` – list of ``(m,)`` arrays (or Python floats, or
  ``None`` meaning identically zero) holding d value / d args[i].

Domain problems raise :class:`DomainError` with a boolean mask of the failing instances.
Formulas: deck_format.md §8.1 and §8.5. Non-differentiable points use the one-sided derivative
of the branch that is selected by the value (e.g. ``ABS'(0) = 0``, ``MAX`` picks its first
argument on ties, ``IF`` uses the selected branch).
"""
from __future__ import annotations

import numpy as np

__all__ = ["DomainError", "FUNCTIONS", "ARITY", "step_profile"]

_LN10 = np.log(10.0)


class DomainError(Exception):
    """Evaluation problem for some instances (``mask`` is an ``(m,)`` bool array)."""

    def __init__(self, message: str, mask):
        super().__init__(message)
        self.message = message
        self.mask = np.asarray(mask, dtype=bool)


def _check(bad, message: str) -> None:
    if bad.any():
        raise DomainError(message, bad)


def check_power(va, vb) -> None:
    """Domain of ``va ** vb`` (both (m,) arrays): DomainError where it is not a real number."""
    _check((va < 0) & (vb != np.trunc(vb)), "negative number raised to a non-integer power")
    _check((va == 0) & (vb < 0), "division by zero (0 raised to a negative power)")


def _abs(a, need):
    x = a[0]
    return np.abs(x), [np.sign(x)]


def _sqrt(a, need):
    x = a[0]
    _check(x < 0, "SQRT of a negative number")
    v = np.sqrt(x)
    if need[0]:
        _check(v == 0, "SQRT derivative is infinite at 0")
        return v, [0.5 / v]
    return v, [None]


def _log(a, need):
    x = a[0]
    _check(x <= 0, "LOG of a non-positive number")
    return np.log(x), [1.0 / x if need[0] else None]


def _log10(a, need):
    x = a[0]
    _check(x <= 0, "LOG10 of a non-positive number")
    return np.log10(x), [1.0 / (x * _LN10) if need[0] else None]


def _asin(a, need):
    x = a[0]
    _check(np.abs(x) > 1, "ASIN argument outside [-1, 1]")
    return np.arcsin(x), [1.0 / np.sqrt(1.0 - x * x) if need[0] else None]


def _acos(a, need):
    x = a[0]
    _check(np.abs(x) > 1, "ACOS argument outside [-1, 1]")
    return np.arccos(x), [-1.0 / np.sqrt(1.0 - x * x) if need[0] else None]


def _tan(a, need):
    v = np.tan(a[0])
    return v, [1.0 + v * v]


def _tanh(a, need):
    v = np.tanh(a[0])
    return v, [1.0 - v * v]


def _exp(a, need):
    v = np.exp(a[0])
    return v, [v]


def _simple(f, df):
    def fn(a, need):
        x = a[0]
        return f(x), [df(x) if need[0] else None]
    return fn


def _atan2(a, need):
    y, x = a
    r2 = x * x + y * y
    safe = np.where(r2 > 0, r2, 1.0)
    return np.arctan2(y, x), [np.where(r2 > 0, x / safe, 0.0), np.where(r2 > 0, -y / safe, 0.0)]


def _aint(a, need):
    return np.trunc(a[0]), [None]


def _anint(a, need):
    x = a[0]
    return np.sign(x) * np.floor(np.abs(x) + 0.5), [None]


def _max(a, need):
    x, y = a
    sel = x >= y
    return np.where(sel, x, y), [sel.astype(float), (~sel).astype(float)]


def _min(a, need):
    x, y = a
    sel = x <= y
    return np.where(sel, x, y), [sel.astype(float), (~sel).astype(float)]


def _mod(a, need):
    x, y = a
    _check(y == 0, "MOD with a zero divisor")
    q = np.trunc(x / y)
    return x - q * y, [1.0, -q]


def _dim(a, need):
    x, y = a
    pos = (x > y).astype(float)
    return (x - y) * pos, [pos, -pos]


def _sign(a, need):
    x, y = a
    s = np.where(y >= 0, 1.0, -1.0)
    return np.abs(x) * s, [np.sign(x) * s, None]


def _if(a, need):
    c, neg, zero, pos = a
    lt, eq = c < 0, c == 0
    gt = ~(lt | eq)
    v = np.where(lt, neg, np.where(eq, zero, pos))
    return v, [None, lt.astype(float), eq.astype(float), gt.astype(float)]


# --- smooth steps ------------------------------------------------------------------------

def profile_step(u):
    """STEP's cubic profile on [0, 1] and its derivative."""
    return u * u * (3.0 - 2.0 * u), 6.0 * u * (1.0 - u)


def profile_step5(u):
    """STEP5's quintic profile on [0, 1] and its derivative."""
    u2 = u * u
    return u2 * u * (10.0 - 15.0 * u + 6.0 * u2), 30.0 * u2 * (1.0 - u) ** 2


def profile_havsin(u):
    """HAVSIN's haversine profile on [0, 1] and its derivative."""
    return 0.5 * (1.0 - np.cos(np.pi * u)), 0.5 * np.pi * np.sin(np.pi * u)


def step_profile(a, need, prof, name="STEP"):
    """Generic smooth step ``h0 + (h1-h0) f(u)``, ``u = clip((x-x0)/(x1-x0), 0, 1)``.

    ``prof(u) -> (f, f')`` with f(0)=0, f(1)=1, f'(0)=f'(1)=0.
    """
    x, x0, h0, x1, h1 = a
    dx = x1 - x0
    _check(~(dx > 0), f"{name} requires x0 < x1")
    u = np.clip((x - x0) / dx, 0.0, 1.0)
    f, fp = prof(u)
    amp = h1 - h0
    val = h0 + amp * f
    g = amp * fp / dx
    parts = [
        g if need[0] else None,
        g * (u - 1.0) if need[1] else None,
        1.0 - f if need[2] else None,
        -g * u if need[3] else None,
        f if need[4] else None,
    ]
    return val, parts


def _step(a, need):
    return step_profile(a, need, profile_step, "STEP")


def _step5(a, need):
    return step_profile(a, need, profile_step5, "STEP5")


def _havsin(a, need):
    return step_profile(a, need, profile_havsin, "HAVSIN")


def _shf(a, need):
    x, x0, amp, w, phi, b = a
    u = x - x0
    th = w * u - phi
    s, c = np.sin(th), np.cos(th)
    ac = amp * c
    return amp * s + b, [ac * w, -ac * w, s, ac * u, -ac, 1.0]


def _poly(a, need):
    x, x0, coef = a[0], a[1], a[2:]
    u = x - x0
    val = np.zeros_like(u)
    dv = np.zeros_like(u)
    for c in reversed(coef):          # Horner, value and derivative together
        dv = dv * u + val
        val = val * u + c
    parts = [dv, -dv]
    p = np.ones_like(u)
    for i in range(len(coef)):
        parts.append(p if need[2 + i] else None)
        p = p * u
    return val, parts


def _cheby(a, need):
    x, x0, coef = a[0], a[1], a[2:]
    u = x - x0
    t_prev, t = np.ones_like(u), u
    d_prev, d = np.zeros_like(u), np.ones_like(u)
    ts, ds = [t_prev, t], [d_prev, d]
    for _ in range(2, len(coef)):
        t_prev, t = t, 2.0 * u * t - t_prev
        d_prev, d = d, 2.0 * ts[-1] + 2.0 * u * d - d_prev
        ts.append(t)
        ds.append(d)
    val = np.zeros_like(u)
    dv = np.zeros_like(u)
    for j, c in enumerate(coef):
        val = val + c * ts[j]
        dv = dv + c * ds[j]
    return val, [dv, -dv] + [ts[j] if need[2 + j] else None for j in range(len(coef))]


def _fourier(use_sin: bool):
    def fn(a, need):
        x, x0, w, coef = a[0], a[1], a[2], a[3:]
        u = x - x0
        th = w * u
        val = coef[0] + np.zeros_like(u)
        dth = np.zeros_like(u)
        parts_c = [1.0 if need[3] else None]
        for j in range(1, len(coef)):
            s, c = np.sin(j * th), np.cos(j * th)
            if use_sin:
                val = val + coef[j] * s
                dth = dth + coef[j] * j * c
                parts_c.append(s if need[3 + j] else None)
            else:
                val = val + coef[j] * c
                dth = dth - coef[j] * j * s
                parts_c.append(c if need[3 + j] else None)
        return val, [dth * w, -dth * w, dth * u] + parts_c
    return fn


def _impact_side(x, xd, xb, k, e, cmax, d, lower: bool, moving: bool):
    """One contact side of IMPACT/BISTOP.

    Returns the value and partials w.r.t. (x, xd, xb, k, e, cmax, d) where xb is the boundary.
    Lower side (x < xb): max(k (xb-x)^e - STEP(x, xb-d, cmax, xb, 0) xd, 0).
    Upper side (x > xb): min(-k (x-xb)^e - STEP(x, xb, 0, xb+d, cmax) xd, 0).
    """
    pen = xb - x if lower else x - xb
    act = pen > 0
    pp = np.where(act, pen, 1.0)
    pe = pp ** e
    sgn = 1.0 if lower else -1.0
    f = sgn * k * pe
    dpen = sgn * k * e * pe / pp                      # d f / d pen
    zero = np.zeros_like(x)
    if moving:
        if lower:
            s, sp = step_profile([x, xb - d, cmax, xb, zero], [True] * 5, profile_step)
            ds_dxb = sp[1] + sp[3]
            ds_dd = -sp[1]
            ds_dc = sp[2]
        else:
            s, sp = step_profile([x, xb, zero, xb + d, cmax], [True] * 5, profile_step)
            ds_dxb = sp[1] + sp[3]
            ds_dd = sp[3]
            ds_dc = sp[4]
        f = f - s * xd
        ds_dx = sp[0]
    else:
        s = ds_dx = ds_dxb = ds_dd = ds_dc = zero
    on = act & ((f > 0) if lower else (f < 0))
    w = on.astype(float)
    val = np.where(on, f, 0.0)
    dxp = -1.0 if lower else 1.0                       # d pen / d x
    parts = [
        w * (dpen * dxp - xd * ds_dx),
        -w * s if moving else None,
        w * (-dpen * dxp - xd * ds_dxb),
        w * sgn * pe,
        w * sgn * k * pe * np.log(pp),
        -w * xd * ds_dc,
        -w * xd * ds_dd,
    ]
    return val, parts


def impact(a, need, static: bool):
    """IMPACT(x, xdot, x1, k, e, cmax, d); ``static`` -> xdot treated as 0."""
    x, xd, x1, k, e, cmax, d = a
    if static:
        xd = np.zeros_like(x)
    return _impact_side(x, xd, x1, k, e, cmax, d, True, not static)


def bistop(a, need, static: bool):
    """BISTOP(x, xdot, x1, x2, k, e, cmax, d); ``static`` -> xdot treated as 0."""
    x, xd, x1, x2, k, e, cmax, d = a
    _check(x1 > x2, "BISTOP requires x1 <= x2")
    if static:
        xd = np.zeros_like(x)
    vl, pl = _impact_side(x, xd, x1, k, e, cmax, d, True, not static)
    vu, pu = _impact_side(x, xd, x2, k, e, cmax, d, False, not static)
    val = vl + vu
    xdp = None if static else pl[1] + pu[1]
    parts = [pl[0] + pu[0], xdp, pl[2], pu[2], pl[3] + pu[3], pl[4] + pu[4],
             pl[5] + pu[5], pl[6] + pu[6]]
    return val, parts


FUNCTIONS = {
    "ABS": _abs, "ACOS": _acos, "AINT": _aint, "ANINT": _anint, "ASIN": _asin,
    "ATAN": _simple(np.arctan, lambda x: 1.0 / (1.0 + x * x)), "ATAN2": _atan2,
    "COS": _simple(np.cos, lambda x: -np.sin(x)), "COSH": _simple(np.cosh, np.sinh),
    "EXP": _exp, "LOG": _log, "LOG10": _log10, "MAX": _max, "MIN": _min, "MOD": _mod,
    "SIN": _simple(np.sin, np.cos), "SINH": _simple(np.sinh, np.cosh), "SQRT": _sqrt,
    "TAN": _tan, "TANH": _tanh, "DIM": _dim, "SIGN": _sign, "IF": _if,
    "STEP": _step, "STEP5": _step5, "HAVSIN": _havsin, "SHF": _shf, "POLY": _poly,
    "CHEBY": _cheby, "FORCOS": _fourier(False), "FORSIN": _fourier(True),
}
"""Pure functions (IMPACT and BISTOP take an extra ``static`` flag and are handled separately)."""

ARITY = {name: (1, 1) for name in FUNCTIONS}
ARITY.update({
    "ATAN2": (2, 2), "MAX": (2, 99), "MIN": (2, 99), "MOD": (2, 2), "DIM": (2, 2),
    "SIGN": (2, 2), "IF": (4, 4), "STEP": (5, 5), "STEP5": (5, 5), "HAVSIN": (5, 5),
    "SHF": (6, 6), "POLY": (3, 33), "CHEBY": (3, 33), "FORCOS": (4, 34), "FORSIN": (4, 34),
    "IMPACT": (7, 7), "BISTOP": (8, 8),
})
"""(min, max) argument counts of all math functions, including IMPACT and BISTOP."""
