"""The floor table's least cost of a certified solve (benchmarks.floor): its arithmetic and its
parts measured on a small sparse chain (no timing assertions)."""
from __future__ import annotations

import math
import sys

import pytest

from support.paths import ROOT

sys.path.insert(0, str(ROOT))
floor = pytest.importorskip("benchmarks.floor")


def _st(x):
    return dict(median=x, min=x, max=x, n=1)


def test_least_counts_each_part_in_newtons_lus():
    row = dict(n=1000, iterations=5, newton_lu_cpu_s=_st(0.004), solve_cpu_s=_st(0.08),
               verdict_parts=dict(jac=_st(0.002), res=_st(0.001), solve=_st(0.0004),
                                  ldl=_st(0.008), ldl_solve=_st(0.0006), ldl_ok=True))
    # 3 LUs + (3 x 2 + 3 x 1 + 5 x 0.4 + 1 x 8 + 5 x 0.6) ms / 4 ms
    assert floor.least(row) == pytest.approx(3 + (6 + 3 + 2 + 8 + 3) / 4)
    md = "\n".join(floor._least([row]))
    assert "| 1000 |" in md and "**8.5**" in md and "| 10 | 1.5 |" in md
    assert floor.least(dict(row, verdict_parts=None)) is None


def test_verdict_parts_on_a_sparse_chain(tmp_path):
    from poise.app.runner import plan
    from poise.deck.parser import load_deck
    from poise.gen.chain import build_chain_deck
    from poise.model.compile import compile_model
    from poise.solvers.driver import Driver

    deck = tmp_path / "chain_200.xml"
    deck.write_text(build_chain_deck(200, "revolute"))
    spec = load_deck(deck)
    model = compile_model(spec)
    req = plan(spec, None)[0]
    drv = Driver(model, req, redundancy=None)
    state, _ = drv.run(model.initial_state(), index=0)
    parts = floor.verdict_parts(model, state, req.settings, drv.data.active, repeat=1)
    assert parts["ldl_ok"] is True                  # the inertia's LDL^T at the solution is valid
    for k in ("jac", "res", "solve", "ldl", "ldl_solve"):
        assert math.isfinite(parts[k]) and parts[k] >= 0.0
