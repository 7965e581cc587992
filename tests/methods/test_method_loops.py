"""The method internals on the one loop (issue 24 §1): MKEAM's iterations, its KE iteration and
the stable descent are Solvers with frozen states and a pure terminate; the loop appends their
rows and turns a spent budget into the declared status. References: the closed-form rest pose
of the inverted pendulum (k phi = m g l sin phi), independent of the solver."""
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from poise.deck.parser import load_deck
from poise.model.compile import compile_model
from poise.solvers.data import SolveData
from poise.solvers.descent import Descent
from poise.solvers.iterate import iterate
from poise.solvers.ke_peak import KeIteration
from poise.solvers.newton import initial_multipliers
from poise.solvers.relaxation import Relaxation
from poise.solvers.settings import StaticSettings
from poise.solvers.status import Status
from support.loops import assert_frozen_and_pure
from support.paths import DECKS

K, MGL, L_CG = 2000.0, 2.0 * 9.81 * 200.0, 200.0    # N mm/rad, N mm (kg mm/s^2 = mN), mm


@pytest.fixture(scope="module")
def pendulum():
    model = compile_model(load_deck(DECKS / "mkeam_inverted_pendulum.xml"))
    settings = replace(StaticSettings(), max_ke_tol=1e-5, max_dq_tol=1e-3, max_num_iter=100)
    return model, settings


def _start(model):
    data = SolveData.for_model(model)
    data.set_redundancy(np.zeros(0, int))
    return data, initial_multipliers(model, model.initial_state(), data)


def test_mkeam_iterations_reach_the_closed_form_rest_with_rows_from_the_loop(pendulum):
    model, settings = pendulum
    data, st = _start(model)
    rows = []
    rx = Relaxation(model, settings, rows, data)
    assert_frozen_and_pure(rx, rx.init(st), data)
    mk, status, msg, n = rx.run(st)
    assert status is Status.CONVERGED, msg
    mkeam_rows = [r for r in rows if r.event == "mkeam"]
    assert [r.iteration for r in mkeam_rows] == list(range(1, n + 1))
    assert all(r.mkeam is not None and r.mkeam[4] > 0 for r in mkeam_rows)
    assert len(rx.iterates) == n + 1 and rx.used >= sum(r.mkeam[4] for r in mkeam_rows)
    # rest pose: k phi = m g l sin(phi), the bar fallen from upright (tilt phi from +Y)
    phi = brentq(lambda p: K * p - MGL * np.sin(p), 0.5, 3.0)
    cg = mk.pos[0]
    tilt = np.arctan2(abs(cg[0]), cg[1])
    assert np.hypot(cg[0], cg[1]) == pytest.approx(L_CG, rel=1e-6)
    assert tilt == pytest.approx(phi, abs=5e-3)      # MKEAM's point (max_dq_tol 1e-3)


def test_mkeam_budgets_become_statuses(pendulum):
    model, settings = pendulum
    data, st = _start(model)
    rows = []
    rx = Relaxation(model, settings, rows, data)
    mk, status, msg, n = iterate(rx, 0, rows, st)      # no iteration allowed
    assert status is Status.MAX_ITERATIONS and "max_num_iter" in msg and not rows
    assert np.array_equal(mk.pos, st.pos)
    data, st = _start(model)
    rx = Relaxation(model, settings, [], data, units=3)
    mk, status, msg, n = rx.run(st)
    assert status is Status.MAX_ITERATIONS and "integration budget (3 steps)" in msg
    assert rx.used <= 3 + settings.max_num_iter    # the hand-over's steps counted too


def test_ke_iteration_spends_its_budget_in_integrator_steps(pendulum):
    model, settings = pendulum
    data, st = _start(model)
    dyn = Relaxation(model, settings, [], data).dyn
    solver = KeIteration(dyn, st.pos.copy())
    assert_frozen_and_pure(solver, solver.init(st, np.inf), data)
    land = iterate(solver, 3, [], st, np.inf)
    assert land.steps == 3 and land.status is Status.MAX_ITERATIONS and not land.failed
    full = iterate(KeIteration(dyn, st.pos.copy()), 1000, [], st, np.inf)
    assert full.status is Status.CONVERGED and full.steps > 3
    assert full.point.ke > land.point.ke > 0.0       # accelerating from rest, up to the peak


def test_descent_state_frozen_and_its_rows_appended_by_the_loop(pendulum):
    model, settings = pendulum
    data, st = _start(model)
    solver = Descent(model, settings, 0, data)
    assert_frozen_and_pure(solver, solver.init(st, None), data)
    rows = []
    end = iterate(solver, 40, rows, st, None)
    assert end.stop in ("polished", "equilibrium") and end.pe < solver.init(st, None).pe
    its = [r.iteration for r in rows if r.event.startswith("stable-descent")]
    assert its and its == sorted(set(its)) and its[-1] <= end.steps
    phi = brentq(lambda p: K * p - MGL * np.sin(p), 0.5, 3.0)
    cg = end.state.pos[0]
    assert np.arctan2(abs(cg[0]), cg[1]) == pytest.approx(phi, abs=1e-3)
