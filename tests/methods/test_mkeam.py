"""MKEAM (kinetic-energy attrition) against independent references.

References are closed forms or 1-D root searches written here (never poise output):
* multi-turn pendulum with a weak spring (several equilibria): the first minimum of
  V(theta) = k/2 (theta - ref)^2 + w l sin(theta) met going downhill from theta = 0;
* inverted pendulum with a too-weak spring: the stable root of k phi = w l sin(phi); FIM_S from the
  same start stays at the (unstable) upright pose;
* hanging chain: the discrete catenary of ``tests/support/reference.py``.
History invariants: KE is zero at every restart (each iteration starts from rest), the peak KE of
an iteration never exceeds the potential drop since the previous restart (energy conservation of
the integrator) nor the total potential drop from the start.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy import optimize

from poise.app import runner

from support import reference as R
from support.paths import DECKS


W = 2.0 * 9.81          # N, weight of the 2 kg pendulum
WL = W * 200.0          # N mm


def _run(name, **over):
    t = time.perf_counter()
    res = runner.run(str(DECKS / name), overrides=over or None)
    return res, res.analyses[0], time.perf_counter() - t


def _mk_rows(ar):
    ev = ar.datasets["iterations/event"]
    return np.nonzero(ev == "mkeam")[0]


def _check_energy_history(ar):
    d = ar.datasets
    rows = _mk_rows(ar)
    ke = d["iterations/kinetic_energy"][rows]
    pe = d["iterations/potential_energy"][rows]
    pe0 = float(d["mkeam/initial_potential_energy"])
    assert np.all(np.isfinite(pe)) and np.isfinite(pe0)
    prev = np.concatenate([[pe0], pe[:-1]])
    scale = max(pe0 - pe.min(), 1e-12)
    # energy conservation within an iteration: KE at the peak = potential drop since the restart
    assert np.all(np.abs(ke - (prev - pe)) <= 5e-3 * scale + 1e-9), (ke, prev - pe)
    assert np.all(ke <= (pe0 - pe.min()) * (1 + 1e-3) + 1e-9)
    # restarts from rest: the potential only decreases from iteration to iteration
    assert np.all(np.diff(np.concatenate([[pe0], pe])) <= 1e-6 * scale)
    assert np.all(d["iterations/integrator_steps"][rows] > 0)
    n_it = len(rows)
    assert d["mkeam/iterate_position"].shape[0] == n_it + 1
    assert d["mkeam/iterate_orientation"].shape[1:] == (d["bodies/position"].shape[1], 3, 3)


def test_multiturn_pendulum_first_minimum_downhill():
    k, ref = 2000.0, 6 * math.pi + 1.0

    def dV(t):
        return k * (t - ref) + WL * math.cos(t)

    # walk downhill from theta = 0 (dV < 0 there) to the first sign change - -> +
    assert dV(0.0) < 0
    grid = np.linspace(0.0, ref + 3.0, 20001)
    vals = np.array([dV(t) for t in grid])
    i = int(np.nonzero(vals >= 0)[0][0])
    theta = optimize.brentq(dV, grid[i - 1], grid[i], xtol=1e-14)
    # several equilibria really exist (the test would be trivial otherwise)
    assert np.sum(np.diff(np.sign(vals)) != 0) >= 3
    res, ar, wall = _run("mkeam_pendulum_multiturn.xml")
    assert ar.status == "converged", ar.message
    assert ar.method == "MKEAM"
    cg = ar.datasets["bodies/position"][0, 0]
    ref_cg = 200.0 * np.array([math.cos(theta), math.sin(theta), 0.0])
    assert np.abs(cg - ref_cg).max() < 1e-6 * 400
    R_ = ar.datasets["bodies/orientation"][0, 0]
    assert np.abs(R_ - R.rot_z(theta)).max() < 1e-6
    _check_energy_history(ar)
    assert len(_mk_rows(ar)) <= 5
    print(f"multi-turn pendulum: {len(_mk_rows(ar))} MKEAM iterations, "
          f"solve {res.timings['solve']:.2f} s, turns {theta / 2 / math.pi:.3f}")


def test_inverted_pendulum_falls_with_mkeam_fim_stays_upright():
    k = 2000.0
    phi = optimize.brentq(lambda p: k * p - WL * math.sin(p), 0.5, math.pi)
    res, ar, _ = _run("mkeam_inverted_pendulum.xml")
    assert ar.status == "converged", ar.message
    cg = ar.datasets["bodies/position"][0, 0]
    ref = 200.0 * np.array([-math.sin(phi), math.cos(phi), 0.0])
    assert np.abs(cg - ref).max() < 1e-6 * 400
    _check_energy_history(ar)
    res2, ar2, _ = _run("mkeam_inverted_pendulum.xml", method="FIM_S")
    assert ar2.status == "converged"
    assert np.abs(ar2.datasets["bodies/position"][0, 0] - [0.0, 200.0, 0.0]).max() < 1e-6 * 400


def _chain_check(name, n, tol):
    ref = R.catenary(n)
    res, ar, wall = _run(name)
    assert ar.status == "converged", ar.message
    pos = ar.datasets["bodies/position"][0]
    assert np.abs(pos - ref["cg"]).max() < tol * n * 100.0
    _check_energy_history(ar)
    return res, ar


def test_chain_10_catenary():
    res, ar = _chain_check_override("chain_10.xml", 10)
    assert "Newton-polished" in ar.message


def _chain_check_override(name, n):
    ref = R.catenary(n)
    res = runner.run(str(DECKS / name), overrides=dict(method="MKEAM", max_ke_tol=1e-3,
                                                        max_num_iter=300))
    ar = res.analyses[0]
    assert ar.status == "converged", ar.message
    pos = ar.datasets["bodies/position"][0]
    assert np.abs(pos - ref["cg"]).max() < 1e-6 * n * 100.0
    _check_energy_history(ar)
    return res, ar


@pytest.mark.slow
def test_chain_20_catenary():
    res, ar = _chain_check("mkeam_chain_20.xml", 20, 1e-6)
    print(f"chain 20: {len(_mk_rows(ar))} MKEAM iterations, solve {res.timings['solve']:.2f} s")


def test_unstable_start_is_perturbed():
    """Exactly upright (no force acts): MKEAM must not stop at the unstable equilibrium."""
    from support.builders import DeckBuilder
    d = DeckBuilder().ground()
    d.add("Param_Unit", force_unit="NEWTON", mass_unit="KILOGRAM", length_unit="MILLIMETER",
          time_unit="SECOND")
    d.add("Force_Gravity", grav_x=0.0, grav_y=-9810.0, grav_z=0.0)
    d.body(2, 200, (0.0, 200.0, 0.0), R.rot_z(math.pi / 2), mass=2.0,
           inertia=(25.0, 26679.2, 26679.2))
    d.marker(201, 2, (0, 0, 0))
    d.marker(101, 1, (0, 0, 0))
    d.add("Constraint_Joint", id=1, type="REVOLUTE", i_marker_id=201, j_marker_id=101)
    d.add("Force_SpringDamper", id=1, type="ROTATIONAL", i_marker_id=201, j_marker_id=101,
          stiffness=2000.0, damping=0.0, length=0.0, preload=0.0)
    from poise.model.compile import compile_model
    from poise.solvers.settings import StaticSettings
    from poise.app.runner import AnalysisRequest
    from poise.solvers.driver import Driver
    m = compile_model(d.spec)
    s = StaticSettings().updated(dict(method="MKEAM", max_imbalance=1e-8, max_error=1e-8))
    an = Driver(m, AnalysisRequest(simulate=None, kind="static", settings=s))
    st, ar = an.run(m.initial_state())
    assert ar.status == "converged", ar.message
    phi = optimize.brentq(lambda p: 2000.0 * p - WL * math.sin(p), 0.5, math.pi)
    c = st.pos[0]
    assert abs(math.hypot(c[0], c[1]) - 200.0) < 1e-6
    assert abs(abs(math.atan2(-c[0], c[1])) - phi) < 1e-6


def test_tight_tolerances_are_reachable(tmp_path):
    """max_dq_tol = 1e-10: the rotation change between restart points is measured with atan2
    (arccos has a floor of ~1.5e-8 rad), so a tight tolerance converges instead of running to
    max_num_iter at the exact answer."""
    import re

    from poise.app.api import run_deck
    src = DECKS / "bench" / "pendulum_multiturn.xml"
    xml = re.sub(r"<Param_Static[^>]*/>",
                 '<Param_Static method="MKEAM" max_ke_tol="1.0E-10" max_dq_tol="1.0E-10" '
                 'max_imbalance="1.0E-10" max_error="1.0E-10" max_num_iter="40"/>',
                 src.read_text())
    deck = tmp_path / "pm.xml"
    deck.write_text(xml)
    res = run_deck(str(deck))
    a = res.analyses[0]
    assert a.status == "converged"
    assert int(a.datasets["frames/iterations"][0]) <= 5
    fs = run_deck(str(src)).analyses[0]           # FIM_S on the same deck: the same pose
    assert np.allclose(a.datasets["bodies/position"], fs.datasets["bodies/position"], atol=1e-6)
