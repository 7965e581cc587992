"""Property test: random expression trees, text and Python reference built from the same tree.

The reference is a Python lambda assembled directly from the random tree (never from poise's
AST), so parser, precedence, number syntax and function semantics are all checked.
"""
from __future__ import annotations

import math

from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from poise.core.errors import EvaluationError
from poise.expr import EvalContext, compile_batch

from support.expr import FakeResolver, mkexpr


# literal text -> value (written independently of the tokenizer)
LITERALS = [("2", 2.0), ("2.", 2.0), ("2.0", 2.0), (".5", 0.5), ("0.5", 0.5),
            ("1.5E0", 1.5), ("15D-1", 1.5), ("2.5d0", 2.5), ("1.E-1", 0.1), ("3e0", 3.0),
            ("90D", math.pi / 2), ("45d", math.pi / 4), ("0", 0.0), ("7", 7.0),
            ("PI", math.pi), ("DTOR", math.pi / 180), ("rtod", 180 / math.pi)]


_TIES = []        # records IF conditions at 0 and MIN/MAX ties (derivative is branch-defined there)


def _if(c, a, b, d):
    if c < 0:
        return a
    if c == 0:
        _TIES.append(1)
        return b
    return d


def _sincos(name):
    return math.sin if name.upper() == "SIN" else math.cos


def _minmax(name):
    f = min if name.upper() == "MIN" else max

    def g(a, b):
        if a == b:             # kink: the derivative is branch-defined there, like IF at 0
            _TIES.append(1)
        return f(a, b)
    return g


def step(x, x0, h0, x1, h1):
    if x <= x0:
        return h0
    if x >= x1:
        return h1
    d = (x - x0) / (x1 - x0)
    return h0 + (h1 - h0) * d * d * (3 - 2 * d)


leaf = st.one_of(
    st.just(("TIME", lambda t: t)),
    st.sampled_from(LITERALS).map(lambda lv: (lv[0], lambda t, v=lv[1]: v)),
)


def P(s):
    return f"({s})"


def extend(children):
    two = st.tuples(children, children)
    name = st.sampled_from
    return st.one_of(
        two.map(lambda ab: (f"{P(ab[0][0])}+{P(ab[1][0])}",
                            lambda t, a=ab[0][1], b=ab[1][1]: a(t) + b(t))),
        two.map(lambda ab: (f"{P(ab[0][0])} - {P(ab[1][0])}",
                            lambda t, a=ab[0][1], b=ab[1][1]: a(t) - b(t))),
        two.map(lambda ab: (f"{P(ab[0][0])}*{P(ab[1][0])}",
                            lambda t, a=ab[0][1], b=ab[1][1]: a(t) * b(t))),
        two.map(lambda ab: (f"{P(ab[0][0])}/(ABS({ab[1][0]})+1)",
                            lambda t, a=ab[0][1], b=ab[1][1]: a(t) / (abs(b(t)) + 1))),
        st.tuples(children, st.sampled_from(["2", "3", "0.5", "1.5"])).map(
            lambda ac: (f"(ABS({ac[0][0]})+1)**{ac[1]}",
                        lambda t, a=ac[0][1], c=float(ac[1]): (abs(a(t)) + 1) ** c)),
        children.map(lambda a: (f"-{P(a[0])}", lambda t, f=a[1]: -f(t))),
        st.tuples(children, name(["SIN", "sin", "Cos", "COS"])).map(
            lambda an: (f"{an[1]}({an[0][0]})",
                        lambda t, f=an[0][1], n=an[1]: _sincos(n)(f(t)))),
        children.map(lambda a: (f"EXP(SIN({a[0]}))", lambda t, f=a[1]: math.exp(math.sin(f(t))))),
        children.map(lambda a: (f"SQRT(ABS({a[0]})+1)",
                                lambda t, f=a[1]: math.sqrt(abs(f(t)) + 1))),
        st.tuples(children, name(["MIN", "MAX", "min"])).map(
            lambda an: (f"{an[1]}({an[0][0]}, TIME*2)",
                        lambda t, f=an[0][1], n=an[1]: _minmax(n)(f(t), t * 2))),
        st.tuples(children, children, st.floats(-1, 1), st.floats(0.1, 2)).map(
            lambda q: (f"STEP({q[0][0]}, {q[2]!r}, {q[1][0]}, {q[2] + q[3]!r}, -1.5)",
                       lambda t, a=q[0][1], b=q[1][1], x0=q[2], x1=q[2] + q[3]:
                       step(a(t), x0, b(t), x1, -1.5))),
        st.tuples(children, children, children, children).map(
            lambda q: (f"IF({q[0][0]}: {q[1][0]}, {q[2][0]}, {q[3][0]})",
                       lambda t, c=q[0][1], a=q[1][1], b=q[2][1], d=q[3][1]:
                       _if(c(t), a(t), b(t), d(t)))),
    )


trees = st.recursive(leaf, extend, max_leaves=12)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tree=trees, t=st.floats(-2.0, 2.0))
@example(tree=("SQRT(ABS((DTOR)*((TIME)*(DTOR)))+1)",
               lambda t: math.sqrt(abs(math.pi / 180 * t * math.pi / 180) + 1)), t=-1e-9)
def test_random_expressions_match_reference(tree, t):
    text, ref = tree
    _TIES.clear()
    try:
        expect = ref(t)
    except (OverflowError, ZeroDivisionError, ValueError):
        assume(False)
    assume(math.isfinite(expect) and abs(expect) < 1e30)
    b = compile_batch([mkexpr(text)], FakeResolver())
    ctx = EvalContext(t=t)
    try:
        res = b.evaluate(ctx)
    except EvaluationError as e:       # only acceptable for overflowing derivatives
        assume("derivative" not in str(e))
        raise
    assert math.isclose(res.value[0], expect, rel_tol=1e-9, abs_tol=1e-9), text
    # d/dTIME against central differences where the reference is smooth around t
    if _TIES:
        return
    try:
        fd1 = (ref(t + 1e-5) - ref(t - 1e-5)) / 2e-5
        fd2 = (ref(t + 1e-6) - ref(t - 1e-6)) / 2e-6
        fwd = (ref(t + 1e-6) - expect) / 1e-6
        bwd = (expect - ref(t - 1e-6)) / 1e-6
    except (OverflowError, ZeroDivisionError, ValueError):
        return
    # a kink (ABS at 0) shows as fwd != bwd by the jump in slope: it must be below the
    # tolerance of the derivative check itself, else the derivative there is branch-defined
    # (SQRT(ABS(DTOR*TIME*DTOR)+1) near TIME = 0 has a jump of DTOR**2 = 3e-4, under 1e-3)
    smooth = abs(fd1 - fd2) <= 1e-5 * (1 + abs(fd1)) and abs(fwd - bwd) <= 1e-5 * (1 + abs(fd2))
    if smooth and abs(fd2) < 1e8:
        assert math.isclose(res.d_time[0], fd2, rel_tol=1e-4, abs_tol=1e-4), text


def test_structure_sharing_across_constants():
    # the same tree with different literals forms one group and matches the reference
    exprs = [mkexpr(f"STEP(TIME, {a}, 1, {a + 1}, 2)*SIN({a}D*TIME)") for a in range(1, 40)]
    b = compile_batch(exprs, FakeResolver())
    assert len(b.groups) == 1
    res = b.evaluate(EvalContext(t=1.7))
    for a, v in zip(range(1, 40), res.value, strict=True):
        assert math.isclose(v, step(1.7, a, 1, a + 1, 2) * math.sin(math.radians(a) * 1.7),
                            rel_tol=1e-12, abs_tol=1e-12)
