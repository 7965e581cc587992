"""The one iteration loop of the frame-level solvers (assembly, Newton, continuation, the
fallback chain).

A strategy has the shape of optimistix's iterative solvers: ``init`` builds the iteration
state, ``step`` does one iteration and returns a :class:`Step` (the budget it spent and the
history rows it produced), ``terminate`` says whether to stop (the strategy keeps why in its
state), ``close`` gives the row that ends the run (Newton's last measured point),
``postprocess`` builds the result. The loop, :func:`iterate`, owns the iteration budget, the
count of iterations spent and the history: it is the one place that appends the rows of
these strategies, so a strategy never touches the :class:`~poise.solvers.history.History`.
Evaluation and factorisation counts are the per-solve data's
(:class:`~poise.solvers.data.SolveData`), through which every strategy evaluates.
"""
from __future__ import annotations

from dataclasses import dataclass

from poise.solvers.history import Row


@dataclass(frozen=True)
class Step:
    """What one ``step`` did: ``spent`` iterations of the budget (0 when it ended the solve
    instead; ``terminate`` then says so) and the history ``rows`` it produced, in order."""

    spent: int
    rows: tuple[Row, ...] = ()


class Iterative:
    """The contract :func:`iterate` runs.

    * ``init(*args) -> s``: the iteration state.
    * ``terminate(s, used) -> bool``: stop now (converged, failed); ``used``: iterations spent.
    * ``step(s, used, left) -> Step``: one iteration.
    * ``exhausted(s, used)``: the budget ran out before ``terminate`` said stop.
    * ``close(s, used) -> tuple[Row, ...]``: rows that end the run (default none).
    * ``postprocess(s, used)``: the result.
    """

    def init(self, *args):
        raise NotImplementedError

    def terminate(self, s, used: int) -> bool:
        raise NotImplementedError

    def step(self, s, used: int, left: int) -> Step:
        raise NotImplementedError

    def exhausted(self, s, used: int) -> None:
        raise NotImplementedError

    def close(self, s, used: int) -> tuple[Row, ...]:
        return ()

    def postprocess(self, s, used: int):
        raise NotImplementedError


def iterate(strategy: Iterative, budget: int, history, *args):
    """Run ``strategy`` from ``init(*args)`` within ``budget`` iterations, appending the rows
    of every step and of ``close`` to ``history`` (anything with ``append(row)``); its
    result."""
    s = strategy.init(*args)
    used = 0
    while not strategy.terminate(s, used):
        if used >= budget:
            strategy.exhausted(s, used)
            break
        rec = strategy.step(s, used, budget - used)
        for row in rec.rows:
            history.append(row)
        used += rec.spent
    for row in strategy.close(s, used):
        history.append(row)
    return strategy.postprocess(s, used)
