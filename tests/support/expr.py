"""Shared helpers for the expression tests: a fake resolver, evaluation helpers and rotation
matrices about the coordinate axes."""
from __future__ import annotations

import math

import numpy as np

from poise.deck.spec import Expr
from poise.core.errors import SourceLoc
from poise.expr import EvalContext, compile_batch

N_MARKERS = 6
N_IMPLICIT = 20


class FakeResolver:
    """Markers 1..6 -> index id-1; VARVAL 1..20 implicit (scalar id-1); explicit variables
    from ``explicit``; DIF(id) -> scalar 20+id; DIF1(1) None, DIF1(id) -> scalar 40+id; spline 1
    a curve, 2 a 2-D family, 3 a curve with linear extrapolation; ARYVAL(1, k) = 10k; reaction
    channels allocated on demand (GFORCE not implemented)."""

    def __init__(self, explicit=None):
        self.explicit = explicit or {}
        self.channels = {}
        self.angles = {}
        self.calls = []

    def marker_index(self, id):
        if id == 0:
            return -1
        if 1 <= id <= N_MARKERS:
            return id - 1
        raise KeyError(id)

    def variable(self, id):
        if id in self.explicit:
            v = self.explicit[id]
            if isinstance(v, str):
                v = Expr(v, SourceLoc("deck.xml", 100 + id, "Reference_Variable", id), "expr")
            return ("explicit", v)
        if 1 <= id <= N_IMPLICIT:
            return ("implicit", id - 1)
        raise KeyError(id)

    def diff_state(self, id):
        if 1 <= id <= 5:
            return 20 + id
        raise KeyError(id)

    def diff_derivative(self, id):
        if id == 1:
            return None
        return 40 + id

    def spline(self, id):
        x = np.array([0.0, 1.0, 2.0, 3.0, 4.5, 6.0])
        y = np.array([0.0, 0.8, 0.9, 0.1, -0.7, -1.0])
        if id == 1:
            return x, y, None, False
        if id == 2:
            z = np.array([0.0, 1.0, 3.0])
            return x, np.stack([y, 2 * y + 1, -y]), z, False
        if id == 3:
            return x, y, None, True
        raise KeyError(id)

    def array(self, id):
        if id == 1:
            return np.array([10.0, 20.0, 30.0])
        raise KeyError(id)

    def reaction(self, kind, id, jflag, comp, rm):
        if kind == "GFORCE":
            raise NotImplementedError("GFORCE reactions are not supported")
        key = (kind, id, jflag, comp, rm)
        self.calls.append(key)
        return self.channels.setdefault(key, len(self.channels))

    def angle_key(self, i_idx, j_idx, axis):
        return self.angles.setdefault((i_idx, j_idx, axis), len(self.angles))


def mkexpr(text, line=7, attr="expr", tag="Force_Scalar_TwoBody", id=3):
    return Expr(text, SourceLoc("deck.xml", line, tag, id), attr)


def random_frames(rng, n=N_MARKERS):
    """Random marker origins (n, 3) and orthonormal right-handed axes (n, 3, 3)."""
    P = rng.normal(size=(n, 3))
    A = np.empty((n, 3, 3))
    for i in range(n):
        q, r = np.linalg.qr(rng.normal(size=(3, 3)))
        q = q * np.sign(np.diag(r))
        if np.linalg.det(q) < 0:
            q[:, 2] *= -1
        A[i] = q
    return P, A


def make_ctx(rng=None, time=0.3, scalars=None, **kw):
    rng = rng or np.random.default_rng(1)
    P, A = random_frames(rng)
    sc = np.zeros(50) if scalars is None else np.asarray(scalars, dtype=float)
    return EvalContext(t=time, P=P, A=A, extra=sc, reactions=np.arange(10.0) + 1.0, **kw)


def ev(text, ctx=None, resolver=None):
    """Compile and evaluate one expression; returns (EvalResult, Batch)."""
    b = compile_batch([mkexpr(text)], resolver or FakeResolver())
    return b.evaluate(ctx or make_ctx()), b


def scalar_grad(res, n_scalars=50):
    """Dense d value / d scalars for instance 0."""
    g = np.zeros(n_scalars)
    for k, idx in enumerate(res.scalar_index[0]):
        if idx >= 0:
            g[idx] += res.d_scalar[0, k]
    return g


def fd_check_scalars(text, x, h=1e-6, rtol=1e-6, atol=1e-6, resolver=None):
    """Evaluate ``text`` with scalars[0:len(x)] = x (use VARVAL(1..k) as arguments) and compare
    the analytic scalar gradient with central differences."""
    x = np.asarray(x, dtype=float)
    sc = np.zeros(50)
    sc[: len(x)] = x
    res, b = ev(text, make_ctx(scalars=sc), resolver)
    g = scalar_grad(res)[: len(x)]
    fd = np.zeros(len(x))
    for k in range(len(x)):
        sp, sm = sc.copy(), sc.copy()
        sp[k] += h
        sm[k] -= h
        fp = b.evaluate(make_ctx(scalars=sp)).value[0]
        fm = b.evaluate(make_ctx(scalars=sm)).value[0]
        fd[k] = (fp - fm) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=rtol, atol=atol, err_msg=f"{text} at {x}")
    return res.value[0]


def Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])
