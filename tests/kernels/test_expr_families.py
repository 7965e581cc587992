"""Expression force families: analytic Jacobians against central finite differences, TIME
dependence, gravity expressions, and located compile errors (tests/kernels/test_jacobians.py style)."""
import numpy as np
import pytest

from poise.deck.spec import Expr
from poise.core.errors import DeckError, SourceLoc
from poise.elements.registry import type_of
from poise.model.compile import compile_model

from support.builders import DeckBuilder
from support.fd import fd_check, perturbed_state, two_body_deck


def X(text, attr="val_expression", tag="Force_Scalar_TwoBody", id=1, line=7):
    return Expr(text, SourceLoc("deck.xml", line, tag, id), attr)


def _vec(**kw):
    return {f"{k}_expression": (X(v, f"{k}_expression", "Force_Vector_OneBody") if isinstance(v, str)
                                else v) for k, v in kw.items()}


SCALAR_CASES = {
    "cubic_dm": dict(type="FORCE", val_expression="-30*(DM(21,31)-0.7)-5*(DM(21,31)-0.7)**3"),
    "extra_markers": dict(type="FORCE",
                          val_expression="DX(22,32,11)*AZ(22,32) + STEP(DY(32,21,22),-1,0,1,2)"),
    "action_only": dict(type="FORCE", is_action_only=True,
                        val_expression="2*DZ(21,31,32)+TIME+SQRT(1+DM(22)**2)"),
    "torque_az": dict(type="TORQUE", val_expression="-3*AZ(21,31)+DY(32)+PSI(22,31)"),
    "torque_action_only": dict(type="TORQUE", is_action_only=True,
                               val_expression="-3*AX(21)+DM(21,32)"),
}


@pytest.mark.parametrize("name", sorted(SCALAR_CASES))
@pytest.mark.parametrize("point_b", [False, True])
def test_scalar_expression_jacobian(name, point_b):
    rng = np.random.default_rng(abs(hash((name, point_b))) % 2**32)
    d = two_body_deck(rng, point_b)
    attrs = dict(SCALAR_CASES[name])
    attrs["val_expression"] = X(attrs["val_expression"])
    d.add("Force_Scalar_TwoBody", id=1, i_marker_id=21, j_marker_id=31, **attrs)
    d.add("Force_Scalar_TwoBody", id=2, i_marker_id=32, j_marker_id=11, **attrs)   # J on ground
    m = compile_model(d.spec)
    assert [f.name for f in m.families] == ["forces:ExprScalarForce"]
    st = perturbed_state(m, rng)
    st.t = 0.3
    fd_check(m, st)


@pytest.mark.parametrize("point_b", [False, True])
def test_vector_expression_jacobian(point_b):
    rng = np.random.default_rng(11 + point_b)
    d = two_body_deck(rng, point_b)
    comps = dict(fx="DX(21)*3+DZ(32,22,31)", fy=1.0, fz="AZ(21,31)", tx="DM(32,22)", ty=0.0,
                 tz="SIN(AX(31))*TIME")
    d.add("Force_Vector_OneBody", id=1, type="FORCEANDTORQUE", marker_id=21, ref_marker_id=32,
          **_vec(**comps))
    d.add("Force_Vector_TwoBody", id=2, type="FORCEANDTORQUE", i_marker_id=21,
          j_floating_marker_id=31, ref_marker_id=22, **_vec(**comps))
    d.add("Force_Vector_TwoBody", id=3, type="FORCEONLY", i_marker_id=32,
          j_floating_marker_id=11, **_vec(fx="DY(32,21)**2", fy=-2.0, fz="YAW(31,21)"))
    d.add("Force_Vector_OneBody", id=4, type="TORQUEONLY", marker_id=31,
          **_vec(tx="DM(31,21)", ty="ROLL(21)", tz=0.5))
    m = compile_model(d.spec)
    assert [f.name for f in m.families] == ["forces:ExprVectorForce"]
    assert type_of(m.families[0]).time_dependent(m.families[0])   # the registry's predicate
    st = perturbed_state(m, rng)
    st.t = 0.7
    fd_check(m, st)


