"""The compiled model is read-only: solves keep their data (active rows, counters) apart.

Every array of every compiled model is snapshotted right after compile and compared after the
run (static FIM_S with redundant rows, MKEAM, quasi-static FIM_S and FIM_D); writes to a
compiled model fail.
"""
from __future__ import annotations


import numpy as np
import pytest

import poise.app.runner as runner_mod
import poise.model.compile as compile_mod
from poise.app.api import run_deck

from support.paths import DECKS


def _snapshot(model) -> dict:
    return {k: np.array(v, copy=True) for k, v in vars(model).items()
            if isinstance(v, np.ndarray)}


@pytest.mark.parametrize("deck, overrides", [
    ("chain_10.xml", None),                                  # redundant rows removed
    ("chain_10.xml", {"method": "MKEAM"}),
    ("qs_pendulum_ramp.xml", None),
    ("elem_cvcv_cam_qs.xml", None),                          # FIM_D
])
def test_solve_leaves_the_model_unchanged(deck, overrides, monkeypatch):
    compiled = []
    real = compile_mod.compile_model

    def spy(*a, **k):
        m = real(*a, **k)
        compiled.append((m, _snapshot(m), set(vars(m))))
        return m

    monkeypatch.setattr(compile_mod, "compile_model", spy)
    monkeypatch.setattr(runner_mod, "compile_model", spy)
    res = run_deck(str(DECKS / deck), overrides, quiet=True)
    assert res.analyses and compiled
    for m, snap, names in compiled:
        assert not hasattr(m, "row_active")
        assert {n for n in vars(m) if not n.startswith("_")} == \
            {n for n in names if not n.startswith("_")}
        for k, v in snap.items():
            np.testing.assert_array_equal(getattr(m, k), v, err_msg=k)


def test_writes_to_a_compiled_model_fail():
    from poise.deck.parser import load_deck
    m = compile_mod.compile_model(load_deck(str(DECKS / "chain_10.xml")))
    with pytest.raises(AttributeError, match="read-only"):
        m.L = 2.0
    with pytest.raises(ValueError):
        m.body_mass[0] = 1.0
