"""Command versions of model elements between two Simulates apply to the analyses that follow
(or are rejected with a located message, exit 3); they are never ignored. Vertical spring-mass
(m = 2, free length 1, hanging from the origin on a slider): y = -1 + m g_y / k."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from poise.core.errors import DeckError
from poise.app.runner import run

DECK = '''<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Force_Gravity grav_x="0" grav_y="-9.81" grav_z="0"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="10"/>
    <Reference_Marker id="10" body_id="1" pos_x="0" pos_y="0" pos_z="0"/>
    <Reference_Marker id="11" body_id="1" pos_x="0" pos_y="-1" pos_z="0" a00="0" a10="0" a20="1" a01="1" a11="0" a21="0" a02="0" a12="1" a22="0"/>
    <Body_Rigid id="2" cg_id="20" mass="2.0" inertia_xx="1." inertia_yy="1." inertia_zz="1." inertia_xy="0." inertia_yz="0." inertia_xz="0."/>
    <Reference_Marker id="20" body_id="2" pos_x="0" pos_y="-1" pos_z="0"/>
    <Reference_Marker id="21" body_id="2" pos_x="0" pos_y="-1" pos_z="0" a00="0" a10="0" a20="1" a01="1" a11="0" a21="0" a02="0" a12="1" a22="0"/>
    <Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="21" j_marker_id="11"/>
    <Force_SpringDamper id="1" type="TRANSLATIONAL" i_marker_id="20" j_marker_id="10" stiffness="200." damping="0." length="1.0" preload="0."/>
    <Reference_Variable id="5" type="EXPRESSION" expr="0"/>
    <Force_Vector_OneBody id="2" type="FORCEONLY" marker_id="20" fx_expression="0" fy_expression="VARVAL(5)" fz_expression="0"/>
  </Model>
  <Command>
    <Simulate analysis_type="Static"/>
{commands}
    <Simulate analysis_type="Static"/>
    <Stop/>
  </Command>
</MotionSolve>
'''
M = 2.0


def _deck(tmp_path, commands, name="d.xml"):
    p = tmp_path / name
    p.write_text(DECK.format(commands=commands))
    return p


def _y(ar):
    return float(np.asarray(ar.datasets["bodies/position"])[-1, 0, 1])


def test_spring_stiffness_changed_between_statics(tmp_path):
    res = run(str(_deck(tmp_path, '<Force_SpringDamper id="1" stiffness="400."/>')))
    a, b = res.analyses
    assert a.status == b.status == "converged"
    assert _y(a) == pytest.approx(-1 - M * 9.81 / 200, abs=1e-10)
    assert _y(b) == pytest.approx(-1 - M * 9.81 / 400, abs=1e-10)


def test_gravity_changed_between_statics(tmp_path):
    res = run(str(_deck(tmp_path, '<Force_Gravity grav_x="0" grav_y="-3.0" grav_z="0"/>')))
    a, b = res.analyses
    assert _y(a) == pytest.approx(-1 - M * 9.81 / 200, abs=1e-10)
    assert _y(b) == pytest.approx(-1 - M * 3.0 / 200, abs=1e-10)


def test_mass_and_variable_changed(tmp_path):
    cmds = ('<Body_Rigid id="2" mass="3.0"/>\n'
            '<Reference_Variable id="5" expr="-10"/>')
    res = run(str(_deck(tmp_path, cmds)))
    a, b = res.analyses
    assert _y(a) == pytest.approx(-1 - M * 9.81 / 200, abs=1e-10)
    assert _y(b) == pytest.approx(-1 + (3.0 * -9.81 - 10) / 200, abs=1e-10)


def test_commands_accumulate_and_apply_to_later_analyses(tmp_path):
    text = DECK.format(commands='<Force_SpringDamper id="1" stiffness="400."/>').replace(
        '    <Stop/>', '    <Force_Gravity grav_y="-19.62"/>\n    <Simulate analysis_type="Static"/>\n'
        '    <Simulate analysis_type="Static"/>\n    <Stop/>')
    p = tmp_path / "seq.xml"
    p.write_text(text)
    ys = [_y(ar) for ar in run(str(p)).analyses]
    exp = [-1 - M * 9.81 / 200, -1 - M * 9.81 / 400, -1 - M * 19.62 / 400, -1 - M * 19.62 / 400]
    np.testing.assert_allclose(ys, exp, atol=1e-10)


def test_quasistatic_after_stiffness_command(tmp_path):
    text = DECK.format(commands='<Force_SpringDamper id="1" stiffness="400."/>\n'
                       '<Reference_Variable id="5" expr="-40*(TIME-1)"/>').replace(
        '<Simulate analysis_type="Static"/>\n    <Stop/>',
        '<Simulate analysis_type="Static" start_time="1" end_time="2" print_interval="0.25"/>\n'
        '    <Stop/>')
    p = tmp_path / "qs.xml"
    p.write_text(text)
    a, b = run(str(p)).analyses
    t = np.asarray(b.datasets["time"])
    y = np.asarray(b.datasets["bodies/position"])[:, 0, 1]
    np.testing.assert_allclose(y, -1 + (M * -9.81 - 40 * (t - 1)) / 400, atol=1e-9)


@pytest.mark.parametrize("cmd, what", [
    ('<Reference_Marker id="20" pos_x="0.5"/>', "Reference_Marker"),
    ('<Force_SpringDamper id="1" i_marker_id="21"/>', "i_marker_id"),
    ('<Constraint_Joint id="1" type="REVOLUTE"/>', "Constraint_Joint"),
])
def test_unsupported_commands_are_located_errors(tmp_path, cmd, what):
    p = _deck(tmp_path, cmd)
    with pytest.raises(DeckError) as e:
        run(str(p))
    msg = str(e.value)
    line = next(k for k, s in enumerate(p.read_text().splitlines(), 1) if s.strip() == cmd)
    assert f"{p}:{line}:" in msg and what in msg


def test_structure_changing_command_is_a_located_error(tmp_path):
    # the variable would now read a continuous angle: a new state the earlier analysis lacks
    p = _deck(tmp_path, '<Reference_Variable id="5" expr="AZ(20,10)"/>')
    with pytest.raises(DeckError) as e:
        run(str(p))
    assert "structure" in str(e.value) and f"{p}:" in str(e.value)


def test_cli_exit_3_for_unsupported_command(tmp_path):
    p = _deck(tmp_path, '<Reference_Marker id="20" pos_x="0.5"/>')
    r = subprocess.run([sys.executable, "-m", "poise_cli", "solve", str(p), "-o",
                        str(tmp_path / "o.h5")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 3, r.stderr
    assert "Reference_Marker" in r.stderr and "Traceback" not in r.stderr


def test_gravity_command_without_model_gravity_adds_it(tmp_path):
    text = DECK.format(commands='<Force_Gravity grav_y="-5.0"/>').replace(
        '<Force_Gravity grav_x="0" grav_y="-9.81" grav_z="0"/>', '')
    p = tmp_path / "nog.xml"
    p.write_text(text)
    a, b = run(str(p)).analyses
    assert _y(a) == pytest.approx(-1.0, abs=1e-10)
    assert _y(b) == pytest.approx(-1 - M * 5.0 / 200, abs=1e-10)


def test_motion_expression_command(tmp_path):
    text = DECK.format(commands='<Motion_Joint id="1" expr="-0.3"/>').replace(
        '</Model>', '<Motion_Joint id="1" joint_id="1" joint_type="T" val_type="D" expr="-0.1"/>'
        '\n</Model>')
    p = tmp_path / "mot.xml"
    p.write_text(text)
    a, b = run(str(p)).analyses
    assert _y(a) == pytest.approx(-1.1, abs=1e-10)
    assert _y(b) == pytest.approx(-1.3, abs=1e-10)
    p.write_text(text.replace('val_type="D" expr="-0.1"', 'val_type="V" ic_disp="0" expr="-0.1"'))
    with pytest.raises(DeckError, match="velocity/acceleration motion"):
        run(str(p))


def test_command_with_misspelt_attribute_is_an_error(tmp_path):
    p = _deck(tmp_path, '<Force_SpringDamper id="1" stifness="400."/>')
    with pytest.raises(DeckError, match="unknown attribute 'stifness'"):
        run(str(p))
