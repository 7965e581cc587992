"""The one loop's contract (solvers/iterate.py): the loop owns the budget and the history,
terminate is pure, a spent budget becomes the solver's declared status."""
from dataclasses import dataclass, replace

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
    with pytest.raises(Exception):
        s.x = 1.0
