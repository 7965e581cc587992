"""The one iteration loop of the frame-level solvers (Newton, continuation, the fallback chain).

A strategy has the shape of optimistix's iterative solvers: ``init`` builds the iteration
state, ``step`` does one iteration (and records its history row), ``terminate`` says whether
to stop (the strategy keeps why in its state), ``postprocess`` builds the result. The loop,
:func:`iterate`, owns the iteration budget and the count of iterations spent, so every
strategy stops the same way when the budget runs out (``exhausted``).
"""
from __future__ import annotations


class Iterative:
    """The contract :func:`iterate` runs.

    * ``init(*args) -> s``: the iteration state.
    * ``terminate(s, used) -> bool``: stop now (converged, failed); ``used``: iterations spent.
    * ``step(s, used, left) -> int``: one iteration; returns the budget it spent (0 when it
      ended the solve instead, ``terminate`` then says so).
    * ``exhausted(s, used)``: the budget ran out before ``terminate`` said stop.
    * ``postprocess(s, used)``: the result.
    """

    def init(self, *args):
        raise NotImplementedError

    def terminate(self, s, used: int) -> bool:
        raise NotImplementedError

    def step(self, s, used: int, left: int) -> int:
        raise NotImplementedError

    def exhausted(self, s, used: int) -> None:
        raise NotImplementedError

    def postprocess(self, s, used: int):
        raise NotImplementedError


def iterate(strategy: Iterative, budget: int, *args):
    """Run ``strategy`` from ``init(*args)`` within ``budget`` iterations; its result."""
    s = strategy.init(*args)
    used = 0
    while not strategy.terminate(s, used):
        if used >= budget:
            strategy.exhausted(s, used)
            break
        used += strategy.step(s, used, budget - used)
    return strategy.postprocess(s, used)
