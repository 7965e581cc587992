"""The reported frame error bounds the true error (independent references, never poise's own
output): a soft block whose load reverses (an SHF turning point) at the default tolerances,
where a predicted point within ``max_imbalance`` can be 0.1 mm from the equilibrium, and the
quasi-static slider-crank bench deck against its virtual-work reference per frame."""
from __future__ import annotations

import numpy as np
import pytest

from poise.app.api import run_deck
from poise.deck.parser import load_deck
from poise.model.compile import compile_model

from benchmarks import wp
from benchmarks.decks import BENCH_DIR
from support.linkages import shf_block, shf_reversal

METHODS = ["FIM_S", "FIM_D"]
ROUNDOFF = 1e-12          # errors are relative to the model size: below this, round-off


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("interval", [0.02, 0.05])
def test_reported_error_bounds_the_true_error_at_a_reversal(tmp_path, method, interval):
    path = shf_reversal(method, interval).write(tmp_path / "shf.xml")
    a = run_deck(path).analyses[0]
    assert a.status == "converged", a.message
    L = compile_model(load_deck(path)).L
    t = np.asarray(a.datasets["time"])
    x = np.asarray(a.datasets["bodies/position"])[:, 0, 0]
    true = np.abs(x - shf_block(t)) / L
    reported = np.asarray(a.datasets["frames/error"])
    assert np.all(true <= reported + ROUNDOFF), (t[np.argmax(true - reported)],
                                                 float(np.max(true - reported)))
    assert np.all(reported <= 1e-4)                      # and the frames meet max_error


def test_bench_quasistatic_frames_bound_their_error():
    """decks/bench/slider_crank_qs.xml at its own settings and at the default tolerances: the
    reported error of every frame bounds the CG error against the virtual-work reference."""
    ref_mod = wp._reference_module()
    path = str(BENCH_DIR / "slider_crank_qs.xml")
    for method in METHODS:
        for over in ({}, {"max_imbalance": 1e-4, "max_error": 1e-4}):
            res = run_deck(path, overrides=dict(method=method, **over))
            a = res.analyses[0]
            assert a.status == "converged", a.message
            d = a.datasets
            ids = list(np.asarray(d["bodies/id"]).astype(int))
            pos = np.asarray(d["bodies/position"])
            want = wp._ref_slider_qs(ref_mod, np.asarray(d["time"]))
            L = float(res.model_datasets["length_scale"])
            true = np.max([np.linalg.norm(pos[:, ids.index(b)] - xr, axis=1)
                           for b, xr in want.items()], axis=0) / L
            reported = np.asarray(a.datasets["frames/error"])
            assert np.all(true <= reported + ROUNDOFF), (method, over, float(np.max(true)))
