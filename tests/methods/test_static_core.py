"""Core FIM_S behaviour: quadratic convergence, units, redundancy, assembly, stability classes.

References are written here independently of the solver (closed forms / scipy root finding).
"""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from poise.app.api import check_deck, run_deck

from support.paths import DECKS


POISE = str(Path(sys.executable).parent / "poise")

I3 = 'a00="1" a10="0" a20="0" a01="0" a11="1" a21="0" a02="0" a12="0" a22="1"'


def pendulum_deck(theta0, k=0.0, ref=0.0, m=2.0, l=400.0, units="mm", stability=None,
                  hinge_offset=0.0, tol=1e-10, extra=""):
    """Pendulum about global Z: CG at l/2 from the hinge along the body's x axis, gravity -Y.

    ``units`` "mm" (N-kg-mm-s, g = 9810 mm/s^2) or "m" (N-kg-m-s, g = 9.81 m/s^2)."""
    s = 1.0 if units == "mm" else 1e-3
    g = 9810.0 * s
    L = l * s
    c, sn = float(np.cos(theta0)), float(np.sin(theta0))
    dcm = f'a00="{c!r}" a10="{sn!r}" a20="0" a01="{-sn!r}" a11="{c!r}" a21="0" a02="0" a12="0" a22="1"'
    unit = "MILLIMETER" if units == "mm" else "METER"
    kk = float(k * s)    # N*mm/rad -> N*m/rad
    stab = f' stability="{stability}"' if stability is not None else ""
    return f"""<MotionSolve><Model>
<Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="{unit}" time_unit="SECOND"/>
<Force_Gravity grav_x="0" grav_y="{-g!r}" grav_z="0"/>
<Param_Static method="FIM_S" max_imbalance="{tol}" max_error="{tol}"{stab}/>
<Body_Rigid id="1" isground="TRUE" cg_id="10"/>
<Reference_Marker id="10" body_id="1" pos_x="0" pos_y="0" pos_z="0" {I3}/>
<Reference_Marker id="11" body_id="1" pos_x="0" pos_y="0" pos_z="0" {I3}/>
<Body_Rigid id="2" cg_id="20" mass="{m}" inertia_xx="{10 * s * s}" inertia_yy="{m * L * L / 12}" inertia_zz="{m * L * L / 12}" inertia_xy="0" inertia_yz="0" inertia_xz="0"/>
<Reference_Marker id="20" body_id="2" pos_x="{L / 2 * c!r}" pos_y="{L / 2 * sn!r}" pos_z="0" {dcm}/>
<Reference_Marker id="21" body_id="2" pos_x="{hinge_offset * s}" pos_y="0" pos_z="0" {dcm}/>
<Constraint_Joint id="1" type="REVOLUTE" i_marker_id="21" j_marker_id="11"/>
<Force_SpringDamper id="1" type="ROTATIONAL" i_marker_id="21" j_marker_id="11" stiffness="{kk!r}" damping="0" length="{float(ref)!r}" preload="0"/>
{extra}
</Model><Command><Simulate analysis_type="Static"/><Stop/></Command></MotionSolve>
"""


def solve_text(tmp_path, text, name="deck.xml", **overrides):
    p = tmp_path / name
    p.write_text(text)
    return run_deck(str(p), overrides=overrides)


def angle_of(res):
    R = res.analyses[0].datasets["bodies/orientation"][0, 0]
    return np.arctan2(R[1, 0], R[0, 0])


def test_quadratic_convergence(tmp_path):
    # spring-loaded pendulum started 1 rad away from equilibrium: smooth, Newton must be quadratic
    k, m, l, g = 4e5, 2.0, 400.0, 9.81
    res = solve_text(tmp_path, pendulum_deck(0.0, k=k, ref=1.0, tol=1e-11))
    a = res.analyses[0]
    assert a.converged
    th = brentq(lambda t: -k * (t - 1.0) - m * g * (l / 2) * np.cos(t), -1, 2)
    assert abs(angle_of(res) - th) < 1e-9
    e = a.datasets["iterations/imbalance"]
    ev = a.datasets["iterations/event"]
    e = e[ev == "newton"]
    assert len(e) <= 6
    # error ratio e_{k+1} / e_k^2 bounded while the error is above round-off
    ratios = [e[i + 1] / e[i] ** 2 for i in range(len(e) - 1) if e[i + 1] > 1e-9 * e[0]]
    assert ratios, e
    assert max(ratios[1:] or ratios) < 10.0 / e[0], (e, ratios)


