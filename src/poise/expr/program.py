"""Vectorised forward-mode programs for one group of structurally identical expressions.

:func:`build` turns a structural key (see :mod:`poise.expr.lower`) into a closure
``f(env) -> (value, grad)`` where ``value`` is ``(m,)`` and ``grad`` is a dict mapping a
variable to its derivative array:

* ``int k``      -> ``(m, 3)`` d value / d slot vector k
* ``"t"``        -> ``(m,)`` d value / d TIME
* ``("u", k)``   -> ``(m,)`` d value / d local scalar unknown k
* ``("r", k)``   -> ``(m,)`` d value / d local reaction channel k

Missing keys are identically zero (sparse forward mode: constants carry no gradient at all).
"""
from __future__ import annotations

import numpy as np

from .functions import FUNCTIONS, DomainError, bistop, impact
from .measures import MEASURE_SLOTS, eval_measure

__all__ = ["build", "GroupEnv"]


class GroupEnv:
    """Inputs of one group evaluation (all arrays have m rows).

    Attributes
    ----------
    params : (NP, m) ndarray
        Constant parameters.
    vecs : list of (m, 3) ndarray
        Slot vectors.
    t : (m,) ndarray
        TIME broadcast.
    sc, rx : (m, U), (m, C) ndarray
        Scalar unknown / reaction channel values.
    ang : (m, NA) ndarray or None
        Angle reference values.
    spl : list of list of (PreparedSpline, rows)
        Per local spline: the distinct splines and the rows using each (rows may be a slice).
    static : bool
    """

    __slots__ = ("params", "vecs", "t", "sc", "rx", "ang", "spl", "static", "ones")


def _scale(g, f):
    """Multiply every gradient entry by ``f`` (scalar or (m,))."""
    if isinstance(f, np.ndarray):
        f2 = f[:, None]
        return {k: (v * f2 if v.ndim == 2 else v * f) for k, v in g.items()}
    if f == 1.0:
        return g
    return {k: v * f for k, v in g.items()}


def _accum(out, g, f):
    """``out += f * g`` (out is a fresh dict owned by the caller)."""
    if isinstance(f, np.ndarray):
        f2 = None
        for k, v in g.items():
            if v.ndim == 2:
                if f2 is None:
                    f2 = f[:, None]
                w = v * f2
            else:
                w = v * f
            out[k] = out[k] + w if k in out else w
    else:
        for k, v in g.items():
            w = v if f == 1.0 else v * f
            out[k] = out[k] + w if k in out else w
    return out


def _add(ga, gb, sign=1.0):
    if not gb:
        return ga
    if not ga and sign == 1.0:
        return gb
    out = dict(ga)
    return _accum(out, gb, sign)


def build(key):
    """Compile a structural key into a closure ``env -> (value (m,), grad dict)``."""
    tag = key[0]
    if tag == "c":
        i = key[1]
        return lambda env: (env.params[i], {})
    if tag == "time":
        return lambda env: (env.t, {"t": env.ones})
    if tag == "sc":
        k = key[1]
        gk = ("u", k)
        return lambda env: (env.sc[:, k], {gk: env.ones})
    if tag == "rx":
        k = key[1]
        gk = ("r", k)
        return lambda env: (env.rx[:, k], {gk: env.ones})
    if tag == "neg":
        fa = build(key[1])

        def neg(env):
            v, g = fa(env)
            return -v, _scale(g, -1.0)
        return neg
    if tag == "bin":
        return _build_bin(key[1], build(key[2]), build(key[3]))
    if tag == "fn":
        return _build_fn(key[1], [build(a) for a in key[2]])
    if tag == "meas":
        return _build_meas(key[1], key[2], key[3])
    if tag == "spl":
        return _build_spl(key[2], build(key[3]), build(key[4]), key[5])
    raise ValueError(tag)  # pragma: no cover


