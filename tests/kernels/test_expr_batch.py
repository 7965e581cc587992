"""Batch compiler: grouping, scatter, state access, splines, errors."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.interpolate import Akima1DInterpolator, CubicSpline

from poise.core.errors import DeckError, EvaluationError
from poise.expr import EvalContext, compile_batch

from support.expr import FakeResolver, fd_check_scalars, make_ctx, mkexpr, scalar_grad


def test_grouping_and_order():
    texts = ["-1000*(DM(1,2)-50)+STEP(TIME,0,0,1,100)", "3.5", "SIN(TIME)",
             "-20*(DM(3,4)-5)+STEP(TIME,0.5,0,2,10)", "-7*(DM(2,1)-1)+STEP(TIME,0,1,1,3)"]
    exprs = [mkexpr(t, line=i) for i, t in enumerate(texts)] + [2.25]
    b = compile_batch(exprs, FakeResolver())
    assert b.n == 6
    assert len(b.groups) == 3          # DM/STEP family, constants, SIN(TIME)
    ctx = make_ctx()
    res = b.evaluate(ctx)
    P = ctx.P

    def step(x, x0, h0, x1, h1):
        d = min(max((x - x0) / (x1 - x0), 0), 1)
        return h0 + (h1 - h0) * d * d * (3 - 2 * d)

    t = ctx.t
    expect = [-1000 * (np.linalg.norm(P[0] - P[1]) - 50) + step(t, 0, 0, 1, 100), 3.5,
              math.sin(t), -20 * (np.linalg.norm(P[2] - P[3]) - 5) + step(t, .5, 0, 2, 10),
              -7 * (np.linalg.norm(P[1] - P[0]) - 1) + step(t, 0, 1, 1, 3), 2.25]
    np.testing.assert_allclose(res.value, expect, rtol=1e-13)
    assert res.d_time[1] == 0 and res.d_time[2] == pytest.approx(math.cos(t))
    assert list(b.time_mask) == [True, False, True, True, True, False]
    assert list(b.state_mask) == [True, False, False, True, True, False]
    assert b.depends_on_time and b.depends_on_state
    # slots: instance 0 reads origins of markers 1 and 2 (indices 0, 1)
    assert list(b.slot_marker[0]) == [0, 1] and list(b.slot_kind[0]) == [0, 0]
    assert list(b.slot_marker[1]) == [-1, -1]
    u = (P[0] - P[1]) / np.linalg.norm(P[0] - P[1])
    np.testing.assert_allclose(res.d_slot[0], [-1000 * u, 1000 * u])


def test_global_frame_slots_are_zeroed_and_grouped():
    b = compile_batch([mkexpr("DX(1)"), mkexpr("DX(1, 2, 3)")], FakeResolver())
    assert len(b.groups) == 1
    res = b.evaluate(make_ctx())
    assert list(b.slot_marker[0]) == [0, -1, -1]
    assert np.all(res.d_slot[0, 1:] == 0)
    np.testing.assert_allclose(res.d_slot[0, 0], [1, 0, 0])


def test_shared_slots_deduplicated():
    b = compile_batch([mkexpr("DM(1,2) + DX(1,2)"), mkexpr("DM(3,4) + DX(5,6)")],
                      FakeResolver())
    assert len(b.groups) == 2
    assert list(b.slot_marker[0][:3]) == [0, 1, -1]


def test_constant_folding():
    b = compile_batch([mkexpr("SIN(PI/4)*2 + 3**2 - ARYVAL(1,3)")], FakeResolver())
    assert b.groups[0].key == (("c", 0),)
    assert b.evaluate(make_ctx()).value[0] == pytest.approx(math.sqrt(2) + 9 - 30)
    # a failing constant sub-expression would fail at every evaluation: a located deck error
    with pytest.raises(DeckError, match=r"expr col 9: division by zero"):
        compile_batch([mkexpr("TIME + 1/0")], FakeResolver())


def test_variables_and_states():
    r = FakeResolver(explicit={101: "2*VARVAL(1) + TIME", 102: 4.5, 103: "VARVAL(101)**2"})
    b = compile_batch([mkexpr("VARVAL(103) + VARVAL(102) + DIF(2) + 3*DIF1(2) + DIF1(1)")], r)
    sc = np.zeros(50)
    sc[0], sc[22], sc[42] = 1.5, 7.0, -2.0
    res = b.evaluate(make_ctx(scalars=sc))
    v = 2 * 1.5 + 0.3
    assert res.value[0] == pytest.approx(v * v + 4.5 + 7.0 - 6.0)
    g = scalar_grad(res)
    assert g[0] == pytest.approx(2 * v * 2) and g[22] == 1 and g[42] == 3
    assert res.d_time[0] == pytest.approx(2 * v)


def spline_ref(kind, x, y, q, lin):
    if kind == "LINSPL":
        # a linear interpolant's own extrapolation is the continued end segment
        f = np.interp(q, x, y)
        s0 = (y[1] - y[0]) / (x[1] - x[0])
        s1 = (y[-1] - y[-2]) / (x[-1] - x[-2])
        f = np.where(q < x[0], y[0] + s0 * (q - x[0]), f)
        return np.where(q > x[-1], y[-1] + s1 * (q - x[-1]), f)
    sp = Akima1DInterpolator(x, y) if kind == "AKISPL" else CubicSpline(x, y)
    if kind == "AKISPL":
        sp.extrapolate = True
    f = sp(q)
    if lin:
        f = np.where(q < x[0], y[0] + sp(x[0], 1) * (q - x[0]), f)
        f = np.where(q > x[-1], y[-1] + sp(x[-1], 1) * (q - x[-1]), f)
    return f


@pytest.mark.parametrize("kind", ["AKISPL", "CUBSPL", "LINSPL"])
@pytest.mark.parametrize("sid", [1, 3])
def test_spline_curves(kind, sid):
    r = FakeResolver()
    x, y, _, lin = r.spline(sid)
    qs = [-0.5, 0.0, 0.4, 1.0, 2.2, 3.7, 5.9, 6.0, 7.0]
    b = compile_batch([mkexpr(f"{kind}(VARVAL(1), 0, {sid})")] * len(qs), r)
    sc = np.zeros((len(qs), 50))
    res = [b.evaluate(make_ctx(scalars=np.r_[q, np.zeros(49)])).value[0] for q in qs]
    np.testing.assert_allclose(res, spline_ref(kind, x, y, np.array(qs), lin), atol=1e-12)
    del sc
    for q in (-0.5, 0.4, 2.2, 3.7, 7.0):
        for order in (0, 1):
            fd_check_scalars(f"{kind}(VARVAL(1)*2 - VARVAL(2), 0, {sid}, {order})",
                             (q, q), h=1e-6, rtol=1e-5, atol=1e-6)
    if kind == "CUBSPL" and not lin:
        # order 1 / 2 against scipy's derivative of the same (not-a-knot) spline
        cs = CubicSpline(x, y)
        for order in (1, 2):
            b = compile_batch([mkexpr(f"CUBSPL(1.3, 0, 1, {order})")], r)
            assert b.evaluate(make_ctx()).value[0] == pytest.approx(cs(1.3, order))


@pytest.mark.parametrize("kind", ["AKISPL", "CUBSPL", "LINSPL"])
def test_spline_family_linear_in_z(kind):
    r = FakeResolver()
    x, Y, z, _ = r.spline(2)
    for xq, zq in ((0.7, 0.25), (2.5, 2.0), (4.0, 0.0), (1.3, 3.0)):
        k = 0 if zq < 1.0 else 1
        w = (zq - z[k]) / (z[k + 1] - z[k])
        f0 = spline_ref(kind, x, Y[k], np.array([xq]), False)[0]
        f1 = spline_ref(kind, x, Y[k + 1], np.array([xq]), False)[0]
        val = fd_check_scalars(f"{kind}(VARVAL(1), VARVAL(2), 2)", (xq, zq + 1e-3 * (zq in z)),
                               h=1e-7, rtol=1e-5, atol=1e-5)
        if zq not in z:
            assert val == pytest.approx((1 - w) * f0 + w * f1, abs=1e-12)


def test_mixed_splines_in_one_group():
    r = FakeResolver()
    exprs = [mkexpr("AKISPL(TIME*10, 0, 1)"), mkexpr("AKISPL(TIME*10, 0, 3)"),
             mkexpr("AKISPL(TIME*20, 0, 1)")]
    b = compile_batch(exprs, r)
    assert len(b.groups) == 1
    res = b.evaluate(make_ctx())
    x, y, _, _ = r.spline(1)
    np.testing.assert_allclose(res.value, Akima1DInterpolator(x, y)([3.0, 3.0, 6.0]),
                               atol=1e-12)


def test_evaluation_error_names_first_failing_instance():
    exprs = [mkexpr(f"SQRT(DX(1) - {v})", line=10 + i, id=100 + i)
             for i, v in enumerate([-1e9, -1e9, 1e9, 1e9])]
    b = compile_batch(exprs, FakeResolver())
    assert len(b.groups) == 1
    with pytest.raises(EvaluationError) as ei:
        b.evaluate(make_ctx())
    assert str(ei.value).startswith("deck.xml:12: <Force_Scalar_TwoBody id=102> expr: SQRT of")
    assert ei.value.attr == "expr" and ei.value.loc.id == 102


def test_many_instances_vectorised():
    n = 2000
    exprs = [mkexpr(f"-{1000 + i}*(DM({1 + i % 5},{2 + i % 5})-{50 + i % 7})"
                    f"+STEP(TIME,0,0,1,{100 + i})") for i in range(n)]
    b = compile_batch(exprs, FakeResolver())
    assert len(b.groups) == 1
    ctx = make_ctx()
    res = b.evaluate(ctx)
    i = 1234
    d = np.linalg.norm(ctx.P[i % 5] - ctx.P[i % 5 + 1])
    t = ctx.t
    assert res.value[i] == pytest.approx(-(1000 + i) * (d - (50 + i % 7))
                                         + (100 + i) * t * t * (3 - 2 * t))


def test_plain_float_batch_and_empty():
    b = compile_batch([1.0, 2.0], FakeResolver())
    res = b.evaluate(EvalContext())
    assert list(res.value) == [1.0, 2.0] and res.d_slot.shape == (2, 0, 3)
    b = compile_batch([], FakeResolver())
    assert b.evaluate(EvalContext()).value.shape == (0,)


def test_global_frame_only_needs_no_markers():
    b = compile_batch([mkexpr("DX(0) + DM(0, 0) + AZ(0)")], FakeResolver())
    res = b.evaluate(EvalContext())
    assert res.value[0] == 0.0 and np.all(res.d_slot == 0)


def test_resolver_raising_keyerror_for_global_frame():
    class R(FakeResolver):
        def marker_index(self, id):
            if id == 0:
                raise KeyError(0)
            return super().marker_index(id)

    b = compile_batch([mkexpr("DX(1)")], R())
    assert list(b.slot_marker[0]) == [0, -1, -1]
