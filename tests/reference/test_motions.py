"""Motion constraint families: exact Jacobian and lambda-weighted Hessian against central FD;
targets of D/V/A motions; log map inverse of retract."""
import numpy as np
import pytest

from poise.deck.spec import Expr
from poise.core.errors import DeckError, SourceLoc
from poise.model.compile import compile_model

from support.builders import stable_seed
from support.fd import fd_check, perturbed_state, two_body_deck


def _expr(text, tag="Motion_Marker", id=1):
    return Expr(text=text, loc=SourceLoc("<built>", 1, tag, id), attr="expr")


@pytest.mark.parametrize("direction", ["X", "Y", "Z", "B1", "B2", "B3"])
def test_motion_marker_jacobian(direction):
    rng = np.random.default_rng(stable_seed(direction))
    d = two_body_deck(rng)
    d.add("Motion_Marker", id=1, i_marker_id=21, j_marker_id=31, direction=direction,
          val_type="D", expr=_expr("0.3*TIME+0.1"))
    d.add("Motion_Marker", id=2, i_marker_id=22, j_marker_id=11, direction=direction,
          val_type="D", expr=_expr("-0.2+SIN(TIME)", id=2))
    m = compile_model(d.spec)
    st = perturbed_state(m, rng)
    st.t = 0.7
    fd_check(m, st)


@pytest.mark.parametrize("jtype,fr", [("REVOLUTE", "R"), ("TRANSLATIONAL", "T"),
                                      ("CYLINDRICAL", "R"), ("CYLINDRICAL", "T")])
def test_motion_joint_jacobian(jtype, fr):
    rng = np.random.default_rng(stable_seed(jtype, fr))
    d = two_body_deck(rng)
    d.add("Constraint_Joint", id=1, type=jtype, i_marker_id=21, j_marker_id=31)
    d.add("Constraint_Joint", id=2, type=jtype, i_marker_id=22, j_marker_id=11)
    d.add("Motion_Joint", id=1, joint_id=1, joint_type=fr, val_type="D",
          expr=_expr("0.5*TIME", "Motion_Joint"))
    d.add("Motion_Joint", id=2, joint_id=2, joint_type=fr, val_type="V", ic_disp=0.2,
          expr=_expr("COS(TIME)", "Motion_Joint", 2))
    m = compile_model(d.spec)
    st = perturbed_state(m, rng)
    st.t = 0.4
    fd_check(m, st)


def test_motion_targets_v_a():
    rng = np.random.default_rng(3)
    d = two_body_deck(rng)
    d.add("Motion_Marker", id=1, i_marker_id=21, j_marker_id=31, direction="X", val_type="V",
          ic_disp=0.5, expr=_expr("COS(TIME)"))
    d.add("Motion_Marker", id=2, i_marker_id=22, j_marker_id=11, direction="Z", val_type="A",
          ic_disp=0.1, ic_vel=0.2, expr=_expr("6*TIME", id=2))
    d.add("Motion_Marker", id=3, i_marker_id=22, j_marker_id=31, direction="Y", val_type="D",
          expr=2.5)
    m = compile_model(d.spec)
    tg = m.families[-1].targets
    for t in (0.0, 0.013, 0.37, 1.234):
        v, dv = tg.values(t)
        np.testing.assert_allclose(v, [0.5 + np.sin(t), 0.1 + 0.2 * t + t ** 3, 2.5], atol=1e-12)
        np.testing.assert_allclose(dv, [np.cos(t), 0.2 + 3 * t ** 2, 0.0], atol=1e-12)
    assert m.depends_on_time()


def test_state_dependent_motion_rejected():
    rng = np.random.default_rng(4)
    d = two_body_deck(rng)
    d.add("Motion_Marker", id=1, i_marker_id=21, j_marker_id=31, direction="X",
          expr=_expr("DX(21,31,31)+TIME"))
    with pytest.raises(DeckError, match="state-dependent motion not supported yet"):
        compile_model(d.spec)


def test_local_difference_inverts_retract():
    rng = np.random.default_rng(5)
    d = two_body_deck(rng, point_b=True)
    d.add("Constraint_Joint", id=1, type="SPHERICAL", i_marker_id=21, j_marker_id=31)
    m = compile_model(d.spec)
    a = perturbed_state(m, rng)
    dq = rng.normal(scale=0.8, size=m.nq)
    b = m.retract(a, dq)
    np.testing.assert_allclose(m.local_difference(a, b), dq, atol=1e-10)