def test_units_m_and_mm_same_physics_same_iterations(tmp_path):
    k = 3e5                                   # N*mm/rad
    r_mm = solve_text(tmp_path, pendulum_deck(0.3, k=k, ref=1.2, units="mm", tol=1e-6), "mm.xml")
    r_m = solve_text(tmp_path, pendulum_deck(0.3, k=k, ref=1.2, units="m", tol=1e-6), "m.xml")
    a_mm, a_m = r_mm.analyses[0], r_m.analyses[0]
    assert a_mm.converged and a_m.converged
    assert abs(angle_of(r_mm) - angle_of(r_m)) < 1e-9
    np.testing.assert_allclose(a_mm.datasets["bodies/position"][0] * 1e-3,
                               a_m.datasets["bodies/position"][0], atol=1e-12)
    # the hinge force (N) is the same; the torque-free hinge
    np.testing.assert_allclose(a_mm.datasets["joints/force"], a_m.datasets["joints/force"], atol=1e-6)
    assert a_mm.datasets["frames/iterations"][0] == a_m.datasets["frames/iterations"][0]


def test_inverted_pendulum_fim_s_stays_and_says_unstable(tmp_path):
    # upright pendulum (theta = 90 deg), weak spring at rest there: FIM_S stays on the unstable root
    res = solve_text(tmp_path, pendulum_deck(np.pi / 2, k=1e3, ref=np.pi / 2))
    a = res.analyses[0]
    assert a.converged
    assert abs(angle_of(res) - np.pi / 2) < 1e-9
    assert a.datasets["frames/stability"][0] == "unstable"
    assert a.datasets["frames/n_negative"][0] == 1
    d = a.datasets
    assert (d["frames/n_modes"][0], d["modes/body"][0], d["modes/kind"][0]) == (1, 2, "rotation")
    # about the hinge axis (global Z), sign-normalised: largest component positive
    np.testing.assert_allclose(d["modes/direction"][0], [0.0, 0.0, 1.0], atol=1e-9)


def test_hanging_pendulum_is_stable(tmp_path):
    res = solve_text(tmp_path, pendulum_deck(-np.pi / 2 + 0.3))
    a = res.analyses[0]
    assert a.converged and abs(angle_of(res) + np.pi / 2) < 1e-9
    assert a.datasets["frames/stability"][0] == "stable"


def test_assembly_when_input_violates_constraints(tmp_path):
    # hinge I marker 3 mm off the J marker: assembled first, then solved; answer unchanged
    res = solve_text(tmp_path, pendulum_deck(-1.2, hinge_offset=3.0))
    a = res.analyses[0]
    assert a.converged
    assert a.attrs["assembled"] is True
    assert "assembled" in a.message
    assert "assembly" in set(a.datasets["iterations/event"])
    R = a.datasets["bodies/orientation"][0, 0]
    # the pendulum hangs straight down through the hinge: the CG is directly below the J marker
    # (hinge point on the body is 3 mm from its original place along the body x axis)
    p = a.datasets["bodies/position"][0, 0]
    c, sn = np.cos(-1.2), np.sin(-1.2)
    R0 = np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]])
    s0 = R0.T @ (np.array([3.0, 0, 0]) - 200.0 * np.array([c, sn, 0]))
    hinge = p + R @ s0
    np.testing.assert_allclose(hinge, 0.0, atol=1e-8)
    assert abs(p[0]) < 1e-8 and p[1] < 0     # CG straight below the hinge


def test_redundant_fourbar_reported_and_reactions_flagged(tmp_path):
    rep = check_deck(str(DECKS / "fourbar_spring.xml"))
    assert rep.n_redundant == 3
    assert rep.dof == 1
    assert {r["tag"] for r in rep.redundant} == {"Constraint_Joint"}
    res = run_deck(str(DECKS / "fourbar_spring.xml"))
    a = res.analyses[0]
    assert a.converged
    assert a.attrs["reactions_unique"] is False
    assert len(a.datasets["redundant/equation"]) == 3
    assert not a.datasets["joints/unique"].all()
    # the minimum-norm reactions still balance each body: sum of joint forces on the chain of
    # links equals the applied loads (gravity + spring) — check the crank pivot force is finite
    assert np.all(np.isfinite(a.datasets["joints/force"]))


