"""Frame recovery (plain Newton + fallback chain) in every analysis, within the user's budget.

* ``max_num_iter`` binds plain Newton; the fallback chain has its own budget
  (``fallback_max_num_iter``, CLI ``--fallback-budget``, default ``max_num_iter``); a frame's
  ``frames/iterations`` counts all its work, split by strategy in ``frames/strategy_iterations``
  and the history's ``iterations/strategy``.
* Quasi-static frames (FIM_S and FIM_D) get the same recovery as a static solve.
* Expected values: the pendulum's equilibrium from a 1-DOF scipy solve written here.
"""
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from poise.app.api import run_deck
from poise.solvers.history import STRATEGIES

from support.paths import DECKS


POISE = str(Path(sys.executable).parent / "poise")
PENDULUM = DECKS / "pendulum_multiturn.xml"
# the chain's budget in units of work (Newton iterations, continuation steps, MKEAM integration
# and descent steps): what the multi-turn pendulum needs after 2 plain iterations
CHAIN = 200


def pendulum_theta():
    """Equilibrium angle of decks/pendulum_multiturn.xml (2 kg, CG at 200 mm, k = 20000 N mm/rad,
    reference 19.84955592153876 rad, g = 9810 mm/s^2 along -Y, so m g = 19.62 N in N-kg-mm-s):
    k (ref - th) = m g l cos(th)."""
    m, g, l, k, ref = 2.0, 9.81, 200.0, 20000.0, 19.84955592153876
    def f(th):
        return k * (ref - th) - m * g * l * np.cos(th)
    return brentq(f, ref - 0.5, ref + 0.5)


def check_pendulum(a, k=0):
    th = pendulum_theta()
    cg = a.datasets["bodies/position"][k, 0]
    assert np.allclose(cg[:2], 200.0 * np.array([np.cos(th), np.sin(th)]), atol=1e-6)


def check_counts(a):
    d = a.datasets
    it = d["frames/strategy_iterations"]
    assert it.shape == (len(d["frames/iterations"]), len(STRATEGIES))
    np.testing.assert_array_equal(it.sum(axis=1), d["frames/iterations"])
    assert a.attrs["iterations_total"] == int(np.sum(d["frames/iterations"]))
    for j, name in enumerate(STRATEGIES):
        assert a.attrs[f"iterations_{name}"] == int(it[:, j].sum())
    assert len(d["iterations/strategy"]) == len(d["iterations/event"])
    assert set(d["iterations/strategy"]) <= set(STRATEGIES)


def test_max_num_iter_binds_the_whole_frame():
    """--max-num-iter 2: plain Newton gets 2, the chain 2 more (its default budget), then the
    frame fails; it no longer reports 'converged in 0 iterations' after hundreds."""
    a = run_deck(str(PENDULUM), overrides={"max_num_iter": 2}).analyses[0]
    assert not a.converged
    assert a.datasets["frames/status"][0] == "max_iterations"
    n = int(a.datasets["frames/iterations"][0])
    assert 2 < n <= 4
    check_counts(a)
    it = a.datasets["frames/strategy_iterations"][0]
    assert it[STRATEGIES.index("plain")] == 2
    assert "fallback chain" in a.message and "of its 2 units of work" in a.message


def test_fallback_budget_grants_the_chain_more_and_counts_every_strategy():
    a = run_deck(str(PENDULUM), overrides={"max_num_iter": 2,
                                           "fallback_max_num_iter": CHAIN}).analyses[0]
    assert a.converged, a.message
    check_pendulum(a)
    check_counts(a)
    n = int(a.datasets["frames/iterations"][0])
    assert 2 < n <= 2 + CHAIN
    strategy = a.datasets["frames/strategy"][0]
    assert strategy in STRATEGIES[1:-1] and f"'{strategy}'" in a.message
    # every recovery row is labelled with its stage; the plain rows come first
    st = list(a.datasets["iterations/strategy"])
    ev = list(a.datasets["iterations/event"])
    assert st[0] == "plain" and ev[0] == "newton"
    assert any(s == strategy for s in st)
    # the history's Newton/continuation rows agree with the split
    it = a.datasets["frames/strategy_iterations"][0]
    n_cont = sum(1 for e in ev if e.startswith("continuation mu="))
    assert it[STRATEGIES.index("continuation")] <= n_cont <= 2 * it[STRATEGIES.index("continuation")]


