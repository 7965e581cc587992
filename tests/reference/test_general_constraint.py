"""``Constraint_General`` (Adams GCON): the complete Newton Jacobian against central differences
(the element type's FD check), closed forms, quasi-static driving by TIME, commands, reactions
and the located refusals.

Closed forms: ``decks/elem_gcon_parabola.xml`` (a point on y = x^2/2 pushed by F: x = F/(m g),
reaction (-F, m g, 0)); a point pendulum ``DM(I, J) - L`` under a side force (angle atan2(F, m g),
rod force along the rod); the parabola driven by ``DX - 0.1 TIME`` (x = 0.1 t, the driver's
reaction m g x along +X, the curve's (-m g x, m g, 0)).
"""
from __future__ import annotations

import re

import numpy as np
import pytest

from poise.app.api import run_deck
from poise.core.errors import DeckError
from poise.model.compile import compile_model

from support.builders import stable_seed
from support.fd import fd_check, perturbed_state, two_body_deck
from support.paths import DECKS

G = 9.81


def _x(text):
    from poise.core.errors import SourceLoc
    from poise.deck.spec import Expr
    return Expr(text, SourceLoc("<built>", 1, "Constraint_General", 1), "expr")


@pytest.mark.parametrize("point_b", [False, True])
def test_general_constraint_jacobian(point_b):
    """Rows of several shapes (distances, continuous angles, Euler angles, functions, powers, a
    scalar unknown), between two bodies and to ground, on a random state with random
    multipliers: the complete Jacobian including lam d2e/dy2."""
    rng = np.random.default_rng(stable_seed("gcon", point_b))
    d = two_body_deck(rng, point_b)
    exprs = ["DM(21,31) - 1.5", "AZ(22,11)*DX(31,11,22) - 0.3",
             "SIN(DX(21,32,11))*EXP(0.2*DY(32,22)) + DM(22)**1.5",
             "PSI(21,11) + 0.5*THETA(22,11) - ATAN2(DY(31,11), DX(31,11))",
             "STEP(DX(31,21), -5, 0, 5, 2)*DZ(32,11,21) + VARVAL(5)**2 - 1",
             "SQRT(1 + DM(21,32)**2) - 2"]
    for k, t in enumerate(exprs):
        d.add("Constraint_General", id=k + 1, expr=_x(t), i_marker_id=21 if k % 2 else 31)
    d.add("Reference_Variable", id=5, type="EXPRESSION", is_implicit=True,
          expr=_x("VARVAL(5) - DX(21,11) - 0.1*DM(31,22)"))
    m = compile_model(d.spec)
    assert m.nc >= len(exprs)
    st = perturbed_state(m, rng)
    st.extra = st.extra + 0.3
    fd_check(m, st)


def test_parabola_deck_closed_form():
    a = run_deck(str(DECKS / "elem_gcon_parabola.xml")).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    x = 2.0 / G
    np.testing.assert_allclose(d["bodies/position"][-1, 0], [x, 0.5 * x * x, 0.0], atol=1e-11)
    assert list(d["gcons/id"]) == [1, 2]
    np.testing.assert_allclose(d["gcons/force"][-1, 0], [-2.0, G, 0.0], atol=1e-9)
    np.testing.assert_allclose(d["gcons/force"][-1, 1], 0.0, atol=1e-9)
    np.testing.assert_allclose(d["gcons/torque"][-1], 0.0, atol=1e-9)


PENDULUM = """<MotionSolve><Model>
<Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
<Force_Gravity grav_x="0" grav_y="-9.81" grav_z="0"/>
<Body_Rigid id="1" isground="TRUE" cg_id="10"/>
<Reference_Marker id="10" body_id="1"/>
<Body_Rigid id="2" cg_id="20" mass="2.0" inertia_xx="0.1" inertia_yy="0.1" inertia_zz="0.1"/>
<Reference_Marker id="20" body_id="2" pos_x="0.6" pos_y="-0.8" pos_z="0"/>
<Reference_Marker id="21" body_id="2" pos_x="0.6" pos_y="-0.8" pos_z="0"/>
<Constraint_Jprim id="1" type="ORIENTATION" i_marker_id="20" j_marker_id="10"/>
<Constraint_General id="7" expr="DM(21,10) - {L}" {imark}/>
<Constraint_General id="8" expr="DZ(21,10,10)"/>
<Force_Vector_OneBody id="1" type="FORCEONLY" marker_id="20" fx_expression="5"
    fy_expression="0" fz_expression="0"/>
</Model><Command><Simulate analysis_type="Static"/>{more}</Command></MotionSolve>
"""


def _pendulum(tmp_path, L=1.0, imark='i_marker_id="21"', more=""):
    p = tmp_path / "pend.xml"
    p.write_text(PENDULUM.format(L=L, imark=imark, more=more))
    return run_deck(str(p))


def test_distance_constraint_pendulum(tmp_path):
    """A body held at distance L from the pivot by DM(I, J) - L, side force F = 5 N: the rod
    leans at atan2(F, m g); its reaction on the body (at I, on the body's CG) is -(F, -m g)."""
    a = _pendulum(tmp_path).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    t = np.arctan2(5.0, 2 * G)
    np.testing.assert_allclose(d["bodies/position"][-1, 0], [np.sin(t), -np.cos(t), 0], atol=1e-10)
    np.testing.assert_allclose(d["gcons/force"][-1, 0], [-5.0, 2 * G, 0.0], atol=1e-8)
    # no reaction marker: MotionSolve gives no reaction, poise writes NaN
    assert np.isnan(d["gcons/force"][-1, 1]).all()