def test_neutral_spherical_chain_does_not_drift(tmp_path):
    res = run_deck(str(DECKS / "chain_10_spherical.xml"))
    a = res.analyses[0]
    assert a.converged
    assert a.datasets["frames/stability"][0] == "neutral"
    assert a.datasets["frames/n_zero"][0] == 10
    # neutral spins stay where they started: with R0 the input orientation and a the link axis,
    # R R0^T must be the minimal rotation taking a0 to a (no twist about the link axis)
    import lxml.etree as ET
    root = ET.parse(str(DECKS / "chain_10_spherical.xml")).getroot()
    mk = {int(e.get("id")): e for e in root.iter("Reference_Marker")}
    bodies = {int(e.get("id")): int(e.get("cg_id")) for e in root.iter("Body_Rigid")
              if e.get("isground", "FALSE").upper() != "TRUE"}
    ids = a.datasets["bodies/id"]
    for b, bid in enumerate(ids):
        e = mk[bodies[int(bid)]]
        R0 = np.array([[float(e.get(f"a{i}{j}")) for j in range(3)] for i in range(3)])
        R = a.datasets["bodies/orientation"][0, b]
        D = R @ R0.T
        a0 = R0[:, 0]
        a1 = R[:, 0]
        # twist angle about a1 of D relative to the minimal rotation a0 -> a1
        v = np.cross(a0, a1)
        s, c = np.linalg.norm(v), a0 @ a1
        K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        Rmin = np.eye(3) + K + K @ K * ((1 - c) / s**2 if s > 1e-12 else 0.5)
        twist = D @ Rmin.T
        ang = np.arccos(np.clip((np.trace(twist) - 1) / 2, -1, 1))
        assert ang < 1e-7, (bid, ang)


def test_regularisation_not_in_reported_residual(tmp_path):
    res = solve_text(tmp_path, pendulum_deck(-1.0, stability=0.01, tol=1e-8))
    a = res.analyses[0]
    assert a.converged
    assert a.datasets["frames/imbalance"][0] < 1e-8
    assert abs(angle_of(res) + np.pi / 2) < 1e-9


def test_no_gravity_code_without_force_gravity(tmp_path):
    text = pendulum_deck(0.0, k=1e4, ref=0.5).replace(
        '<Force_Gravity grav_x="0" grav_y="-9810.0" grav_z="0"/>', "")
    res = solve_text(tmp_path, text)
    assert "gravity" not in res.active_effects
    assert "Constraint_Joint:REVOLUTE" in res.active_effects
    assert abs(angle_of(res) - 0.5) < 1e-10


def test_cli_check_prints_dof_and_redundancy():
    r = subprocess.run([POISE, "check", str(DECKS / "fourbar_spring.xml")], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    out = r.stdout + r.stderr
    assert "redundant" in out.lower()
    assert "3" in out


@pytest.mark.parametrize("deck", ["pendulum_multiturn", "double_pendulum", "slider_crank_load",
                                  "bushing_block"])
def test_smooth_decks_converge_within_six_iterations(deck):
    res = run_deck(str(DECKS / f"{deck}.xml"))
    a = res.analyses[0]
    assert a.converged
    assert a.datasets["frames/iterations"][0] <= 6


def test_fallback_chain_recorded_and_switchable(tmp_path):
    deck = str(DECKS / "pendulum_multiturn.xml")
    # the chain's budget defaults to max_num_iter (2 here: not enough); it is granted explicitly
    # (units of work: Newton iterations, continuation steps, MKEAM integration steps)
    res = run_deck(deck, overrides={"max_num_iter": 2, "fallback_max_num_iter": 200})
    a = res.analyses[0]
    assert a.converged
    assert a.datasets["frames/iterations"][0] <= 2 + 200
    assert "fallback strategy" in a.message
    events = set(a.datasets["iterations/event"])
    assert any(e.startswith("fallback: stability") for e in events)
    assert any(e.startswith("fallback: continuation") for e in events)
    # same equilibrium as the plain solve
    ref = run_deck(deck).analyses[0]
    np.testing.assert_allclose(a.datasets["bodies/position"], ref.datasets["bodies/position"],
                               atol=1e-6)
    off = run_deck(deck, overrides={"max_num_iter": 2, "fallback": False}).analyses[0]
    assert not off.converged
    assert not any(e.startswith("fallback") for e in off.datasets["iterations/event"])
    r = subprocess.run([POISE, "solve", deck, "-o", str(tmp_path / "o.h5"), "--max-num-iter",
                        "2", "--no-fallback", "-q"], capture_output=True, text=True)
    assert r.returncode == 1
