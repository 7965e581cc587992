"""Exact second derivatives of a compiled expression group (dense second-order forward mode).

A constraint written as an expression (``Constraint_General``) needs ``d2 e / dy2`` for the
multiplier-weighted Hessian of the Newton matrix; :func:`build_hessian` runs the same tape as
:func:`poise.expr.program.build` on *jets* ``(value (m,), gradient (m, D), Hessian (m, D, D))``
over the group's local variables: the three components of every slot vector (``3 s + c``) then
the scalar unknowns (``3 S + k``). TIME is a constant here (the Jacobian needs no time
derivative of the gradient). Measures are built from dot products of slot vectors, whose second
derivatives are constant blocks; functions chain their first partials (the forward mode's) and
second partials (:mod:`poise.expr.second`). Reaction channels and IMPACT/BISTOP have no second
derivatives here: :func:`build_hessian` raises :class:`NoHessian` naming them.
"""
from __future__ import annotations

import numpy as np

from .functions import FUNCTIONS, DomainError, check_power
from .measures import EULER_LOCK_TOL, MEASURE_SLOTS, wrap_to_ref
from .second import NO_SECOND, SECOND

__all__ = ["build_hessian", "NoHessian", "Jet"]


class NoHessian(Exception):
    """The tape reads something without second derivatives (a reaction channel, IMPACT)."""


class Jet:
    """Value, gradient and Hessian over the local variables; ``g``/``H`` None when zero."""

    __slots__ = ("v", "g", "H")

    def __init__(self, v, g=None, H=None):
        self.v, self.g, self.H = v, g, H


def _sum(a, b, sign=1.0):
    if a is None:
        return None if b is None else (b if sign == 1.0 else -b)
    if b is None:
        return a
    return a + b if sign == 1.0 else a - b


def _outer(ga, gb):
    return ga[:, :, None] * gb[:, None, :]


def _scaled(x, f):
    """``f * x`` for a gradient (m, D) or Hessian (m, D, D) ``x`` and ``f`` (m,) or float."""
    if x is None:
        return None
    if np.ndim(f) == 0:
        return x * f
    return x * f.reshape((-1,) + (1,) * (x.ndim - 1))


def chain(v, p1, p2, args):
    """Jet of ``f(args)`` from its value ``v``, first partials ``p1`` (list, None = 0) and second
    partials ``p2`` ({(i, j): array}, i <= j)."""
    g = H = None
    for p, a in zip(p1, args):
        if p is None or a.g is None:
            continue
        g = _sum(g, _scaled(a.g, p))
        H = _sum(H, _scaled(a.H, p))
    for (i, j), p in p2.items():
        gi, gj = args[i].g, args[j].g
        if gi is None or gj is None:
            continue
        t = _scaled(_outer(gi, gj), p)
        H = _sum(H, t if i == j else t + t.transpose(0, 2, 1))
    return Jet(v, g, H)


def _mul(a, b):
    return chain(a.v * b.v, [b.v, a.v], {(0, 1): 1.0}, [a, b])


def _unary(x, v, d1, d2):
    return chain(v, [d1], {(0, 0): d2}, [x])


def _div(a, b):
    vb = b.v
    if (vb == 0).any():
        raise DomainError("division by zero", vb == 0)
    inv = 1.0 / vb
    return _mul(a, _unary(b, inv, -inv * inv, 2.0 * inv ** 3))


def _pow(a, b):
    va, vb = a.v, b.v
    check_power(va, vb)
    v = va ** vb
    pos = va > 0
    lg = np.log(np.where(pos, va, 1.0))
    with np.errstate(all="ignore"):
        am1 = np.where(va != 0, va ** (vb - 1.0), np.where(vb == 1.0, 1.0, 0.0))
        am2 = np.where(va != 0, va ** (vb - 2.0), np.where(vb == 2.0, 1.0, 0.0))
    p1 = [vb * am1, np.where(pos, v * lg, 0.0)]
    p2 = {(0, 0): vb * (vb - 1.0) * am2, (0, 1): np.where(pos, am1 * (1.0 + vb * lg), 0.0),
          (1, 1): np.where(pos, v * lg * lg, 0.0)}
    return chain(v, p1, p2, [a, b])


