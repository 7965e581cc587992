"""Function library: values against independent formulas, derivatives against central FD."""
from __future__ import annotations

import math

import numpy as np
import pytest

from poise.core.errors import EvaluationError

from support.expr import ev, fd_check_scalars, make_ctx


V = [f"VARVAL({k})" for k in range(1, 21)]


def call(name, n):
    if name == "IF":
        return f"IF({V[0]}: {V[1]}, {V[2]}, {V[3]})"
    return f"{name}({', '.join(V[:n])})"


def step_ref(x, x0, h0, x1, h1):
    if x <= x0:
        return h0
    if x >= x1:
        return h1
    d = (x - x0) / (x1 - x0)
    return h0 + (h1 - h0) * d * d * (3 - 2 * d)


def step5_ref(x, x0, h0, x1, h1):
    if x <= x0:
        return h0
    if x >= x1:
        return h1
    d = (x - x0) / (x1 - x0)
    return h0 + (h1 - h0) * d ** 3 * (10 - 15 * d + 6 * d * d)


def havsin_ref(x, x0, h0, x1, h1):
    if x <= x0:
        return h0
    if x >= x1:
        return h1
    d = (x - x0) / (x1 - x0)
    return (h0 + h1) / 2 + (h1 - h0) / 2 * math.sin(math.pi * d - math.pi / 2)


def impact_ref(x, xd, x1, k, e, cmax, d):
    if x >= x1:
        return 0.0
    return max(k * (x1 - x) ** e - step_ref(x, x1 - d, cmax, x1, 0) * xd, 0.0)


def bistop_ref(x, xd, x1, x2, k, e, cmax, d):
    if x < x1:
        return max(k * (x1 - x) ** e - step_ref(x, x1 - d, cmax, x1, 0) * xd, 0.0)
    if x <= x2:
        return 0.0
    return min(-k * (x - x2) ** e - step_ref(x, x2, 0, x2 + d, cmax) * xd, 0.0)


def cheb_ref(u, coef):
    t = [1.0, u]
    while len(t) < len(coef):
        t.append(2 * u * t[-1] - t[-2])
    return sum(c * tj for c, tj in zip(coef, t))


class Jump(tuple):
    """Argument tuple at a discontinuity: value checked, derivative not FD-checked."""