def test_cli_fallback_budget_option(tmp_path):
    out = tmp_path / "o.h5"
    r = subprocess.run([POISE, "solve", str(PENDULUM), "-o", str(out), "--max-num-iter", "2",
                        "--fallback-budget", str(CHAIN), "--json"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    js = json.loads(r.stdout)
    assert 2 < js["analyses"][0]["iterations"] <= 2 + CHAIN
    r = subprocess.run([POISE, "solve", str(PENDULUM), "-o", str(out), "--max-num-iter", "2",
                        "--fallback-budget", "0", "--json"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1, r.stderr
    js = json.loads(r.stdout)
    assert js["analyses"][0]["iterations"] == 2
    import h5py
    with h5py.File(out, "r") as f:
        g = f["analysis_000"]
        assert [s.decode() if isinstance(s, bytes) else s
                for s in g["iterations/strategy"][()]] == ["plain"] * 3


def quasistatic_pendulum(tmp_path, method):
    """The multi-turn pendulum as a quasi-static run (nothing depends on time: frame 0 is the
    whole solve): plain Newton cannot reach it in 2 iterations, the recovery must."""
    text = PENDULUM.read_text().replace(
        '<Simulate analysis_type="Static"/>',
        '<Simulate analysis_type="Static" end_time="1.0" num_steps="2"/>').replace(
        'method="FIM_S"', f'method="{method}"')
    p = tmp_path / f"qs_{method}.xml"
    p.write_text(text)
    return str(p)


@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_quasistatic_frame_zero_gets_the_recovery(tmp_path, method):
    deck = quasistatic_pendulum(tmp_path, method)
    a = run_deck(deck, overrides={"max_num_iter": 2, "fallback_max_num_iter": CHAIN}).analyses[0]
    assert a.analysis_type == "quasistatic"
    assert a.converged, a.message
    for k in range(3):
        check_pendulum(a, k)
    assert a.datasets["frames/strategy"][0] != "plain"
    assert "frame 0" in a.message and "fallback strategy" in a.message
    check_counts(a)
    off = run_deck(deck, overrides={"max_num_iter": 2, "fallback": False}).analyses[0]
    assert not off.converged


@dataclass(frozen=True)
class Counted:
    n: int
    it: int = 0


def test_the_loop_appends_every_row_and_owns_the_budget():
    """``iterate`` appends each step's rows, then the closing rows, and stops at the budget;
    a ``History.stage`` view labels the rows recorded through it."""
    from poise.solvers.history import History, Row
    from dataclasses import replace

    from poise.solvers.iterate import Next, Solver, iterate
    from poise.solvers.status import Status

    class Count(Solver):
        out_of_budget = Status.STEP_TOO_SMALL

        def init(self, n):
            return Counted(n)

        def terminate(self, s):
            return (True, Status.CONVERGED) if s.n == 0 else (False, None)

        def step(self, s, left):
            return Next(replace(s, n=s.n - 1, it=s.it + 1), 1, (Row(0, s.it, event="step"),))

        def close(self, s, status, used):
            return (Row(0, used, event="close"),)

        def postprocess(self, s, status, used):
            return used, "" if status is Status.CONVERGED else "budget"

    h = History()
    assert iterate(Count(), 10, h, 3) == (3, "")
    assert iterate(Count(), 2, h.stage("continuation"), 5) == (2, "budget")
    d = h.columns()
    assert list(d["event"]) == ["step"] * 3 + ["close"] + ["step"] * 2 + ["close"]
    assert list(d["iteration"]) == [0, 1, 2, 3, 0, 1, 2]
    assert list(d["strategy"]) == ["plain"] * 4 + ["continuation"] * 3


def test_solve_data_counts_every_evaluation_and_factorisation():
    """``SolveData.evaluate`` / ``jacobian`` / ``factor`` are the counted entry points."""
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    from poise.solvers.data import SolveData

    model = compile_model(load_deck(PENDULUM))
    st = model.initial_state()
    d = SolveData.for_model(model)
    ev = d.evaluate(model, st, "defer")
    assert d.as_dict() == {"residuals": 1, "jacobians": 0, "factorizations": 0}
    d.factor(d.jacobian(model, ev))
    d.jacobian(model, ev)                                    # assembled once, counted once
    assert d.as_dict() == {"residuals": 1, "jacobians": 1, "factorizations": 1}
    d.evaluate(model, st, "jacobian", residual=False)        # IDA's Jacobian callback
    d.evaluate(model, [st, st, st], "residual")              # three frames
    d.evaluate(model, st, "phi")
    assert d.as_dict() == {"residuals": 5, "jacobians": 2, "factorizations": 1}
    assert d.factor(np.eye(2), lambda J: "mine", count=3) == "mine"
    assert d.factorizations == 4
