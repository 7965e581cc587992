"""CONSTANT_VELOCITY joint: MotionSolve/Adams convention, each marker's z axis down its own shaft
away from the joint centre (opposite z axes for coaxial shafts). Input shaft on a revolute along
global x behind the centre, output shaft on a revolute along u = (cos b, sin b, 0) in front; a
CV joint transmits the input rotation exactly (output angle = input angle, any bend b). The
degenerate set-up (z axes the same way) used to converge with the output shaft still: now a
located error naming the convention."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from poise.core.errors import DeckError
from poise.app.runner import run


def _mk(id, body, p, R):
    a = " ".join(f'a{i}{j}="{R[i, j]:.17g}"' for i in range(3) for j in range(3))
    return (f'<Reference_Marker id="{id}" body_id="{body}" pos_x="{p[0]:.17g}" '
            f'pos_y="{p[1]:.17g}" pos_z="{p[2]:.17g}" {a}/>')


def _cols(x, y, z):
    return np.column_stack([x, y, z])


def _deck(beta=0.0, angle=0.7, convention=True, torque=False):
    ex, ey, ez = np.eye(3)
    u = np.array([np.cos(beta), np.sin(beta), 0.0])
    RJ = _cols(ez, ey, -ex)                                  # input shaft: z_J = -x
    RI = _cols(ez, np.array([np.sin(beta), -np.cos(beta), 0.0]), u)   # output shaft: z_I = u
    if not convention:                                       # both z axes along +x
        RJ = RI = _cols(ey, ez, ex)
    Ru = _cols(np.cross(ez, u), ez, u)
    Rx = _cols(ey, ez, ex)
    I3 = np.eye(3)
    m = [_mk(10, 1, [0, 0, 0], I3), _mk(11, 1, [-1, 0, 0], Rx), _mk(12, 1, u, Ru),
         _mk(20, 2, [-1, 0, 0], I3), _mk(21, 2, [-1, 0, 0], Rx), _mk(22, 2, [0, 0, 0], RJ),
         _mk(30, 3, u, I3), _mk(31, 3, u, Ru), _mk(32, 3, [0, 0, 0], RI)]
    if torque:     # input: torsion spring k = 10 and torque 10*angle; output spring k = 5
        drive = ('<Force_SpringDamper id="2" type="ROTATIONAL" i_marker_id="21" j_marker_id="11" '
                 'stiffness="10." damping="0." length="0" preload="0"/>\n'
                 '<Force_Scalar_TwoBody id="3" type="TORQUE" i_marker_id="21" j_marker_id="11" '
                 f'val_expression="{10 * angle!r}"/>')
    else:
        drive = (f'<Motion_Joint id="1" joint_id="1" joint_type="R" val_type="D" '
                 f'expr="{angle!r}"/>')
    body = ('mass="1" inertia_xx="1" inertia_yy="1" inertia_zz="1" inertia_xy="0" '
            'inertia_yz="0" inertia_xz="0"')
    nl = "\n"
    return f'''<?xml version="1.0"?>
<MotionSolve><Model>
<Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
<Body_Rigid id="1" isground="TRUE" cg_id="10"/>
<Body_Rigid id="2" cg_id="20" {body}/>
<Body_Rigid id="3" cg_id="30" {body}/>
{nl.join(m)}
<Constraint_Joint id="1" type="REVOLUTE" i_marker_id="21" j_marker_id="11"/>
<Constraint_Joint id="2" type="REVOLUTE" i_marker_id="31" j_marker_id="12"/>
<Constraint_Joint id="3" type="CONSTANT_VELOCITY" i_marker_id="32" j_marker_id="22"/>
<Force_SpringDamper id="1" type="ROTATIONAL" i_marker_id="31" j_marker_id="12" stiffness="5." damping="0." length="0" preload="0"/>
{drive}
</Model><Command><Simulate analysis_type="Static"/><Stop/></Command></MotionSolve>
'''


def _angle(R, axis):
    """Signed rotation angle of R about the unit axis (R is a rotation about that axis)."""
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(np.arctan2(0.5 * w @ axis, 0.5 * (np.trace(R) - 1.0)))


@pytest.mark.parametrize("beta", [0.0, 0.4])
@pytest.mark.parametrize("torque", [False, True])
def test_output_turns_with_input(tmp_path, beta, torque):
    p = tmp_path / "cv.xml"
    p.write_text(_deck(beta, 0.7, True, torque))
    ar = run(str(p)).analyses[0]
    assert ar.status == "converged", ar.message
    R = np.asarray(ar.datasets["bodies/orientation"])[-1]
    u = np.array([np.cos(beta), np.sin(beta), 0.0])
    # motion: input angle 0.7; torque 7 against springs 10 (input) + 5 (output): 7/15
    expected = 7.0 / 15.0 if torque else 0.7
    assert _angle(R[0], np.array([1.0, 0.0, 0.0])) == pytest.approx(expected, abs=1e-9)
    assert _angle(R[1], u) == pytest.approx(expected, abs=1e-9)


def test_degenerate_axes_are_a_located_error(tmp_path):
    p = tmp_path / "cvbad.xml"
    text = _deck(0.0, 0.7, convention=False)
    p.write_text(text)
    line = next(k for k, s in enumerate(text.splitlines(), 1) if "CONSTANT_VELOCITY" in s)
    with pytest.raises(DeckError) as e:
        run(str(p))
    msg = str(e.value)
    assert f"{p}:{line}: <Constraint_Joint id=3>" in msg
    assert "convention" in msg and "z axis" in msg


def test_degenerate_axes_cli_exit_3(tmp_path):
    p = tmp_path / "cvbad.xml"
    p.write_text(_deck(0.0, 0.7, convention=False))
    r = subprocess.run([sys.executable, "-m", "poise_cli", "solve", str(p), "-o",
                        str(tmp_path / "o.h5")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 3 and "CONSTANT_VELOCITY" in r.stderr and "Traceback" not in r.stderr


def test_bent_same_way_axes_are_an_error(tmp_path):
    """z axes the same way on bent shafts (0.4 rad): the row would make the output shaft turn
    backwards (-0.7 rad for +0.7 rad in); rejected like the coaxial case."""
    ex, ey, ez = np.eye(3)
    b = 0.4
    Rz = np.array([[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]])
    RJ = _cols(ey, ez, ex)
    lines = _deck(b, 0.7).splitlines()
    for i, s in enumerate(lines):
        if s.startswith('<Reference_Marker id="22"'):
            lines[i] = _mk(22, 2, [0, 0, 0], RJ)
        if s.startswith('<Reference_Marker id="32"'):
            lines[i] = _mk(32, 3, [0, 0, 0], Rz @ RJ)
    p = tmp_path / "bent.xml"
    p.write_text("\n".join(lines))
    with pytest.raises(DeckError, match="z_I.z_J = 0.921"):
        run(str(p))