# (name, reference, list of argument tuples); every argument tuple except Jump(...) points
# is also FD-checked
CASES = [
    ("ABS", abs, [(-1.3,), (2.1,)]),
    ("ACOS", math.acos, [(0.3,), (-0.7,)]),
    ("ASIN", math.asin, [(0.3,), (-0.7,)]),
    ("ATAN", math.atan, [(0.3,), (-4.0,)]),
    ("ATAN2", math.atan2, [(0.3, -0.5), (-1.0, 2.0), (1.0, -3.0)]),
    ("COS", math.cos, [(0.3,), (4.0,)]),
    ("COSH", math.cosh, [(0.3,), (-1.5,)]),
    ("EXP", math.exp, [(0.3,), (-2.0,)]),
    ("LOG", math.log, [(0.3,), (20.0,)]),
    ("LOG10", math.log10, [(0.3,), (20.0,)]),
    ("SIN", math.sin, [(0.3,), (4.0,)]),
    ("SINH", math.sinh, [(0.3,), (-1.5,)]),
    ("SQRT", math.sqrt, [(0.3,), (20.0,)]),
    ("TAN", math.tan, [(0.3,), (-1.2,)]),
    ("TANH", math.tanh, [(0.3,), (-1.2,)]),
    ("MAX", max, [(1.0, 2.0), (3.0, -1.0)]),
    ("MIN", min, [(1.0, 2.0), (3.0, -1.0)]),
    ("MOD", lambda a, b: a - int(a / b) * b, [(7.3, 2.0), (-7.3, 2.0), (7.3, -2.5)]),
    ("DIM", lambda a, b: max(a - b, 0.0), [(3.0, 1.0), (1.0, 3.0)]),
    ("SIGN", lambda a, b: abs(a) if b >= 0 else -abs(a), [(-3.0, 1.0), (3.0, -1.0),
                                                         Jump((2.0, 0.0))]),
    ("AINT", lambda a: float(int(a)), [(2.7,), (-2.7,)]),
    ("ANINT", lambda a: math.copysign(math.floor(abs(a) + 0.5), a), [Jump((2.5,)),
                                                                     Jump((-2.5,)),
                                                                     (2.4,), (-2.6,)]),
    ("IF", lambda c, a, b, d: a if c < 0 else (b if c == 0 else d),
     [(-1.0, 2.0, 3.0, 4.0), Jump((0.0, 2.0, 3.0, 4.0)), (0.5, 2.0, 3.0, 4.0)]),
    ("STEP", step_ref, [(x, 1.0, -2.0, 3.0, 5.0) for x in (0.0, 1.0, 1.7, 2.0, 2.9, 3.0, 4.0)]),
    ("STEP5", step5_ref, [(x, 1.0, -2.0, 3.0, 5.0) for x in (0.0, 1.0, 1.7, 2.9, 3.0, 4.0)]),
    ("HAVSIN", havsin_ref, [(x, 1.0, -2.0, 3.0, 5.0) for x in (0.0, 1.0, 1.7, 2.9, 3.0, 4)]),
    ("SHF", lambda x, x0, a, w, p, b: a * math.sin(w * (x - x0) - p) + b,
     [(0.7, 0.2, 2.0, 3.0, 0.4, 1.5)]),
    ("POLY", lambda x, x0, *c: sum(cj * (x - x0) ** j for j, cj in enumerate(c)),
     [(1.7, 0.5, 1.0), (1.7, 0.5, 1.0, -2.0, 3.0, 0.5), (-0.3, 0.5, 2.0, 1.0)]),
    ("CHEBY", lambda x, x0, *c: cheb_ref(x - x0, c),
     [(0.7, 0.2, 1.0), (0.7, 0.2, 1.0, -2.0), (0.7, 0.2, 1.0, -2.0, 3.0, 0.5, 0.25)]),
    ("FORCOS", lambda x, x0, w, *a: a[0] + sum(aj * math.cos(j * w * (x - x0))
                                               for j, aj in enumerate(a) if j),
     [(0.7, 0.2, 2.0, 1.0, 0.5, -0.3, 0.2)]),
    ("FORSIN", lambda x, x0, w, *a: a[0] + sum(aj * math.sin(j * w * (x - x0))
                                               for j, aj in enumerate(a) if j),
     [(0.7, 0.2, 2.0, 1.0, 0.5, -0.3, 0.2), (0.7, 0.2, 2.0, 1.0)]),
    ("IMPACT", impact_ref, [(x, 0.0, 1.0, 100.0, 1.5, 2.0, 0.1) for x in (0.5, 0.95, 1.2)]
     + [(0.5, 0.0, 1.0, 100.0, 1.0, 2.0, 0.1)]),
    ("BISTOP", bistop_ref, [(x, 0.0, 1.0, 2.0, 100.0, 1.5, 2.0, 0.1)
                            for x in (0.5, 0.95, 1.5, 2.05, 2.5)]),
]


@pytest.mark.parametrize("name,ref,points", CASES, ids=[c[0] for c in CASES])
def test_value_and_derivative(name, ref, points):
    for args in points:
        text = call(name, len(args))
        if isinstance(args, Jump):
            sc = np.zeros(50)
            sc[: len(args)] = args
            val = ev(text, make_ctx(scalars=sc))[0].value[0]
        else:
            val = fd_check_scalars(text, args, h=1e-7, rtol=1e-5, atol=1e-5)
        assert val == pytest.approx(ref(*args), rel=1e-12, abs=1e-12), (text, args)


@pytest.mark.parametrize("text,expect", [
    ("STEP(1.5, 1, 0, 2, 10)", 5.0),
    ("STEP(TIME, 0, 0, 1, 100)", 100 * 0.3 ** 2 * (3 - 0.6)),
    ("HAVSIN(1.5, 1, 0, 2, 10)", 5.0),
    ("STEP5(1.5, 1, 0, 2, 10)", 5.0),
    ("MAX(1, 5, 3)", 5.0),
    ("MIN(4, 2, 3, -1)", -1.0),
    ("IF(-1: 1, 2, 3)", 1.0),
    ("if(0 : 1, 2, 3)", 2.0),
    ("IF(TIME: 1, 2, 3)", 3.0),
    ("ARYVAL(1, 2)", 20.0),
    ("SHF(TIME, 0, 2, 90D, 0D, 1)", 2 * math.sin(math.pi / 2 * 0.3) + 1),
    ("FORCOS(TIME, 0, 360D, 1, 2)", 1 + 2 * math.cos(2 * math.pi * 0.3)),
])
def test_constant_values(text, expect):
    res, _ = ev(text)
    assert res.value[0] == pytest.approx(expect, rel=1e-12)


