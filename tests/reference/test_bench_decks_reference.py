"""Every deck in ``decks/bench`` solved as a user would (``run_deck`` at the deck's own
settings) matches its independent reference (``tests/support/reference.py``: closed forms, virtual
work, the discrete catenary) — the same references the work-precision benchmark measures
errors against."""
from __future__ import annotations

import pytest

from poise.app.api import run_deck
from benchmarks import wp
from benchmarks.decks import BENCH_DIR

CASES = [pytest.param(name, spec[0], spec[3], id=name) for name, spec in wp.DECKS.items()]
CASES.append(pytest.param("slider_crank_qs_1000", "slider_crank_qs_1000.xml", wp._ref_slider_qs,
                          id="slider_crank_qs_1000", marks=pytest.mark.slow))   # ~6 s


@pytest.mark.parametrize("name,file,ref_fn", CASES)
def test_bench_deck_matches_reference(name, file, ref_fn):
    res = run_deck(str(BENCH_DIR / file))
    assert res.exit_code == 0, [a.message for a in res.analyses]
    assert all(a.status == "converged" for a in res.analyses)
    err = wp.deck_error(res, ref_fn, wp._reference_module())
    assert err < 1e-6, f"{name}: CG error / L = {err:.2e}"
    if name.startswith("slider_crank_qs"):
        frames = res.analyses[0].datasets["bodies/position"].shape[0]
        assert frames == (1001 if name.endswith("1000") else 101)
