"""Exact second derivatives of expressions (``Batch.hessian``, poise.expr.hessian) against
central differences of the exact first derivatives, for every function with second partials,
every position measure, splines, powers and scalar unknowns; and the refusals (reactions,
IMPACT)."""
from __future__ import annotations

import numpy as np
import pytest

from poise.expr import EvalContext, compile_batch
from poise.expr.hessian import NoHessian

from support.expr import FakeResolver, mkexpr, random_frames

EXPRS = [
    "DM(1,2)", "DM(1)", "DX(1,2,3)", "DY(2,4)", "DZ(1,2,3)**2", "AZ(1,2)", "AX(3,4)", "AY(5,6)",
    "PSI(1,2)", "THETA(1,2)", "PHI(1,2)", "YAW(1,2)", "PITCH(3,4)", "ROLL(5,6)", "AZ(2)",
    "SIN(DX(1,2))*COS(DY(1,2))", "EXP(0.1*DM(1,2))", "LOG(DM(1,2))", "LOG10(DM(1,2)+1)",
    "SQRT(DM(1,2))", "TAN(0.2*DX(1,2))", "TANH(DX(1,2))", "ATAN(DY(1,2))",
    "ASIN(0.3*DZ(1,2)/DM(1,2))", "ACOS(0.3*DX(1,2)/DM(1,2))", "SINH(DX(1,2))",
    "COSH(DY(1,2))", "ATAN2(DY(1,2), DX(1,2))", "ABS(DX(1,2))*DY(1,3)",
    "MAX(DX(1,2), DY(1,2))**2", "MIN(DX(1,2), DY(1,2), DZ(1,2))*DM(3,4)",
    "STEP(DX(1,2), -2, 0, 2, 2)", "STEP5(DX(1,2), -2, 0, 2, 2)", "HAVSIN(DY(1,2), -4, 1, 4, 3)",
    "STEP(0.5, 0, DX(1,2), 1, DY(1,2)**2)", "STEP(DX(1,2), DX(3,4)-9, DY(1,2), DY(3,4)+9, 1)",
    "SHF(DX(1,2), 0.1, DY(1,2), 2, 0.3, DZ(1,2))", "SHF(DX(1,2), DZ(1,2), 1, DY(3,4), 0.3, 0)",
    "POLY(DX(1,2), 0.5, 1, DY(1,2), 3, 0.5)", "CHEBY(DX(1,2), 0, 1, 2, DY(1,2), 4, 0.5)",
    "FORCOS(DX(1,2), 0.1, DY(1,2), 1, 0.5, DZ(1,2), 0.2)", "FORSIN(DX(1,2), 0.1, 1.3, 1, DM(1,3))",
    "DX(1,2)/DY(1,2)", "DM(1,2)**DX(3,4)", "DM(1,2)**2.5", "2**DX(1,2)",
    "VARVAL(1)*DX(1,2) + VARVAL(2)**2", "VARVAL(3)/DM(1,2)",
    "AKISPL(DX(1,2)+3, 0, 1)", "CUBSPL(DX(1,2)+3, DY(1,2)+1, 2)", "CUBSPL(DX(1,2)+3, 0, 1, 1)",
    "AKISPL(DX(1,2)+3, 0, 3, 2)", "LINSPL(DM(1,2)-2, DZ(1,2)-2, 2)",
    "IF(DX(1,2): DY(1,2)**2, 0, DZ(1,2)**3)", "MOD(3*DX(1,2), 1.7)*DY(1,2)",
    "SIGN(DX(1,2), DY(1,2))*DZ(1,2)", "DIM(DX(1,2), DY(1,2))*DM(1,2)", "-DX(1,2)*DY(1,2)",
    "INCANG(1,2,3)", "INCANG(4,1,2)*DM(1,3)",
]


def _grad(b, P, A, sc):
    """Dense d value / d (slot components, scalars) of instance 0, the Hessian's layout."""
    r = b.evaluate(EvalContext(t=0.3, P=P, A=A, extra=sc, reactions=np.zeros(10)))
    g = np.zeros(3 * b.S + b.U)
    g[:3 * b.S] = r.d_slot[0].ravel()
    g[3 * b.S:] = r.d_scalar[0]
    return g


@pytest.mark.parametrize("text", EXPRS)
def test_hessian_against_differences_of_the_gradient(text):
    rng = np.random.default_rng(11)
    P, A = random_frames(rng)
    P = 2.0 * P
    sc = np.zeros(50)
    sc[:3] = [0.7, -1.3, 2.1]
    b = compile_batch([mkexpr(text)], FakeResolver())
    H = b.hessian(EvalContext(t=0.3, P=P, A=A, extra=sc))[0]
    D = 3 * b.S + b.U
    fd = np.zeros((D, D))
    h = 1e-6
    for k in range(D):
        args = []
        for sign in (1.0, -1.0):
            Pk, Ak, sk = P.copy(), A.copy(), sc.copy()
            if k < 3 * b.S:
                s, c = divmod(k, 3)
                m, kind = b.slot_marker[0, s], b.slot_kind[0, s]
                if m < 0:                     # the global frame: no coordinates
                    args.append(None)
                    continue
                if kind == 0:
                    Pk[m, c] += sign * h
                else:
                    Ak[m, c, kind - 1] += sign * h
            else:
                sk[b.scalar_index[0, k - 3 * b.S]] += sign * h
            args.append(_grad(b, Pk, Ak, sk))
        if args[0] is not None:
            fd[:, k] = (args[0] - args[1]) / (2 * h)
    scale = max(1.0, np.abs(fd).max())
    np.testing.assert_allclose(H, fd, rtol=0, atol=2e-6 * scale, err_msg=text)
    np.testing.assert_allclose(H, H.T, rtol=0, atol=1e-12 * scale)


def test_hessian_of_many_instances_in_groups():
    """Several instances of different shapes: each row's Hessian in the batch layout."""
    texts = ["DM(1,2) - 3", "DM(3,4) - 1", "AZ(1,2)*VARVAL(1)", "DX(5,6,1)**2"]
    rng = np.random.default_rng(3)
    P, A = random_frames(rng)
    sc = np.linspace(0.5, 1.5, 50)
    b = compile_batch([mkexpr(t) for t in texts], FakeResolver())
    H = b.hessian(EvalContext(P=P, A=A, extra=sc))
    for i, t in enumerate(texts):
        bi = compile_batch([mkexpr(t)], FakeResolver())
        Hi = bi.hessian(EvalContext(P=P, A=A, extra=sc))[0]
        Di = 3 * bi.S
        np.testing.assert_allclose(H[i, :Di, :Di], Hi[:Di, :Di], atol=1e-13)
        if bi.U:
            np.testing.assert_allclose(H[i, 3 * b.S:3 * b.S + bi.U, :Di], Hi[Di:, :Di],
                                       atol=1e-13)


@pytest.mark.parametrize("text,what", [("JOINT(1,0,2,0)*DX(1,2)", "reaction"),
                                       ("IMPACT(DX(1,2), 0, 1, 10, 2, 0, 0.1)", "IMPACT")])
def test_no_hessian_for_reactions_and_force_laws(text, what):
    rng = np.random.default_rng(3)
    P, A = random_frames(rng)
    b = compile_batch([mkexpr(text)], FakeResolver())
    with pytest.raises(NoHessian, match=what):
        b.hessian(EvalContext(P=P, A=A, extra=np.zeros(50), reactions=np.zeros(10)))
