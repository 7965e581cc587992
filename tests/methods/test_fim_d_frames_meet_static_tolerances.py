"""Every FIM_D frame a results file calls converged meets the ``Param_Static`` tolerances.

IDA's output points satisfy IDA's local error test, not ``max_imbalance``: they are corrected
onto the equilibrium (``fim_d.Corrector``) and each frame records what it met. References are
closed forms (the pendulum under a ramped side load: ``tan(theta) = F / (m g)``) or the
slider-crank's virtual-work equilibrium of ``tests/support/reference.py``, never poise output.
"""
from __future__ import annotations


import numpy as np
import pytest

from poise.app.api import run_deck

from support.paths import ROOT


def _pendulum_deck(tmp_path, interpolate=True, dae_tol=1e-6):
    xml = (ROOT / "decks" / "qs_pendulum_ramp.xml").read_text()
    assert 'max_imbalance="1.0E-9" max_error="1.0E-9"' in xml
    tr = f'<Param_Transient dae_constr_tol="{dae_tol!r}"'
    if not interpolate:
        tr += ' dae_interpolation="FALSE"'
    xml = xml.replace('<Param_Transient dae_constr_tol="1.0E-6"', tr)
    p = tmp_path / "pendulum_ramp.xml"
    p.write_text(xml)
    return p


@pytest.mark.parametrize("interpolate", [True, False], ids=["interpolated", "tstop"])
def test_pendulum_ramp_every_frame_meets_max_imbalance(tmp_path, interpolate):
    """1 kg bob 1 m below a Z hinge, side load 20 t N: tan(theta) = 20 t / 9.81, bob at
    (sin theta, -cos theta). IDA runs at 1e-6 (its points are ~1e-7 off); every frame must
    meet max_imbalance = max_error = 1e-9 and sit on the closed form to that accuracy."""
    res = run_deck(str(_pendulum_deck(tmp_path, interpolate)), overrides=dict(method="FIM_D"))
    a = res.analyses[0]
    assert res.exit_code == 0 and a.status == "converged", a.message
    assert a.method == "FIM_D"
    d = a.datasets
    t = d["time"]
    assert len(t) == 101
    assert np.all(d["frames/converged"])
    assert np.all(d["frames/status"] == "converged")
    assert np.all(d["frames/imbalance"] <= 1e-9)
    assert np.all(d["frames/error"] <= 1e-9)
    theta = np.arctan2(20.0 * t, 9.81)
    bob = np.stack([np.sin(theta), -np.cos(theta), 0 * t], axis=1)
    assert np.abs(d["bodies/position"][:, 0] - bob).max() < 1e-8
    # the interpolated points were corrected (iterations recorded per frame), not re-solved
    assert np.sum(d["frames/iterations"][1:-1] >= 1) > 50
    assert int(a.attrs["correction_newton"]) == 0
    ev = d["iterations/event"]
    rows = np.nonzero(ev == "ida")[0]
    assert len(rows) == 99
    assert np.all(d["iterations/imbalance"][rows] <= 1e-9)


def test_loose_ida_tolerance_still_gives_tight_frames(tmp_path):
    """dae_constr_tol 1e-3: IDA's points are far off (mm), the frames still meet 1e-9."""
    res = run_deck(str(_pendulum_deck(tmp_path, dae_tol=1e-3)), overrides=dict(method="FIM_D"))
    a = res.analyses[0]
    assert a.status == "converged", a.message
    d = a.datasets
    assert np.all(d["frames/converged"]) and np.all(d["frames/imbalance"] <= 1e-9)
    theta = np.arctan2(20.0 * d["time"], 9.81)
    assert np.abs(d["bodies/position"][:, 0, 0] - np.sin(theta)).max() < 1e-8


@pytest.mark.slow
def test_slider_crank_1000_frames_all_meet_tolerances():
    """The benchmark deck (1001 frames, max_imbalance = max_error = 1e-8) with FIM_D: every
    frame meets the FIM_S scales (force rows 1e-8 N, moment rows 1e-8 * L N mm, constraints
    1e-8 (x L)) and matches the virtual-work reference to 1e-6 L."""
    from support import reference as R
    res = run_deck(str(ROOT / "decks" / "bench" / "slider_crank_qs_1000.xml"),
                   overrides=dict(method="FIM_D"))
    a = res.analyses[0]
    assert a.status == "converged", a.message
    d = a.datasets
    L = float(res.model_datasets["length_scale"])
    assert np.all(d["frames/converged"])
    assert np.all(d["frames/imbalance"] <= 1e-8 * L)
    assert np.all(d["frames/error"] <= 1e-8)
    ids = list(d["bodies/id"])
    for k in range(0, len(d["time"]), 50):
        cg = R.slider_crank(dict(R.SLIDER_CRANK_PARAMS, fx=-60.0 * float(d["time"][k])))["cg"]
        for b, name in ((2, "crank"), (3, "rod"), (4, "slider")):
            assert np.abs(d["bodies/position"][k, ids.index(b)] - cg[name]).max() < 1e-6 * L


def test_frames_the_correction_cannot_finish_get_a_full_newton(tmp_path, monkeypatch):
    """No correction allowed (``correct_max_iter`` = 0): every IDA point off the tolerances goes
    through a full Newton (event ``ida_newton``), and the frames still meet 1e-9 at the closed
    form."""
    from dataclasses import replace

    from poise.solvers.limits import LIMITS
    from poise.solvers.settings import StaticSettings
    monkeypatch.setattr(StaticSettings, "limits", replace(LIMITS, correct_max_iter=0))
    res = run_deck(str(_pendulum_deck(tmp_path)), overrides=dict(method="FIM_D"))
    a = res.analyses[0]
    assert a.status == "converged", a.message
    d = a.datasets
    assert int(a.attrs["correction_newton"]) > 50
    assert np.sum(d["iterations/event"] == "ida_newton") > 50
    assert np.all(d["frames/converged"]) and np.all(d["frames/imbalance"] <= 1e-9)
    theta = np.arctan2(20.0 * d["time"], 9.81)
    assert np.abs(d["bodies/position"][:, 0, 0] - np.sin(theta)).max() < 1e-8
