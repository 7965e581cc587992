"""Every value shown or written is in the deck's units: a 2 kg body in an N-kg-mm-s deck is 2
(not the internal F = m a scaled 0.002), in /model/bodies/mass, `poise check` and its JSON; the
solution itself uses the scaled mass (weight m g through the units factor)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from poise.app.check import check
from poise.app.runner import run

DECK = '''<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Unit force_unit="{force}" mass_unit="{mass_u}" length_unit="{length}" time_unit="SECOND"/>
    <Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Force_Gravity grav_x="0" grav_y="{g}" grav_z="0"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="10"/>
    <Reference_Marker id="10" body_id="1" pos_x="0" pos_y="0" pos_z="0"/>
    <Reference_Marker id="11" body_id="1" pos_x="0" pos_y="-{L}" pos_z="0" a00="0" a10="0" a20="1" a01="1" a11="0" a21="0" a02="0" a12="1" a22="0"/>
    <Body_Rigid id="2" cg_id="20" mass="{m}" inertia_xx="1." inertia_yy="1." inertia_zz="1." inertia_xy="0." inertia_yz="0." inertia_xz="0."/>
    <Reference_Marker id="20" body_id="2" pos_x="0" pos_y="-{L}" pos_z="0"/>
    <Reference_Marker id="21" body_id="2" pos_x="0" pos_y="-{L}" pos_z="0" a00="0" a10="0" a20="1" a01="1" a11="0" a21="0" a02="0" a12="1" a22="0"/>
    <Body_Point id="3" cg_id="30" mass="{m2}"/>
    <Reference_Marker id="30" body_id="3" pos_x="{L}" pos_y="0" pos_z="0"/>
    <Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="21" j_marker_id="11"/>
    <Constraint_Joint id="2" type="SPHERICAL" i_marker_id="30" j_marker_id="10"/>
    <Force_SpringDamper id="1" type="TRANSLATIONAL" i_marker_id="20" j_marker_id="10" stiffness="{k}" damping="0." length="{L}" preload="0."/>
  </Model>
  <Command>
    <Simulate analysis_type="Static"/>
    <Stop/>
  </Command>
</MotionSolve>
'''

# (units, mass, point mass, g [length/s^2], k [force/length], L, weight of body 2 [force])
CASES = {
    # N-kg-mm-s: 1 kg mm/s^2 = 1e-3 N; weight 2 kg * 9810 mm/s^2 * 1e-3 = 19.62 N
    "N-kg-mm-s": (dict(force="NEWTON", mass_u="KILOGRAM", length="MILLIMETER"), 2.0, 0.5,
                  -9810.0, 10.0, 1000.0, 2.0 * 9.81),
    # lbf-lbm-in-s: 1 lbm in/s^2 = 0.45359237*0.0254/4.4482216152605 lbf; standard g
    "lbf-lbm-in-s": (dict(force="POUND_FORCE", mass_u="POUND_MASS", length="INCH"), 3.0, 0.25,
                     -9.80665 / 0.0254, 20.0, 40.0,
                     3.0 * (9.80665 / 0.0254) * 0.45359237 * 0.0254 / 4.4482216152605),
}


def _write(tmp_path, name):
    units, m, m2, g, k, L, _ = CASES[name]
    p = tmp_path / f"{name}.xml"
    p.write_text(DECK.format(m=m, m2=m2, g=g, k=k, L=L, **units))
    return p


@pytest.mark.parametrize("name", sorted(CASES))
def test_written_and_shown_masses_are_deck_units(tmp_path, name):
    _, m, m2, g, k, L, weight = CASES[name]
    p = _write(tmp_path, name)
    res = run(str(p))
    np.testing.assert_allclose(res.model_datasets["bodies/mass"], [m, m2], rtol=1e-15)
    rep = check(str(p))
    assert [b["mass"] for b in rep.bodies] == pytest.approx([m, m2], rel=1e-15)
    # the solution weighs the body through the units factor: y = -L - W / k (hand-computed W)
    ar = res.analyses[0]
    assert ar.status == "converged"
    y = float(np.asarray(ar.datasets["bodies/position"])[-1, 0, 1])
    assert y == pytest.approx(-L - weight / k, rel=1e-12)


def test_hdf5_and_check_json_show_deck_mass(tmp_path):
    p = _write(tmp_path, "N-kg-mm-s")
    out = tmp_path / "o.h5"
    r = subprocess.run([sys.executable, "-m", "poise_cli", "solve", str(p), "-o", str(out)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    import h5py
    with h5py.File(out, "r") as f:
        np.testing.assert_allclose(f["model/bodies/mass"][()], [2.0, 0.5], rtol=1e-15)
    r = subprocess.run([sys.executable, "-m", "poise_cli", "check", str(p), "--json"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert [b["mass"] for b in d["bodies"]] == pytest.approx([2.0, 0.5], rel=1e-15)