def test_command_changes_the_expression(tmp_path):
    """A command ``<Constraint_General id=7 expr=...>`` between analyses: the rod length
    changes for the second one."""
    run = _pendulum(tmp_path, more='<Constraint_General id="7" expr="DM(21,10) - 1.5"/>'
                                   '<Simulate analysis_type="Static"/>')
    t = np.arctan2(5.0, 2 * G)
    for a, L in zip(run.analyses, (1.0, 1.5)):
        assert a.converged, a.message
        np.testing.assert_allclose(a.datasets["bodies/position"][-1, 0],
                                   [L * np.sin(t), -L * np.cos(t), 0], atol=1e-9)


@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_time_driven_general_constraint(tmp_path, method):
    """The parabola point driven along x by DX - 0.1 TIME over t in [0, 1]: quasi-static, x =
    0.1 t; the driver's reaction is m g x along +X, the curve's (-m g x, m g, 0)."""
    text = (DECKS / "elem_gcon_parabola.xml").read_text()
    text = re.sub(r'<Force_Vector_OneBody.*?/>', '<Constraint_General id="3" i_marker_id="200" '
                  'expr="DX(200,101,101) - 0.1*TIME"/>', text, flags=re.S)
    text = text.replace('method="FIM_S"', f'method="{method}"')
    text = text.replace('<Simulate analysis_type="Static"/>',
                        '<Simulate analysis_type="Static" end_time="1.0" num_steps="10"/>')
    p = tmp_path / "drive.xml"
    p.write_text(text)
    a = run_deck(str(p)).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    t = np.asarray(d["time"] if "time" in d else d["frames/time"])
    x = 0.1 * t
    np.testing.assert_allclose(d["bodies/position"][:, 0, 0], x, atol=1e-8)
    np.testing.assert_allclose(d["bodies/position"][:, 0, 1], 0.5 * x * x, atol=1e-8)
    np.testing.assert_allclose(d["gcons/force"][:, 2, 0], G * x, atol=1e-6)
    np.testing.assert_allclose(d["gcons/force"][:, 0, 0], -G * x, atol=1e-6)
    np.testing.assert_allclose(d["gcons/force"][:, 0, 1], G, atol=1e-6)


@pytest.mark.parametrize("attrs,msg", [
    ('type="USERSUB" usrsub_param_string="USER(1)" usrsub_fnc_name="GCOSUB"',
     "user-subroutine general constraints (GCOSUB) are not supported"),
    ('expr="JOINT(1,0,2,0) - DX(21,10)"', "JOINT() is not supported in Constraint_General"),
    ('expr="IMPACT(DX(21,10), 0, 1, 10, 2, 0, 0.1)"', "IMPACT in a Constraint_General"),
    ('expr="FOO(21) - 1"', "unknown function 'FOO'"),
    ('', "Constraint_General needs expr"),
])
def test_refusals_are_located(tmp_path, attrs, msg):
    p = tmp_path / "bad.xml"
    text = PENDULUM.format(L=1.0, imark="", more="").replace(
        '<Constraint_General id="7" expr="DM(21,10) - 1.0" />', f'<Constraint_General id="7" {attrs}/>')
    p.write_text(text)
    with pytest.raises(DeckError) as e:
        run_deck(str(p))
    assert "bad.xml:10: <Constraint_General id=7>" in str(e.value)
    assert msg in str(e.value)


def test_configuration_free_expression_is_left_out_with_a_warning(tmp_path):
    """A velocity-only constraint (VX is 0 at rest) constrains nothing in statics."""
    p = tmp_path / "v.xml"
    text = PENDULUM.format(L=1.0, imark="", more="").replace(
        '</Model>', '<Constraint_General id="9" expr="VX(21,10)"/></Model>')
    p.write_text(text)
    run = run_deck(str(p))
    a = run.analyses[0]
    assert a.converged, a.message
    assert list(a.datasets["gcons/id"]) == [7, 8]
    assert any("<Constraint_General id=9>" in str(w) and "constrains nothing in statics" in str(w)
               for w in run.warnings)


POINT = """<MotionSolve><Model>
<Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
<Force_Gravity grav_x="0" grav_y="-9.81" grav_z="0"/>
<Body_Rigid id="1" isground="TRUE" cg_id="10"/>
<Reference_Marker id="10" body_id="1"/>
<Body_Point id="2" cg_id="20" mass="2.0"/>
<Reference_Marker id="20" body_id="2" pos_x="0.1" pos_y="{y}" pos_z="0"/>
<Constraint_General id="1" expr="DM(20,10) - 1.0" i_marker_id="20"/>
<Constraint_General id="2" expr="DZ(20,10,10)"/>
</Model><Command><Simulate analysis_type="Static"/></Command></MotionSolve>
"""


@pytest.mark.parametrize("y,cls", [(-0.99, "stable"), (0.99, "unstable")])
def test_distance_constraint_stability_and_quadratic_newton(tmp_path, y, cls):
    """A point mass held only by DM(I, J) - L: its tangential stiffness is the constraint's
    geometric stiffness lam d2DM/dy2 alone (m g / L, + below the pivot, - above), so the
    stability class tests the exact Hessian; Newton converges quadratically."""
    p = tmp_path / "pt.xml"
    p.write_text(POINT.format(y=y))
    a = run_deck(str(p)).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    np.testing.assert_allclose(d["bodies/position"][-1, 0], [0.0, np.sign(y), 0.0], atol=1e-12)
    assert list(d["frames/stability"]) == [cls]
    r = np.asarray(d["iterations/imbalance"], float)
    k = int(np.argmax(r < 1.0))                  # inside the quadratic basin
    assert r[k + 1] < 10.0 * r[k] ** 2