# ------------------------------------------------------------------------- measures
class _Vars:
    """Slot vectors of one group evaluation as variables ``3 s + c``."""

    def __init__(self, env, D):
        self.env, self.D = env, D
        self.m = env.vecs[0].shape[0] if env.vecs else 0

    def dot(self, s, t, sign=1.0):
        """Jet of ``sign * (y_s . y_t)``."""
        a, b = self.env.vecs[s], self.env.vecs[t]
        m, D = a.shape[0], self.D
        g = np.zeros((m, D))
        H = np.zeros((m, D, D))
        g[:, 3 * s:3 * s + 3] += sign * b
        g[:, 3 * t:3 * t + 3] += sign * a
        i3 = sign * np.eye(3)
        H[:, 3 * s:3 * s + 3, 3 * t:3 * t + 3] += i3
        H[:, 3 * t:3 * t + 3, 3 * s:3 * s + 3] += i3
        return Jet(sign * np.einsum("ij,ij->i", a, b), g, H)


    def dist2(self, s, t):
        """Jet of ``|y_s - y_t|^2`` (the difference taken first: no cancellation)."""
        d = self.env.vecs[s] - self.env.vecs[t]
        m, D = d.shape[0], self.D
        g = np.zeros((m, D))
        H = np.zeros((m, D, D))
        g[:, 3 * s:3 * s + 3] = 2.0 * d
        g[:, 3 * t:3 * t + 3] = -2.0 * d
        i3 = 2.0 * np.eye(3)
        for a, b, sg in ((s, s, 1.0), (t, t, 1.0), (s, t, -1.0), (t, s, -1.0)):
            H[:, 3 * a:3 * a + 3, 3 * b:3 * b + 3] += sg * i3
        return Jet(np.einsum("ij,ij->i", d, d), g, H)


def _add(*jets):
    out = jets[0]
    for j in jets[1:]:
        out = Jet(out.v + j.v, _sum(out.g, j.g), _sum(out.H, j.H))
    return out


def _lin(k, j):
    """``k * j`` of a jet."""
    return Jet(k * j.v, _scaled(j.g, k), _scaled(j.H, k))


def _atan2j(s, c):
    r2 = s.v * s.v + c.v * c.v
    ok = r2 > 0
    q = np.where(ok, 1.0 / np.where(ok, r2, 1.0), 0.0)
    p1 = [c.v * q, -s.v * q]
    p2 = {(0, 0): -2.0 * s.v * c.v * q * q, (1, 1): 2.0 * s.v * c.v * q * q,
          (0, 1): (s.v * s.v - c.v * c.v) * q * q}
    return chain(np.arctan2(s.v, c.v), p1, p2, [s, c])


def _sqrtj(x):
    """``sqrt(x)`` of a non-negative jet; gradient and Hessian 0 where x = 0 (the measures'
    convention at singular points)."""
    r = np.sqrt(np.maximum(x.v, 0.0))
    ok = r > 0
    inv = np.where(ok, 1.0 / np.where(ok, r, 1.0), 0.0)
    return chain(r, [0.5 * inv], {(0, 0): -0.25 * inv ** 3}, [x])


def _zero_where(j, mask):
    if not mask.any():
        return j
    return Jet(np.where(mask, 0.0, j.v), _scaled(j.g, ~mask), _scaled(j.H, ~mask))


def _measure(V, name, slots, ref):
    if name in ("DX", "DY", "DZ"):
        pi, pj, e = slots
        return _add(V.dot(pi, e), V.dot(pj, e, -1.0))
    if name == "DM":
        return _sqrtj(V.dist2(*slots))
    if name == "INCANG":                # |a|^2 |b|^2 - (a.b)^2 = |a x b|^2, a.b from distances
        pi, pj, pk = slots
        aa, bb = V.dist2(pi, pj), V.dist2(pk, pj)
        ab = _lin(0.5, _add(aa, bb, _lin(-1.0, V.dist2(pi, pk))))
        s = _sqrtj(_add(_mul(aa, bb), _lin(-1.0, _mul(ab, ab))))
        out = _atan2j(s, ab)
        flat = _zero_where(out, s.v <= 0)           # collinear: derivatives 0, value kept
        return Jet(out.v, flat.g, flat.H)
    if name in ("THETA", "PITCH"):
        u, a, b, c = slots
        sa, sb, sc = V.dot(u, a), V.dot(u, b), V.dot(u, c)
        h = _sqrtj(_add(_mul(sa, sa), _mul(sb, sb)))
        out = _atan2j(h, sc) if name == "THETA" else _atan2j(sc, h)
        flat = _zero_where(out, h.v <= 0)           # gimbal lock: derivatives 0, value kept
        return Jet(out.v, flat.g, flat.H)
    if name == "PSI":
        zI, yJ, xJ, xI = slots
        r13, r23 = V.dot(zI, xJ), V.dot(zI, yJ, -1.0)
        out = _atan2j(r13, r23)
        lock = np.hypot(r13.v, r23.v) <= EULER_LOCK_TOL
        if lock.any():
            alt = _atan2j(V.dot(yJ, xI), V.dot(xJ, xI))
            L1, L2 = lock[:, None], lock[:, None, None]
            out = Jet(np.where(lock, alt.v, out.v), np.where(L1, alt.g, out.g),
                      np.where(L2, alt.H, out.H))
        return out
    u, cv, sv = slots
    out = _atan2j(V.dot(u, sv), V.dot(u, cv))
    if name == "PHI":
        out = _zero_where(out, np.hypot(V.dot(u, sv).v, V.dot(u, cv).v) <= EULER_LOCK_TOL)
    if ref is not None:
        out = Jet(wrap_to_ref(out.v, ref), out.g, out.H)
    return out


