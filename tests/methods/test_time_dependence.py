"""Anything that reads TIME makes a quasi-static run time-dependent (no "solved once, frame
replicated" short cut): gravity, variables, splines, motions, differential states, implicit
variables, user routines. Each source drives a vertical spring-mass (m = 2, k = 200, free length
1, hanging from the origin on a vertical slider) whose equilibrium has a closed form:
y(t) = -1 + F_y(t) / k."""
from __future__ import annotations

import inspect

import numpy as np
import pytest

from poise.app.runner import run

from support.paths import DECKS


M, K = 2.0, 200.0

DECK = '''<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Static method="{method}" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="10"/>
    <Reference_Marker id="10" body_id="1" pos_x="0" pos_y="0" pos_z="0"/>
    <Reference_Marker id="11" body_id="1" pos_x="0" pos_y="-1" pos_z="0" a00="0" a10="0" a20="1" a01="1" a11="0" a21="0" a02="0" a12="1" a22="0"/>
    <Body_Rigid id="2" cg_id="20" mass="2.0" inertia_xx="1." inertia_yy="1." inertia_zz="1." inertia_xy="0." inertia_yz="0." inertia_xz="0."/>
    <Reference_Marker id="20" body_id="2" pos_x="0" pos_y="-1" pos_z="0"/>
    <Reference_Marker id="21" body_id="2" pos_x="0" pos_y="-1" pos_z="0" a00="0" a10="0" a20="1" a01="1" a11="0" a21="0" a02="0" a12="1" a22="0"/>
    <Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="21" j_marker_id="11"/>
    <Force_SpringDamper id="1" type="TRANSLATIONAL" i_marker_id="20" j_marker_id="10" stiffness="200." damping="0." length="1.0" preload="0."/>
{extra}
  </Model>
  <Command>
    <Simulate analysis_type="Static" end_time="1.0" print_interval="0.125"/>
    <Stop/>
  </Command>
</MotionSolve>
'''

FY = '<Force_Vector_OneBody id="2" type="FORCEONLY" marker_id="20" fx_expression="0" ' \
     'fy_expression="{e}" fz_expression="0"/>'

USER_SCRIPT = '''
def gfosub_ramp(id, time, par, q):
    return [0.0, par[0] * time, 0.0]
'''


