"""MKEAM on models its integration cannot resolve, and its bounded cost.

* A soft body (1e-9 N/mm spring) next to a stiff one: the integration's step and kinetic-energy
  scales are set by the stiff mode, so only the Newton polish can move the soft body; it must,
  and the result is called converged only if it meets ``max_imbalance`` (with a 1e12 N/mm
  spring the residual of the stiff body cannot drop below ~1e-2 N in double precision: exit 1,
  with the soft body still at its equilibrium). Expected positions: the closed form of two
  springs in series, derived here.
* An inverted pendulum whose (doubled) torsion spring holds it upright: the upright pose is the
  stable equilibrium (k = 4000 > m g l = 3924 N mm), reached within a bounded integration
  budget (the soft quartic mode near upright once kept MKEAM integrating for minutes).
* A gravity expression that divides by zero, and a marker so far out that the model size is not
  finite: a clean failure (exit 1, results written), as FIM_S gives, not an internal error.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from poise.app.api import run_deck

POISE = str(Path(sys.executable).parent / "poise")

TWO_SPRINGS = """<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="MILLIMETER" time_unit="SECOND"/>
    <Force_Gravity grav_x="0." grav_y="0." grav_z="0."/>
    <Param_Static method="MKEAM" max_num_iter="100" max_imbalance="1.0E-8" max_error="1.0E-8"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="100"/>
    <Reference_Marker id="100" body_id="1" pos_x="0." pos_y="0." pos_z="0."/>
    <Body_Rigid id="2" cg_id="200" mass="1.0" inertia_xx="1" inertia_yy="1" inertia_zz="1"/>
    <Reference_Marker id="200" body_id="2" pos_x="100.0" pos_y="0." pos_z="0."/>
    <Reference_Marker id="201" body_id="2" pos_x="100.0" pos_y="0." pos_z="0." {AX}/>
    <Reference_Marker id="202" body_id="1" pos_x="100.0" pos_y="0." pos_z="0." {AX}/>
    <Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="201" j_marker_id="202"/>
    <Force_SpringDamper id="2" type="TRANSLATIONAL" i_marker_id="200" j_marker_id="100" stiffness="{K2!r}" damping="0" length="100.0" preload="0"/>
    <Force_Vector_OneBody id="2" type="FORCEONLY" marker_id="200" ref_marker_id="100" fx_expression="{F2!r}" fy_expression="0" fz_expression="0"/>
    <Body_Rigid id="3" cg_id="300" mass="1.0" inertia_xx="1" inertia_yy="1" inertia_zz="1"/>
    <Reference_Marker id="300" body_id="3" pos_x="150.0" pos_y="0." pos_z="0."/>
    <Reference_Marker id="301" body_id="3" pos_x="150.0" pos_y="0." pos_z="0." {AX}/>
    <Reference_Marker id="302" body_id="1" pos_x="150.0" pos_y="0." pos_z="0." {AX}/>
    <Constraint_Joint id="2" type="TRANSLATIONAL" i_marker_id="301" j_marker_id="302"/>
    <Force_SpringDamper id="3" type="TRANSLATIONAL" i_marker_id="300" j_marker_id="200" stiffness="{K3!r}" damping="0" length="50.0" preload="0"/>
    <Force_Vector_OneBody id="3" type="FORCEONLY" marker_id="300" ref_marker_id="100" fx_expression="{F3!r}" fy_expression="0" fz_expression="0"/>
  </Model>
  <Command>
    <Simulate analysis_type="Static"/>
    <Stop/>
  </Command>
</MotionSolve>
"""
# marker z axis along global X (the TRANSLATIONAL joints slide along X)
AX = 'a00="0" a10="0" a20="-1" a01="0" a11="1" a21="0" a02="1" a12="0" a22="0"'


def two_springs(tmp_path, k2, k3=1e-9, f2=1000.0, f3=1e-6):
    p = tmp_path / "two_springs.xml"
    p.write_text(TWO_SPRINGS.format(AX=AX, K2=k2, K3=k3, F2=f2, F3=f3))
    return p


def series_equilibrium(k2, k3, f2, f3):
    """Body 2 (free length 100 from ground) carries its load and the soft spring's pull f3;
    body 3 sits f3 / k3 beyond the soft spring's free length 50 from body 2."""
    x2 = 100.0 + (f2 + f3) / k2
    return x2, x2 + 50.0 + f3 / k3


def _strict_json(text):
    def bad(c):
        raise ValueError(f"non-strict JSON constant {c}")
    return json.loads(text, parse_constant=bad)


def _cli(deck, out, timeout=60):
    r = subprocess.run([POISE, "solve", str(deck), "-o", str(out), "--json"],
                       capture_output=True, text=True, timeout=timeout)
    assert "Traceback" not in r.stderr, r.stderr
    return r, _strict_json(r.stdout)