# ------------------------------------------------------------------------- the program
def build_hessian(key, S, U):
    """A closure ``env -> Jet`` over ``D = 3 S + U`` local variables for the tape ``key`` (see
    :func:`poise.expr.tape.extract`); ``env`` is the :class:`poise.expr.program.GroupEnv` of the
    first-order evaluation. Raises :class:`NoHessian` for reaction channels and IMPACT/BISTOP."""
    for op in key:
        if op[0] == "rx":
            raise NoHessian("element-force and reaction functions (JOINT, FX, ...)")
        if op[0] == "fn" and op[1] in NO_SECOND:
            raise NoHessian(op[1])
    D = 3 * S + U

    def program(env):
        m = env.t.shape[0]
        V = _Vars(env, D)
        J = []
        for op in key:
            tag = op[0]
            if tag == "c":
                J.append(Jet(np.broadcast_to(env.params[op[1]], (m,))))
            elif tag == "time":
                J.append(Jet(env.t))
            elif tag == "sc":
                g = np.zeros((m, D))
                g[:, 3 * S + op[1]] = 1.0
                J.append(Jet(env.sc[:, op[1]], g))
            elif tag == "neg":
                a = J[op[1]]
                J.append(Jet(-a.v, _scaled(a.g, -1.0), _scaled(a.H, -1.0)))
            elif tag == "bin":
                a, b = J[op[2]], J[op[3]]
                o = op[1]
                if o in "+-":
                    s = 1.0 if o == "+" else -1.0
                    J.append(Jet(a.v + s * b.v, _sum(a.g, b.g, s), _sum(a.H, b.H, s)))
                elif o == "*":
                    J.append(_mul(a, b))
                elif o == "/":
                    J.append(_div(a, b))
                else:
                    J.append(_pow(a, b))
            elif tag == "fn":
                args = [J[i] for i in op[2]]
                v, p1 = FUNCTIONS[op[1]]([a.v for a in args], [True] * len(args))
                J.append(chain(v, p1, SECOND[op[1]]([a.v for a in args]), args))
            elif tag == "meas":
                assert len(op[2]) == len(MEASURE_SLOTS[op[1]])
                ref = env.ang[:, op[3]] if (op[3] >= 0 and env.ang is not None) else None
                J.append(_measure(V, op[1], op[2], ref))
            elif tag == "spl":
                J.append(_spline(env, op, J))
            else:
                raise NoHessian(tag)  # pragma: no cover
        out = J[-1]
        g = out.g if out.g is not None else np.zeros((m, D))
        H = out.H if out.H is not None else np.zeros((m, D, D))
        return np.broadcast_to(out.v, (m,)), g, H
    return program


def _spline(env, op, J):
    """``S^(order)(x, z)``: first partials from ``order``, second from ``order + 1`` (cubic
    pieces: the x-derivative of order 4 is 0; linear in z between curves: no z-z term)."""
    _, _kind, order, ix, iz, si = op
    x, z = J[ix], J[iz]
    m = x.v.shape[0]
    parts = env.spl[si]
    out = [np.empty(m) for _ in range(5)]

    def ev(sp, rows):
        v, dx, dz = sp.evaluate(x.v[rows], z.v[rows], order)
        v1, dxx, dxz = sp.evaluate(x.v[rows], z.v[rows], order + 1)
        if order + 2 > 3:
            dxx = np.zeros_like(dxx)
        for k, a in enumerate((v, dx, dz, dxx, dxz)):
            out[k][rows] = a
    for sp, rows in parts:
        ev(sp, rows)
    v, dx, dz, dxx, dxz = out
    return chain(v, [dx, dz], {(0, 0): dxx, (0, 1): dxz}, [x, z])