def _build_bin(op, fa, fb):
    if op == "+":
        def f(env):
            va, ga = fa(env)
            vb, gb = fb(env)
            return va + vb, _add(ga, gb)
    elif op == "-":
        def f(env):
            va, ga = fa(env)
            vb, gb = fb(env)
            return va - vb, _add(ga, gb, -1.0)
    elif op == "*":
        def f(env):
            va, ga = fa(env)
            vb, gb = fb(env)
            if not gb:
                return va * vb, _scale(ga, vb)
            if not ga:
                return va * vb, _scale(gb, va)
            return va * vb, _accum(_scale(ga, vb), gb, va)
    elif op == "/":
        def f(env):
            va, ga = fa(env)
            vb, gb = fb(env)
            zero = vb == 0
            if zero.any():
                raise DomainError("division by zero", zero)
            inv = 1.0 / vb
            v = va * inv
            out = _scale(ga, inv) if ga else {}
            if gb:
                out = _accum(dict(out), gb, -v * inv)
            return v, out
    else:  # power
        def f(env):
            va, ga = fa(env)
            vb, gb = fb(env)
            bad = (va < 0) & (vb != np.trunc(vb))
            if bad.any():
                raise DomainError("negative number raised to a non-integer power", bad)
            bad = (va == 0) & (vb < 0)
            if bad.any():
                raise DomainError("division by zero (0 raised to a negative power)", bad)
            v = va ** vb
            out = {}
            if ga:
                out = _scale(ga, vb * va ** (vb - 1.0))
            if gb:
                if (va <= 0).any():
                    nz = va <= 0
                    lg = np.log(np.where(nz, 1.0, va))
                    dv = np.where(nz, 0.0, v * lg)
                else:
                    dv = v * np.log(va)
                out = _accum(dict(out), gb, dv)
            return v, out
    return f


def _build_fn(name, fargs):
    n = len(fargs)
    if name in ("IMPACT", "BISTOP"):
        impl = impact if name == "IMPACT" else bistop

        def f(env):
            vals, grads = _eval_args(fargs, env)
            v, parts = impl(vals, [bool(g) for g in grads], env.static)
            return v, _chain(parts, grads)
        return f
    impl = FUNCTIONS[name]
    if n == 1:
        fa = fargs[0]

        def f1(env):
            va, ga = fa(env)
            v, parts = impl([va], [bool(ga)])
            if not ga or parts[0] is None:
                return v, {}
            return v, _scale(ga, parts[0])
        return f1

    def f(env):
        vals, grads = _eval_args(fargs, env)
        v, parts = impl(vals, [bool(g) for g in grads])
        return v, _chain(parts, grads)
    return f


def _eval_args(fargs, env):
    vals, grads = [], []
    for fa in fargs:
        v, g = fa(env)
        vals.append(v)
        grads.append(g)
    return vals, grads


def _chain(parts, grads):
    out = {}
    for p, g in zip(parts, grads, strict=True):
        if g and p is not None:
            _accum(out, g, p)
    return out


def _build_meas(name, slots, ang):
    slots = tuple(slots)
    assert len(slots) == len(MEASURE_SLOTS[name])

    def f(env):
        vecs = [env.vecs[s] for s in slots]
        ref = env.ang[:, ang] if (ang >= 0 and env.ang is not None) else None
        v, gl = eval_measure(name, vecs, ref)
        out = {}
        for s, g in zip(slots, gl, strict=True):
            out[s] = out[s] + g if s in out else g
        return v, out
    return f


def _build_spl(order, fx, fz, si):
    def f(env):
        vx, gx = fx(env)
        vz, gz = fz(env)
        m = vx.shape[0]
        parts = env.spl[si]
        if len(parts) == 1 and isinstance(parts[0][1], slice):
            v, dx, dz = parts[0][0].evaluate(vx, vz, order)
        else:
            v, dx, dz = np.empty(m), np.empty(m), np.empty(m)
            for sp, rows in parts:
                v[rows], dx[rows], dz[rows] = sp.evaluate(vx[rows], vz[rows], order)
        out = {}
        if gx:
            _accum(out, gx, dx)
        if gz:
            _accum(out, gz, dz)
        return v, out
    return f