def test_derivative_edges_of_step_and_impact():
    # STEP at and near both breakpoints (C1 profile -> FD works at the knots themselves)
    for x in (1.0 - 1e-3, 1.0, 1.0 + 1e-3, 3.0 - 1e-3, 3.0, 3.0 + 1e-3):
        fd_check_scalars(call("STEP", 5), (x, 1.0, -2.0, 3.0, 5.0), h=1e-7, atol=1e-5)
    # IMPACT with e > 1 is C1 across the contact point
    for x in (1.0 - 1e-3, 1.0 + 1e-3):
        fd_check_scalars(call("IMPACT", 7), (x, 0.0, 1.0, 100.0, 2.0, 2.0, 0.1), h=1e-7,
                         atol=1e-4)
    # MOD close to (but not across) a jump
    fd_check_scalars(call("MOD", 2), (3.999, 2.0), h=1e-7)
    # IF close to the switch on either side
    fd_check_scalars(f"IF({V[0]}: {V[1]}*{V[1]}, 0, {V[2]}**3)", (-1e-4, 1.5, 2.0), h=1e-7)
    fd_check_scalars(f"IF({V[0]}: {V[1]}*{V[1]}, 0, {V[2]}**3)", (1e-4, 1.5, 2.0), h=1e-7)


def test_impact_velocity_ignored_in_static_context():
    res, b = ev("IMPACT(0.95, 10, 1, 100, 1, 2, 0.1)")
    assert res.value[0] == pytest.approx(100 * 0.05)
    dyn = make_ctx(static=False)
    # dynamic: velocity term uses STEP(x, x1-d, cmax, x1, 0)
    expect = max(100 * 0.05 - step_ref(0.95, 0.9, 2.0, 1.0, 0.0) * 10, 0.0)
    assert b.evaluate(dyn).value[0] == pytest.approx(expect)


def test_impact_dynamic_derivatives():
    # non-static: the damping part and all derivatives
    from support.expr import FakeResolver, mkexpr
    from poise.expr import compile_batch
    text = call("IMPACT", 7)
    b = compile_batch([mkexpr(text)], FakeResolver())
    x = np.array([0.95, -0.3, 1.0, 100.0, 1.5, 2.0, 0.1])
    sc = np.zeros(50)
    sc[:7] = x
    res = b.evaluate(make_ctx(scalars=sc, static=False))
    assert res.value[0] == pytest.approx(impact_ref(*x))
    for k in range(7):
        sp, sm = sc.copy(), sc.copy()
        sp[k] += 1e-7
        sm[k] -= 1e-7
        fd = (b.evaluate(make_ctx(scalars=sp, static=False)).value[0]
              - b.evaluate(make_ctx(scalars=sm, static=False)).value[0]) / 2e-7
        assert res.d_scalar[0, list(res.scalar_index[0]).index(k)] == pytest.approx(
            fd, rel=1e-5, abs=1e-5)


def test_operators_and_power_derivatives():
    fd_check_scalars(f"{V[0]}**{V[1]}", (1.7, 2.3))
    fd_check_scalars(f"{V[0]}/{V[1]} - {V[0]}*{V[1]}", (1.7, -2.3))
    fd_check_scalars(f"-{V[0]}**2 + (-{V[1]})**3", (1.7, 0.4))
    assert fd_check_scalars(f"{V[0]}**2", (-3.0,)) == pytest.approx(9.0)


@pytest.mark.parametrize("text,msg", [
    ("1/(TIME-0.3)", "division by zero"),
    ("SQRT(TIME-1)", "SQRT of a negative"),
    ("LOG(TIME-0.3)", "LOG of a non-positive"),
    ("ASIN(TIME+1)", "ASIN argument outside"),
    ("ACOS(-TIME-1)", "ACOS argument outside"),
    ("EXP(10000*TIME)", "non-finite value"),
    ("(-TIME)**0.5", "non-integer power"),
    ("MOD(TIME, 0)", "zero divisor"),
])
def test_evaluation_errors(text, msg):
    with pytest.raises(EvaluationError) as ei:
        ev(text)
    s = str(ei.value)
    assert msg in s
    assert s.startswith("deck.xml:7: <Force_Scalar_TwoBody id=3> expr:")
