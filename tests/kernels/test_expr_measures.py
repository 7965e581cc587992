"""Kinematic measures against direct numpy computation; derivatives against central FD."""
from __future__ import annotations

import math

import numpy as np
import pytest

from poise.expr import EvalContext, compile_batch

from support.expr import FakeResolver, make_ctx, mkexpr, random_frames, Rx, Ry, Rz


def frame(P, A, mid):
    """Origin and axes of marker id (0 = global)."""
    if mid == 0:
        return np.zeros(3), np.eye(3)
    return P[mid - 1], A[mid - 1]


def direct(name, ids, P, A):
    I, J, K = (list(ids) + [0, 0, 0])[:3]
    pI, aI = frame(P, A, I)
    pJ, aJ = frame(P, A, J)
    _, aK = frame(P, A, K)
    d = pI - pJ
    if name in ("DX", "DY", "DZ"):
        return d @ aK[:, "XYZ".index(name[1])]
    if name == "DM":
        return np.linalg.norm(d)
    xI, yI, zI = aI.T
    xJ, yJ, zJ = aJ.T
    if name == "AZ":
        return math.atan2(xI @ yJ, xI @ xJ)
    if name == "AX":
        return math.atan2(yI @ zJ, yI @ yJ)
    if name == "AY":
        return math.atan2(zI @ xJ, zI @ zJ)
    raise KeyError(name)


CASES = [("DX", (1, 2, 3)), ("DY", (1, 2, 3)), ("DZ", (2, 4, 5)), ("DX", (1,)),
         ("DY", (1, 0, 3)), ("DZ", (3, 2)), ("DM", (1, 2)), ("DM", (4,)), ("AZ", (1, 2)),
         ("AX", (3, 4)), ("AY", (5, 6)), ("AZ", (2,))]


@pytest.mark.parametrize("name,ids", CASES)
def test_measure_values(name, ids):
    rng = np.random.default_rng(7)
    ctx = make_ctx(rng)
    text = f"{name}({', '.join(map(str, ids))})"
    res = compile_batch([mkexpr(text)], FakeResolver()).evaluate(ctx)
    assert res.value[0] == pytest.approx(direct(name, ids, ctx.P, ctx.A), abs=1e-13)


def fd_markers(text, seed=3, h=1e-6, rtol=1e-5, atol=1e-7, ctx_kw=None):
    """Compare d_slot with central differences w.r.t. every marker origin/axis component."""
    rng = np.random.default_rng(seed)
    P, A = random_frames(rng)
    kw = dict(t=0.3, extra=np.zeros(50), reactions=np.zeros(10), **(ctx_kw or {}))
    b = compile_batch([mkexpr(text)], FakeResolver())
    res = b.evaluate(EvalContext(P=P, A=A, **kw))
    # analytic dense gradient: (markers, 4 kinds, 3)
    dense = np.zeros((len(P), 4, 3))
    for s in range(res.d_slot.shape[1]):
        m, k = res.slot_marker[0, s], res.slot_kind[0, s]
        if m >= 0:
            dense[m, k] += res.d_slot[0, s]
    fd = np.zeros_like(dense)
    for m in range(len(P)):
        for k in range(4):
            for c in range(3):
                vals = []
                for sgn in (1, -1):
                    P2, A2 = P.copy(), A.copy()
                    if k == 0:
                        P2[m, c] += sgn * h
                    else:
                        A2[m, c, k - 1] += sgn * h
                    vals.append(b.evaluate(EvalContext(P=P2, A=A2, **kw)).value[0])
                fd[m, k, c] = (vals[0] - vals[1]) / (2 * h)
    np.testing.assert_allclose(dense, fd, rtol=rtol, atol=atol, err_msg=text)
    return res


@pytest.mark.parametrize("text", [
    "DX(1,2,3)", "DY(1,2,3)", "DZ(1,2,3)", "DX(1)", "DM(1,2)", "DM(3)", "AX(1,2)", "AY(1,2)",
    "AZ(1,2)", "AZ(4)", "PSI(1,2)", "THETA(1,2)", "PHI(1,2)", "YAW(1,2)", "PITCH(1,2)",
    "ROLL(1,2)", "PSI(3)", "DM(1,2)*DX(1,2,2) + SIN(AZ(1,2))", "DX(1,2,1)",
    "-1000*(DM(1,2)-50)+STEP(TIME,0,0,1,100)", "INCANG(1,2,3)", "INCANG(3,1,2)",
])
def test_measure_derivatives(text):
    fd_markers(text)


def test_included_angle_at_the_middle_marker():
    """INCANG(I, J, K): the angle at J between the lines to I and to K, in [0, pi]."""
    P = np.zeros((6, 3))
    A = np.tile(np.eye(3), (6, 1, 1))
    P[0], P[1] = [3.0, 1.0, 0.0], [1.0, 1.0, 0.0]
    b = compile_batch([mkexpr("INCANG(1,2,3)")], FakeResolver())
    for k, want in (([1.0, 3.0, 0.0], math.pi / 2), ([-1.0, 1.0, 0.0], math.pi),
                    ([1.0 + math.sqrt(3.0), 2.0, 0.0], math.pi / 6),
                    ([0.0, 1.0, -1.0], 3 * math.pi / 4)):
        P[2] = k
        ctx = EvalContext(P=P, A=A, extra=np.zeros(50), reactions=np.zeros(10))
        assert b.evaluate(ctx).value[0] == pytest.approx(want, abs=1e-14)


