"""Decks that cannot converge fail fast, with a reason, within a budget counted in work.

* A load larger than the model can hold anywhere along a full turn (a pendulum under 1.5 m g l,
  a crank torque no slider load position balances): ``diverged``, "no equilibrium within
  reach", the body and its turns named, in a few dozen Newton iterations and without the
  fallback chain (continuation and MKEAM would only descend the same way).
* The fallback chain's budget counts MKEAM's integration steps (``--fallback-budget`` bounds
  the time of a frame): the integrator steps taken never exceed the MKEAM share, and the frame's
  ``iterations`` include them.
No timings are asserted (``make bench`` has the time-to-fail table); counts are.
"""
import json
import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np

from poise.app.api import run_deck
from poise.gen.torque import torque_pendulum
from poise.solvers.history import STRATEGIES

from support.paths import DECKS

POISE = str(Path(sys.executable).parent / "poise")
G = 9.81


def pendulum(frac):
    """A 2 kg bar hinged 200 mm from its CG under gravity and a constant torque frac x m g l
    (no equilibrium above 1)."""
    return torque_pendulum(frac)


def crank_torque(torque):
    """decks/slider_crank_load.xml with its torsion spring replaced by a constant crank torque
    [N mm]: the 60 N slider load holds at most 60 N x max|dx/dphi| (about 105 mm)."""
    text = (DECKS / "slider_crank_load.xml").read_text()
    return re.sub(r'<Force_SpringDamper id="1".*?/>',
                  '<Force_Vector_OneBody id="2" type="TORQUEONLY" marker_id="200" '
                  'ref_marker_id="100" fx_expression="0." fy_expression="0." fz_expression="0." '
                  f'tx_expression="0." ty_expression="0." tz_expression="{torque!r}"/>', text,
                  flags=re.S)


def runaway(a, body):
    assert not a.converged
    assert a.datasets["frames/status"][0] == "diverged"
    assert a.message.startswith("no equilibrium within reach")
    assert f"<Body_Rigid id={body}> turned" in a.message
    assert "the fallback chain was not tried" in a.message
    assert "try MKEAM" not in a.message
    assert set(a.datasets["iterations/strategy"]) == {"plain"}
    m = re.search(r"turned ([0-9.]+) turns", a.message)
    assert 1.0 <= float(m.group(1)) < 2.0


def test_a_torque_beyond_m_g_l_is_a_runaway(tmp_path):
    a = run_deck(pendulum(1.5).write(tmp_path / "p.xml")).analyses[0]
    runaway(a, 2)
    # the potential fell by at least the torque's work over the turn less gravity's (zero over
    # a whole turn): T x 2 pi
    m = re.search(r"it fell by ([0-9.e+]+) N\*mm", a.message)
    assert float(m.group(1)) >= 0.95 * 1.5 * 2.0 * G * 200.0 * 2 * np.pi
    assert a.datasets["frames/iterations"][0] <= 40
    # the healthy counterpart converges where cos(theta) = 0.5 (stable root)
    ok = run_deck(pendulum(0.5).write(tmp_path / "ok.xml")).analyses[0]
    assert ok.converged, ok.message
    R = ok.datasets["bodies/orientation"][0, 0]
    assert abs(np.cos(np.arctan2(R[1, 0], R[0, 0])) - 0.5) < 1e-9


def test_a_crank_torque_no_load_position_balances(tmp_path):
    p = tmp_path / "sc.xml"
    p.write_text(crank_torque(10000.0))
    out = tmp_path / "sc.h5"
    r = subprocess.run([POISE, "solve", str(p), "-o", str(out), "--json", "-q"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    js = json.loads(r.stdout)
    assert js["analyses"][0]["message"].startswith("no equilibrium within reach")
    assert "<Body_Rigid id=2> turned" in js["analyses"][0]["message"]
    with h5py.File(out, "r") as f:                       # the results file is written
        assert f["analysis_000/frames/status"].asstr()[0] == "diverged"
        assert int(f["analysis_000/frames/iterations"][0]) <= 100    # plain Newton only
    p2 = tmp_path / "sc_ok.xml"
    p2.write_text(crank_torque(3000.0))
    assert run_deck(str(p2)).analyses[0].converged


def test_mkeam_integration_steps_count_against_the_fallback_budget(tmp_path, monkeypatch):
    """The multi-turn pendulum after 2 plain iterations, chain budget 60: every RATTLE step
    MKEAM takes is counted in its share, and the frame never costs more than 2 + 60."""
    from poise.solvers import ke_peak
    steps = []
    orig = ke_peak.rattle_step

    def counted(dyn, a, h):
        steps.append(h)
        return orig(dyn, a, h)
    monkeypatch.setattr(ke_peak, "rattle_step", counted)
    a = run_deck(str(DECKS / "pendulum_multiturn.xml"),
                 overrides={"max_num_iter": 2, "fallback_max_num_iter": 60}).analyses[0]
    it = a.datasets["frames/strategy_iterations"][0]
    mk = int(it[STRATEGIES.index("mkeam")])
    assert steps, "the chain reached MKEAM"
    assert len(steps) <= mk                      # every integration step counted
    assert int(a.datasets["frames/iterations"][0]) == int(it.sum()) <= 2 + 60