def test_soft_body_reaches_the_closed_form_and_converges(tmp_path):
    """k2 = 1e4, k3 = 1e-9 (13 decades apart): the residual floor of the stiff body
    (k2 x ulp(100) ~ 1e-10 N) is below max_imbalance, so the run must converge, at the
    closed form, with the soft body moved 1000 mm by the polish."""
    k2, k3, f2, f3 = 1e4, 1e-9, 1000.0, 1e-6
    x2, x3 = series_equilibrium(k2, k3, f2, f3)
    assert abs(x3 - 1150.1) < 1e-6
    res = run_deck(str(two_springs(tmp_path, k2, k3, f2, f3)))
    a = res.analyses[0]
    assert res.exit_code == 0 and a.status == "converged", a.message
    d = a.datasets
    L = float(res.model_datasets["length_scale"])
    pos = d["bodies/position"][0]
    assert abs(pos[0, 0] - x2) < 1e-6 * L
    assert abs(pos[1, 0] - x3) < 1e-6 * L
    assert bool(d["frames/converged"][0])
    assert d["frames/imbalance"][0] <= 1e-8          # translations only: force rows
    assert d["frames/error"][0] <= 1e-8


def test_soft_body_next_to_a_1e12_spring_moves_but_is_not_called_converged(tmp_path):
    """The reliability deck: the soft body must reach x = 1150, and since the stiff body's
    residual cannot reach 1e-8 N in double precision (k2 x ulp(100) ~ 0.014 N), the run ends
    with exit 1, results written, every label saying not converged."""
    k2, k3, f2, f3 = 1e12, 1e-9, 1000.0, 1e-6
    x2, x3 = series_equilibrium(k2, k3, f2, f3)
    assert abs(x3 - 1150.0) < 1e-6
    out = tmp_path / "soft.h5"
    r, js = _cli(two_springs(tmp_path, k2, k3, f2, f3), out)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert js["status"] != "converged"
    an = js["analyses"][0]
    assert an["status"] == "failed"
    assert "max_imbalance" in an["message"]
    with h5py.File(out, "r") as f:
        g = f["analysis_000"]
        assert not bool(g["frames/converged"][0])
        assert g["frames/status"].asstr()[0] != "converged"
        assert g["frames/imbalance"][0] > 1e-8
        pos = g["bodies/position"][0]
        L = float(f["model/length_scale"][()])
    assert abs(pos[1, 0] - x3) < 1e-6 * L
    assert abs(pos[0, 0] - x2) < 1e-6 * L


INVERTED = """<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="MILLIMETER" time_unit="SECOND"/>
    <Force_Gravity grav_x="0." grav_y="-9810." grav_z="0."/>
    <Param_Static method="MKEAM" max_num_iter="100" max_imbalance="1.0E-8" max_error="1.0E-8"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="100"/>
    <Reference_Marker id="100" body_id="1" pos_x="0." pos_y="0." pos_z="0."/>
    <Reference_Marker id="101" body_id="1" pos_x="0." pos_y="0." pos_z="0."/>
    <Body_Rigid id="2" cg_id="200" mass="2.0" inertia_xx="25.0" inertia_yy="26679.166666666668" inertia_zz="26679.166666666668"/>
    <Reference_Marker id="200" body_id="2" pos_x="-19.966683329365637" pos_y="199.00083305560514" pos_z="0." a00="-0.09983341664682818" a10="0.9950041652780257" a20="0." a01="-0.9950041652780257" a11="-0.09983341664682818" a21="0." a02="0." a12="0." a22="1.0"/>
    <Reference_Marker id="201" body_id="2" pos_x="0." pos_y="0." pos_z="0."/>
    <Constraint_Joint id="1" type="REVOLUTE" i_marker_id="201" j_marker_id="101"/>
    <Force_SpringDamper id="1" type="ROTATIONAL" i_marker_id="201" j_marker_id="101" stiffness="{K!r}" damping="0." length="-0.1" preload="0."/>
    <Force_SpringDamper id="2" type="ROTATIONAL" i_marker_id="201" j_marker_id="101" stiffness="{K!r}" damping="0." length="-0.1" preload="0."/>
  </Model>
  <Command>
    <Simulate analysis_type="Static"/>
    <Stop/>
  </Command>
</MotionSolve>
"""


def test_inverted_pendulum_held_by_a_doubled_spring_stays_upright_in_bounded_time(tmp_path):
    """Two 2000 N mm/rad springs (free angle: upright) on a 2 kg bar, CG 200 mm from the hinge,
    started 0.1 rad off upright. V(phi) = k phi^2 / 2 + m g l cos(phi) with k = 4000 > m g l:
    V' = k phi - m g l sin(phi) vanishes only at phi = 0, a minimum (V'' = k - m g l > 0):
    the answer is upright. Near upright the mode is nearly quartic (V'' = 76 N mm/rad): the
    integration alone used to crawl there for minutes."""
    k, wl = 2000.0, 2.0 * 9810.0 * 200.0 / 1000.0
    assert 2 * k > wl
    phis = np.linspace(1e-3, 4 * math.pi, 20000)
    assert np.all(2 * k * phis - wl * np.sin(phis) > 0)      # no other equilibrium for phi > 0
    deck = tmp_path / "inverted2.xml"
    deck.write_text(INVERTED.format(K=k))
    out = tmp_path / "inverted2.h5"
    r, js = _cli(deck, out, timeout=60)
    assert r.returncode == 0, (r.stdout, r.stderr)
    with h5py.File(out, "r") as f:
        g = f["analysis_000"]
        assert bool(g["frames/converged"][0])
        cg = g["bodies/position"][0, 0]
    assert np.abs(cg - [0.0, 200.0, 0.0]).max() < 1e-6 * 400


