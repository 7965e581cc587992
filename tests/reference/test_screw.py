"""SCREW joint against a closed form (its FD-Jacobian case comes from the registry).

A body on a CYLINDRICAL + SCREW joint pair (pitch p, common z axis), pushed along z by a force F
and held by a rotational spring k about z. Virtual work with z = p theta / (2 pi):
F p / (2 pi) = k theta, so theta = F p / (2 pi k) and z = p theta / (2 pi). The screw carries
the whole axial load: its reaction on the body is -F along z and F p / (2 pi) about z.
"""
import numpy as np
import pytest

from poise.app.api import run_deck

DECK = """<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="10"/>
    <Reference_Marker id="10" body_id="1"/>
    <Reference_Marker id="11" body_id="1"/>
    <Body_Rigid id="2" cg_id="20" mass="1.0" inertia_xx="1" inertia_yy="1" inertia_zz="1"
        inertia_xy="0" inertia_yz="0" inertia_xz="0"/>
    <Reference_Marker id="20" body_id="2"/>
    <Reference_Marker id="21" body_id="2"/>
    <Constraint_Joint id="1" type="CYLINDRICAL" i_marker_id="21" j_marker_id="11"/>
    <Constraint_Joint id="2" type="SCREW" i_marker_id="21" j_marker_id="11" pitch="{p}"/>
    <Force_Vector_OneBody id="1" type="FORCEONLY" marker_id="21" fx_expression="0."
        fy_expression="0." fz_expression="{F}"/>
    <Force_SpringDamper id="2" type="ROTATIONAL" i_marker_id="21" j_marker_id="11"
        stiffness="{k}" damping="0." length="0." preload="0."/>
  </Model>
  <Command>
    <Simulate analysis_type="Static"/>
    <Stop/>
  </Command>
</MotionSolve>
"""


@pytest.mark.parametrize("p", [0.5, -0.5])          # right- and left-handed
def test_screw_under_axial_force_and_torsion_spring(tmp_path, p):
    F, k = 10.0, 2.0
    theta = F * p / (2 * np.pi * k)
    z = p * theta / (2 * np.pi)
    path = tmp_path / "screw.xml"
    path.write_text(DECK.format(p=p, F=F, k=k))
    a = run_deck(str(path)).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    R = d["bodies/orientation"][-1, 0]
    assert abs(np.arctan2(R[1, 0], R[0, 0]) - theta) < 1e-9
    np.testing.assert_allclose(d["bodies/position"][-1, 0], [0.0, 0.0, z], atol=1e-10)
    assert list(d["joints/id"]) == [1, 2]
    np.testing.assert_allclose(d["joints/force"][-1, 1], [0, 0, -F], atol=1e-8)
    np.testing.assert_allclose(d["joints/torque"][-1, 1], [0, 0, F * p / (2 * np.pi)], atol=1e-8)