def test_euler_angles_reconstruct_relative_rotation():
    rng = np.random.default_rng(11)
    for _ in range(5):
        ctx = make_ctx(rng)
        r = FakeResolver()
        b = compile_batch([mkexpr(t) for t in ("PSI(1,2)", "THETA(1,2)", "PHI(1,2)",
                                               "YAW(1,2)", "PITCH(1,2)", "ROLL(1,2)")], r)
        psi, th, phi, yaw, pitch, roll = b.evaluate(ctx).value
        R = ctx.A[1].T @ ctx.A[0]
        np.testing.assert_allclose(Rz(psi) @ Rx(th) @ Rz(phi), R, atol=1e-12)
        np.testing.assert_allclose(Rz(yaw) @ Ry(-pitch) @ Rx(roll), R, atol=1e-12)
        assert 0 <= th <= math.pi and -math.pi / 2 <= pitch <= math.pi / 2


def test_yaw_pitch_roll_sense():
    # I rotated by +0.3 about its own -y axis relative to global: PITCH = +0.3
    P = np.zeros((6, 3))
    A = np.tile(np.eye(3), (6, 1, 1))
    A[0] = Ry(-0.3)
    ctx = EvalContext(P=P, A=A, extra=np.zeros(50), reactions=np.zeros(10))
    b = compile_batch([mkexpr("PITCH(1)"), mkexpr("YAW(1)"), mkexpr("ROLL(1)")], FakeResolver())
    np.testing.assert_allclose(b.evaluate(ctx).value, [0.3, 0.0, 0.0], atol=1e-14)


@pytest.mark.parametrize("name,axis", [("AZ", 2), ("AX", 0), ("AY", 1)])
def test_angle_continuity_through_turns(name, axis):
    rng = np.random.default_rng(5)
    P, A = random_frames(rng)
    r = FakeResolver()
    b = compile_batch([mkexpr(f"{name}(1,2)")], r)
    assert list(r.angles) == [(0, 1, axis)]
    rot = (Rx, Ry, Rz)[axis]
    ref = np.zeros(1)
    for th in np.linspace(0.0, 4.5 * 2 * math.pi, 200):
        A2 = A.copy()
        A2[0] = A[1] @ rot(th)          # I = J rotated by th about J's axis
        ctx = EvalContext(P=P, A=A2, extra=np.zeros(50), reactions=np.zeros(10),
                          angle=ref)
        v = b.evaluate(ctx).value[0]
        assert v == pytest.approx(th, abs=1e-9)
        ref = np.array([v])
    # and backwards through zero into negative turns
    for th in np.linspace(-0.1, -3 * 2 * math.pi, 150):
        A2 = A.copy()
        A2[0] = A[1] @ rot(th)
        ctx = EvalContext(P=P, A=A2, extra=np.zeros(50), reactions=np.zeros(10),
                          angle=np.array([ref[0] if th < -0.2 else 0.0]))
        v = b.evaluate(ctx).value[0]
        assert v == pytest.approx(th, abs=1e-9)
        ref = np.array([v])


def test_velocity_measures_are_zero_and_validated():
    b = compile_batch([mkexpr(t) for t in ("VX(1,2,3,4)", "VM(1)", "WZ(1,2)", "ACCM(1,2)",
                                           "WDTX(1,2,3,4)", "VR(1,2)")], FakeResolver())
    res = b.evaluate(make_ctx())
    assert np.all(res.value == 0) and not b.depends_on_state


def test_reaction_functions():
    r = FakeResolver()
    exprs = [mkexpr("FX(1,2,3)"), mkexpr("2*JOINT(5, 1, 3, 0)"), mkexpr("FM(1)+TZ(1)"),
             mkexpr("SPDP(3,0,2)")]
    b = compile_batch(exprs, r)
    assert r.calls == [("FX", 1, 2, 2, 3), ("JOINT", 5, 1, 3, 0), ("FM", 1, 0, 1, 0),
                       ("TZ", 1, 0, 8, 0), ("SPDP", 3, 0, 2, 0)]
    ctx = make_ctx()
    res = b.evaluate(ctx)
    ch = r.channels
    np.testing.assert_allclose(res.value, [
        ctx.reactions[ch[("FX", 1, 2, 2, 3)]], 2 * ctx.reactions[ch[("JOINT", 5, 1, 3, 0)]],
        ctx.reactions[ch[("FM", 1, 0, 1, 0)]] + ctx.reactions[ch[("TZ", 1, 0, 8, 0)]],
        ctx.reactions[ch[("SPDP", 3, 0, 2, 0)]]])
    assert res.reaction_index[1, 0] == ch[("JOINT", 5, 1, 3, 0)]
    assert res.d_reaction[1, 0] == 2.0
    assert sorted(res.d_reaction[2]) == [1.0, 1.0]
    assert b.depends_on_state