def test_hopeless_inputs_fail_cleanly(tmp_path):
    """A gravity component 1/0 is a constant that cannot be evaluated: a located deck error
    (exit 3) before any method runs (state-dependent divisions by zero under MKEAM end as
    exit 1: tests/regression/test_expr_failures_clean.py)."""
    deck = tmp_path / "bad.xml"
    deck.write_text(INVERTED.format(K=2000.0).replace('grav_y="-9810."', 'grav_y="1/0"'))
    r, js = _cli(deck, tmp_path / "bad.h5", timeout=60)
    assert r.returncode == 3, (r.stdout, r.stderr)
    assert any("division by zero" in p and "<Force_Gravity>" in p and p.startswith(str(deck))
               for p in js["problems"]), js


def test_a_marker_too_far_out_is_a_located_deck_error(tmp_path):
    """A marker at 2.4e299 (its model size would overflow, the MKEAM run hung): refused at
    the deck, exit 3, located."""
    deck = tmp_path / "bad.xml"
    deck.write_text(INVERTED.format(K=2000.0).replace(
        '<Reference_Marker id="201" body_id="2" pos_x="0." pos_y="0." pos_z="0."/>',
        '<Reference_Marker id="201" body_id="2" pos_x="0." pos_y="0." pos_z="0."/>\n'
        '    <Reference_Marker id="202" body_id="2" pos_x="400." pos_y="0." '
        'pos_z="2.4203405691310655e+299"/>'))
    r, js = _cli(deck, tmp_path / "bad.h5", timeout=60)
    assert r.returncode == 3, (r.stdout, r.stderr)
    assert any("pos_z" in p and "<Reference_Marker id=202>" in p and p.startswith(str(deck))
               for p in js["problems"]), js


def test_certify_demotes_a_frame_that_misses_the_tolerances():
    """The one rule every method's frames go through: force rows against max_imbalance,
    moment rows against max_imbalance * L, constraint rows against max_error (x L)."""
    from types import SimpleNamespace

    from poise.solvers.certify import certify
    from poise.solvers.newton import FrameOutcome
    from poise.solvers.status import Status
    L = 50.0
    model = SimpleNamespace(L=L, q_kind=np.array([0, 0, 0, 1, 1, 1]), row_kind=np.array([0, 1]),
                            nq=6, coord_info=[f"q{i}" for i in range(6)],
                            row_info=[dict(file="f", line=1, tag="T", id=1, equation="e")] * 2)
    s = SimpleNamespace(max_imbalance=1e-6, max_error=1e-6)

    def run(r, phi, error=np.nan):
        o = FrameOutcome(Status.CONVERGED, 1, np.nan, error, "converged")
        c, _ = certify(model, s, o, np.asarray(r, float), np.asarray(phi, float))
        assert o.status is Status.CONVERGED and np.isnan(o.imbalance)   # a new outcome
        return c

    ok = run([1e-7, 0, 0, 4e-5, 0, 0], [1e-5, 1e-7])          # moment 4e-5 <= 1e-6 * 50
    assert ok.ok and ok.imbalance == pytest.approx(4e-5) and ok.error == pytest.approx(2e-7)
    bad_force = run([2e-6, 0, 0, 0, 0, 0], [0, 0])
    assert bad_force.status is Status.TOLERANCE_NOT_MET and "imbalance 2e-06" in bad_force.message
    bad_moment = run([0, 0, 0, 6e-5, 0, 0], [0, 0])
    assert bad_moment.status is Status.TOLERANCE_NOT_MET and "moment" in bad_moment.message
    bad_phi = run([0] * 6, [1e-3, 0])                          # 1e-3 > 1e-6 * 50
    assert bad_phi.status is Status.TOLERANCE_NOT_MET and "constraint" in bad_phi.message
    bad_err = run([0] * 6, [0, 0], error=1e-3)                 # the method's own estimate
    assert bad_err.status is Status.TOLERANCE_NOT_MET
    failed = FrameOutcome(Status.MAX_ITERATIONS, 1, np.nan, np.nan, "m")
    failed, _ = certify(model, s, failed, np.zeros(6), np.zeros(2))
    assert failed.status is Status.MAX_ITERATIONS and failed.imbalance == 0.0