def test_expression_forces_with_joint_and_splines():
    """Mixed with a constraint family, a spline and an explicit variable."""
    rng = np.random.default_rng(3)
    d = two_body_deck(rng)
    d.add("Constraint_Joint", id=1, type="SPHERICAL", i_marker_id=22, j_marker_id=11)
    from poise.deck.spec import Element
    sp = Element("Reference_Spline", dict(id=5, num_xy_pair=5, linear_extrap=True),
                 SourceLoc("deck.xml", 3, "Reference_Spline", 5), text="0 0 1 2 2 3 3 3.5 4 5")
    d.spec.model.append(sp)
    d.add("Reference_Variable", id=7, type="EXPRESSION", expr=X("CUBSPL(DM(21,31),0,5)", "expr",
                                                                "Reference_Variable", 7))
    d.add("Force_Scalar_TwoBody", id=1, type="FORCE", i_marker_id=21, j_marker_id=31,
          val_expression=X("-10*VARVAL(7) + AKISPL(DX(21,31),0,5,1)"))
    m = compile_model(d.spec)
    fd_check(m, perturbed_state(m, rng))


def test_time_drives_evaluation():
    d = DeckBuilder().ground()
    d.body(2, 200, (0.0, -1.0, 0.0), point=True, mass=2.0)
    d.add("Force_Scalar_TwoBody", id=1, type="FORCE", is_action_only=True, i_marker_id=200,
          j_marker_id=1000, val_expression=X("5*TIME"))
    d.add("Force_Gravity", grav_x=0.0, grav_y=X("-10 + 4*TIME", "grav_y", "Force_Gravity", None),
          grav_z=0.0)
    m = compile_model(d.spec)
    assert m.depends_on_time()
    st = m.initial_state()
    for t in (0.0, 1.5):
        st.t = t
        r = m.evaluate(st, need_jac=False).r
        # residual = -Q: -(5t z_J) - m g(t)
        np.testing.assert_allclose(r, [0.0, -(2.0 * (-10 + 4 * t)), -5 * t], atol=1e-12)


def _deck_error(d):
    with pytest.raises(DeckError) as ei:
        compile_model(d.spec)
    return str(ei.value)


def test_state_dependent_gravity_rejected():
    d = DeckBuilder().ground()
    d.body(2, 200, (0.0, -1.0, 0.0), point=True)
    d.add("Force_Gravity", grav_x=0.0, grav_y=X("-10*DY(200)", "grav_y", "Force_Gravity", None),
          grav_z=0.0)
    msg = _deck_error(d)
    assert "<Force_Gravity> grav_y:" in msg and "Force_Vector_TwoBody" in msg


def test_reaction_in_force_accepted_in_gravity_rejected_with_column():
    # forces may read reactions (ReactionFeed, tests/kernels/test_expr_reactions_euler.py);
    # gravity still may not
    d = DeckBuilder().ground()
    d.body(2, 200, (0.0, -1.0, 0.0), point=True)
    d.add("Constraint_Jprim", id=1, type="INPLANE", i_marker_id=200, j_marker_id=1000)
    d.add("Force_Scalar_TwoBody", id=1, type="FORCE", i_marker_id=200, j_marker_id=1000,
          val_expression=X("1+JPRIM(1,0,2,0)"))
    m = compile_model(d.spec)
    assert m.reaction_feed is not None and m.families[m.eval_order[-1]].reads_reactions
    d.add("Force_Gravity", grav_x=0.0, grav_y=X("-10+JPRIM(1,0,2,0)", "grav_y", "Force_Gravity",
                                                None), grav_z=0.0)
    msg = _deck_error(d)
    assert "grav_y col 5" in msg and "not supported in gravity" in msg, msg


def test_implicit_variable_is_a_scalar_unknown():
    # implicit variables are scalar unknowns (tests/kernels/test_diffs_variables_user_routines.py)
    d = DeckBuilder().ground()
    d.body(2, 200, (0.0, -1.0, 0.0), point=True)
    d.add("Reference_Variable", id=3, type="EXPRESSION", is_implicit=True,
          expr=X("VARVAL(3)-1", "expr", "Reference_Variable", 3))
    d.add("Force_Scalar_TwoBody", id=1, type="FORCE", i_marker_id=200, j_marker_id=1000,
          val_expression=X("VARVAL(3)"))
    m = compile_model(d.spec)
    assert m.n_extra == 1 and m.families[0].scols.tolist() == [[0]]
