"""Vectorised forward-mode programs for one group of structurally identical expressions.

:func:`build` turns a structural key (a tape, see :mod:`poise.expr.tape`) into a closure
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

from .functions import FUNCTIONS, DomainError, bistop, check_power, impact
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
    """Compile a structural key (tape, see :func:`poise.expr.tape.extract`) into a closure
    ``env -> (value (m,), grad dict)``.

    The tape is run in order, each instruction once (shared sub-expressions and variables are
    evaluated once per call, their values and gradients reused); an intermediate is dropped
    after its last use, so memory stays proportional to the live set, not to the tape length.
    """
    steps = [_build_op(op) for op in key]
    n = len(steps)
    last = list(range(n))
    for k, op in enumerate(key):
        for j in _operands(op):
            last[j] = k
    frees = [[] for _ in range(n)]
    for j in range(n - 1):
        frees[last[j]].append(j)
    plan = tuple((f, tuple(fr)) for f, fr in zip(steps, frees))

    def program(env):
        V = [None] * n
        G = [None] * n
        for k, (f, fr) in enumerate(plan):
            V[k], G[k] = f(env, V, G)
            for j in fr:
                V[j] = G[j] = None
        return V[-1], G[-1]
    return program


def _operands(op):
    tag = op[0]
    if tag == "bin":
        return (op[2], op[3])
    if tag == "neg":
        return (op[1],)
    if tag == "fn":
        return op[2]
    if tag == "spl":
        return (op[3], op[4])
    return ()


def _build_op(op):
    """One instruction: ``f(env, V, G) -> (value, grad)`` reading operands from V/G."""
    tag = op[0]
    if tag == "c":
        i = op[1]
        return lambda env, V, G: (env.params[i], {})
    if tag == "time":
        return lambda env, V, G: (env.t, {"t": env.ones})
    if tag == "sc":
        k = op[1]
        gk = ("u", k)
        return lambda env, V, G: (env.sc[:, k], {gk: env.ones})
    if tag == "rx":
        k = op[1]
        gk = ("r", k)
        return lambda env, V, G: (env.rx[:, k], {gk: env.ones})
    if tag == "neg":
        a = op[1]
        return lambda env, V, G: (-V[a], _scale(G[a], -1.0))
    if tag == "bin":
        return _build_bin(op[1], op[2], op[3])
    if tag == "fn":
        return _build_fn(op[1], op[2])
    if tag == "meas":
        return _build_meas(op[1], op[2], op[3])
    if tag == "spl":
        return _build_spl(op[2], op[3], op[4], op[5])
    raise ValueError(tag)  # pragma: no cover


def _build_bin(op, a, b):
    if op == "+":
        def f(env, V, G):
            return V[a] + V[b], _add(G[a], G[b])
    elif op == "-":
        def f(env, V, G):
            return V[a] - V[b], _add(G[a], G[b], -1.0)
    elif op == "*":
        def f(env, V, G):
            va, ga, vb, gb = V[a], G[a], V[b], G[b]
            if not gb:
                return va * vb, _scale(ga, vb)
            if not ga:
                return va * vb, _scale(gb, va)
            return va * vb, _accum(_scale(ga, vb), gb, va)
    elif op == "/":
        def f(env, V, G):
            va, ga, vb, gb = V[a], G[a], V[b], G[b]
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
        def f(env, V, G):
            va, ga, vb, gb = V[a], G[a], V[b], G[b]
            check_power(va, vb)
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


def _build_fn(name, idx):
    n = len(idx)
    if name in ("IMPACT", "BISTOP"):
        impl = impact if name == "IMPACT" else bistop

        def f(env, V, G):
            vals, grads = [V[i] for i in idx], [G[i] for i in idx]
            v, parts = impl(vals, [bool(g) for g in grads], env.static)
            return v, _chain(parts, grads)
        return f
    impl = FUNCTIONS[name]
    if n == 1:
        a = idx[0]

        def f1(env, V, G):
            va, ga = V[a], G[a]
            v, parts = impl([va], [bool(ga)])
            if not ga or parts[0] is None:
                return v, {}
            return v, _scale(ga, parts[0])
        return f1

    def f(env, V, G):
        vals, grads = [V[i] for i in idx], [G[i] for i in idx]
        v, parts = impl(vals, [bool(g) for g in grads])
        return v, _chain(parts, grads)
    return f


def _chain(parts, grads):
    out = {}
    for p, g in zip(parts, grads, strict=True):
        if g and p is not None:
            _accum(out, g, p)
    return out


def _build_meas(name, slots, ang):
    slots = tuple(slots)
    assert len(slots) == len(MEASURE_SLOTS[name])

    def f(env, V, G):
        vecs = [env.vecs[s] for s in slots]
        ref = env.ang[:, ang] if (ang >= 0 and env.ang is not None) else None
        v, gl = eval_measure(name, vecs, ref)
        out = {}
        for s, g in zip(slots, gl, strict=True):
            out[s] = out[s] + g if s in out else g
        return v, out
    return f


def _build_spl(order, ix, iz, si):
    def f(env, V, G):
        vx, gx, vz, gz = V[ix], G[ix], V[iz], G[iz]
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