def _step(t):
    s = np.clip(t, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


# source -> (deck elements, closed-form y(t))
SOURCES = {
    "gravity_step": ('<Force_Gravity grav_x="0" grav_y="-9.81*STEP(TIME,0,0,1,1)" grav_z="0"/>',
                     lambda t: -1 + M * -9.81 * _step(t) / K),
    "gravity_via_variable": ('<Reference_Variable id="5" type="EXPRESSION" expr="-9.81*TIME"/>\n'
                             '<Force_Gravity grav_x="0" grav_y="VARVAL(5)" grav_z="0"/>',
                             lambda t: -1 + M * -9.81 * t / K),
    "variable_chain": ('<Reference_Variable id="5" type="EXPRESSION" expr="-10*TIME"/>\n'
                       '<Reference_Variable id="6" type="EXPRESSION" expr="2*VARVAL(5)"/>\n'
                       + FY.format(e="VARVAL(6)"),
                       lambda t: -1 - 20 * t / K),
    "spline_of_time": ('<Reference_Spline id="3" num_xy_pair="4">0 0 0.5 -10 1 -20 1.5 -30'
                       '</Reference_Spline>\n' + FY.format(e="AKISPL(TIME,0,3)"),
                       lambda t: -1 - 20 * t / K),
    "motion_of_time": ('<Reference_Variable id="5" type="EXPRESSION" expr="-0.1*TIME"/>\n'
                       '<Motion_Joint id="1" joint_id="1" joint_type="T" val_type="D" '
                       'expr="VARVAL(5)"/>',
                       lambda t: -1 - 0.1 * t),
    "velocity_motion_constant": ('<Motion_Joint id="1" joint_id="1" joint_type="T" val_type="V" '
                                 'ic_disp="0" expr="-0.1"/>',
                                 lambda t: -1 - 0.1 * t),
    "control_diff_state": ('<Control_Diff id="7" ic="0" expr="DIF(7) + 20*TIME"/>\n'
                           + FY.format(e="DIF(7)"),
                           lambda t: -1 - 20 * t / K),
    "implicit_variable": ('<Reference_Variable id="5" type="EXPRESSION" is_implicit="TRUE" '
                          'expr="VARVAL(5) + 20*TIME"/>\n' + FY.format(e="VARVAL(5)"),
                          lambda t: -1 - 20 * t / K),
    "general_constraint_of_time": ('<Constraint_General id="1" expr="DY(20,10,10) + 1 + 0.1*TIME"/>',
                                   lambda t: -1 - 0.1 * t),
    "user_routine": ('<Force_Vector_OneBody id="2" type="FORCEONLY" marker_id="20" '
                     'usrsub_param_string="USER(-20)" usrsub_fnc_name="gfosub_ramp" '
                     'script_name="ramp_routines.py" interpreter="PYTHON"/>',
                     lambda t: -1 - 20 * t / K),
}


def _run(path):
    # user routines may need an explicit opt-in in later versions of the API
    kw = {}
    if "allow_user_code" in inspect.signature(run).parameters:
        kw["allow_user_code"] = True
    return run(str(path), **kw)


@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
@pytest.mark.parametrize("source", sorted(SOURCES))
def test_quasistatic_ramp_follows_time(tmp_path, source, method):
    extra, closed = SOURCES[source]
    (tmp_path / "ramp_routines.py").write_text(USER_SCRIPT)
    deck = tmp_path / f"{source}.xml"
    deck.write_text(DECK.format(method=method, extra=extra))
    res = _run(deck)
    ar = res.analyses[0]
    assert ar.status == "converged", ar.message
    assert "solved once" not in ar.message
    t = np.asarray(ar.datasets["time"])
    y = np.asarray(ar.datasets["bodies/position"])[:, 0, 1]
    assert len(t) == 9 and t[-1] == pytest.approx(1.0)
    # FIM_D's interpolated frames carry the integrator's error (tol 1e-6)
    np.testing.assert_allclose(y, closed(t), rtol=0, atol=1e-9 if method == "FIM_S" else 1e-6)
    assert abs(y[-1] - y[0]) > 0.05         # it really moved


def test_time_independent_scene_is_still_solved_once(tmp_path):
    deck = tmp_path / "const.xml"
    deck.write_text(DECK.format(method="FIM_S", extra=FY.format(e="-20")))
    ar = run(str(deck)).analyses[0]
    assert ar.status == "converged"
    assert "solved once" in ar.message
    y = np.asarray(ar.datasets["bodies/position"])[:, 0, 1]
    np.testing.assert_allclose(y, -1 - 20 / K, atol=1e-9)


def test_time_sources_name_the_element(tmp_path):
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    deck = tmp_path / "g.xml"
    deck.write_text(DECK.format(method="FIM_S", extra=SOURCES["gravity_step"][0]))
    model = compile_model(load_deck(str(deck)))
    assert model.depends_on_time()
    assert any("Force_Gravity" in s and "grav_y" in s for s in model.time_sources)


def test_request_of_time_does_not_make_the_solution_time_dependent(tmp_path):
    """Output-only expressions (Post_Request) never change the solution."""
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    deck = tmp_path / "r.xml"
    deck.write_text(DECK.format(method="FIM_S", extra=FY.format(e="-20") + '\n<Post_Request '
                                'id="1" type="EXPRESSION" expr1="TIME" expr2="DY(20)"/>'))
    model = compile_model(load_deck(str(deck)))
    assert not model.depends_on_time()


def test_curve_of_time_is_a_located_error(tmp_path):
    """Curve geometry is evaluated without a time: TIME there read 0 at every frame (the point
    stayed on the t = 0 curve); now a located error."""

    from poise.core.errors import DeckError
    src = DECKS / "elem_ptcv_parabola.xml"
    text = src.read_text().replace('y_expression="0.5*U**2"', 'y_expression="0.5*U**2 + TIME"')
    p = tmp_path / "ptcv_time.xml"
    p.write_text(text)
    line = next(k for k, s in enumerate(text.splitlines(), 1) if "<Reference_ParamCurve" in s)
    with pytest.raises(DeckError) as e:
        run(str(p))
    assert f"{p}:{line}: <Reference_ParamCurve id=1> y_expression" in str(e.value)
    assert "TIME" in str(e.value)


#: element type -> a scene of SOURCES whose only time dependence is in that type
TIME_SCENES = {"gravity": "gravity_step", "motions": "motion_of_time",
               "expressions": "spline_of_time", "diff_vars": "control_diff_state",
               "user": "user_routine", "gcons": "general_constraint_of_time"}


def _time_capable():
    from poise.elements.registry import element_types, static
    return [et.name for et in element_types() if et.time_dependent is not static]


def test_every_time_capable_type_has_a_scene():
    """A type that declares a ``time_dependent`` other than ``static`` gets a scene below."""
    assert sorted(_time_capable()) == sorted(TIME_SCENES)


@pytest.mark.parametrize("name", _time_capable())
def test_time_dependence_comes_from_the_declaring_type(tmp_path, name):
    """The model's decision (solve once or per frame) is the element types' declared
    ``time_dependent`` of its compiled families; a scene whose only time dependence is in
    element type ``name`` is detected, through that type alone."""
    from poise.deck.parser import load_deck
    from poise.elements.registry import type_of
    from poise.model.compile import compile_model
    (tmp_path / "ramp_routines.py").write_text(USER_SCRIPT)
    deck = tmp_path / "scene.xml"
    deck.write_text(DECK.format(method="FIM_S", extra=SOURCES[TIME_SCENES[name]][0]))
    model = compile_model(load_deck(str(deck)), user_code="run")
    assert model.depends_on_time()
    reading = {type_of(f).name for f in model.families if type_of(f).time_dependent(f)}
    assert reading == {name}
    assert model.time_sources and all("scene.xml:" in s for s in model.time_sources)
