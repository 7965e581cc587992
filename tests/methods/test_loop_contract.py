"""The one loop's contract (solvers/iterate.py): the loop owns the budget and the history,
terminate is pure, a spent budget becomes the solver's declared status."""
from dataclasses import FrozenInstanceError, dataclass, replace

import pytest

from poise.solvers.history import Row
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.status import Status


@dataclass(frozen=True)
class _Halving:
    x: float
    n: int = 0


class Halve(Solver):
    """Halve x until it is below tol; one history row per step."""

    out_of_budget = Status.STEP_TOO_SMALL

    def __init__(self, tol):
        self.tol = tol
        self.terminate_calls = 0

    def init(self, x):
        return _Halving(float(x))

    def terminate(self, s):
        self.terminate_calls += 1
        return (True, Status.CONVERGED) if s.x < self.tol else (False, None)

    def step(self, s, left):
        nxt = replace(s, x=s.x / 2, n=s.n + 1)
        return Next(nxt, 1, (Row(0, s.n, s.x, 0.0, 0.0, 1.0, "", "halve"),))

    def postprocess(self, s, status, used):
        return s, status, used


def test_converges_with_rows_appended_by_the_loop():
    rows = []
    s, status, used = iterate(Halve(1.0), 100, rows, 16.0)
    assert status is Status.CONVERGED
    assert s.x == pytest.approx(0.5) and used == 5 and s.n == 5
    assert [r.iteration for r in rows] == [0, 1, 2, 3, 4]


def test_budget_becomes_the_declared_status():
    rows = []
    s, status, used = iterate(Halve(1e-9), 3, rows, 16.0)
    assert status is Status.STEP_TOO_SMALL
    assert used == 3 and s.x == pytest.approx(2.0) and len(rows) == 3


def test_states_are_frozen():
    s = Halve(1.0).init(4.0)
    with pytest.raises(FrozenInstanceError):
        s.x = 1.0


def test_frame_solvers_have_frozen_states_and_a_pure_terminate():
    """Newton, the assembly, pseudo-transient continuation: frozen states, and ``terminate``
    evaluates nothing (the per-solve counters do not move), however often it is asked; the
    loop's answer is the one of the function running it."""
    import numpy as np

    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    from poise.solvers.data import SolveData
    from poise.solvers.fallback import Continuation
    from poise.solvers.newton import NewtonIteration, newton
    from poise.solvers.reach import Assembly
    from poise.solvers.settings import StaticSettings
    from support.loops import assert_frozen_and_pure
    from support.paths import DECKS

    model = compile_model(load_deck(DECKS / "double_pendulum.xml"))
    settings = StaticSettings()
    data = SolveData.for_model(model)
    st = model.initial_state()
    for solver in (NewtonIteration(model, settings, 0, data), Assembly(model, settings, 0, data),
                   Continuation(model, settings, 0, data)):
        assert_frozen_and_pure(solver, solver.init(st), data)
    rows = []
    s, out = iterate(NewtonIteration(model, settings, 0, data), 100, rows, st)
    s2, out2 = newton(model, st, settings, [], 0, SolveData.for_model(model))
    assert out.ok and out2.ok and out.iterations == out2.iterations == len(rows) - 1
    assert np.allclose(s.pos, s2.pos) and np.allclose(s.lam, s2.lam)


def test_evolve_is_replace():
    """``iterate.evolve`` gives what ``dataclasses.replace`` gives (also for a field named
    like its argument), refuses unknown fields, and falls back for a ``__post_init__``."""
    import dataclasses

    import numpy as np

    from poise.solvers.iterate import evolve

    @dataclasses.dataclass(frozen=True)
    class St:
        state: object
        it: int = 0
        seen: tuple = ()

    a = St(np.arange(3.0), 1, (1,))
    b = evolve(a, state=np.ones(2), it=2)
    assert np.array_equal(b.state, np.ones(2))
    assert b.it == 2 and b.seen == (1,) and a.it == 1 and np.array_equal(a.state, np.arange(3.0))
    assert vars(b).keys() == vars(dataclasses.replace(a, it=2)).keys()
    with pytest.raises(dataclasses.FrozenInstanceError):
        b.it = 3
    with pytest.raises(TypeError):
        evolve(a, nope=1)

    @dataclasses.dataclass(frozen=True)
    class Checked:
        x: int

        def __post_init__(self):
            if self.x < 0:
                raise ValueError("negative")

    with pytest.raises(ValueError):
        evolve(Checked(1), x=-1)
