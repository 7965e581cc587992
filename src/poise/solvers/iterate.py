"""The one iteration loop of poise's solvers, and its contract.

A solver has the shape of optimistix's iterative solvers (``_iterate.py``): ``init`` builds a
frozen, typed state; ``step(state, left)`` does one iteration and returns a :class:`Next` (the
next state, the budget it spent and the history rows it produced); ``terminate(state)`` is
pure and says whether to stop and with which :class:`~poise.solvers.status.Status`; ``close``
gives the rows that end the run; ``postprocess`` builds the result. The loop, :func:`iterate`,
owns the budget, the count of work spent and the history: it is the one place that appends
rows, and it turns a spent budget into the solver's declared ``out_of_budget`` status.
Evaluation and factorisation counts are the per-solve data's
(:class:`~poise.solvers.data.SolveData`), through which every solver evaluates.
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from poise.core.readonly import slot_names
from poise.solvers.history import Row
from poise.solvers.status import Status

S = TypeVar("S")


@functools.cache
def _init_fields(cls):
    """The field names of dataclass ``cls`` when :func:`evolve` may copy its instances (every
    field set by ``__init__``, no ``__post_init__``, none in slots), else None."""
    fs = dataclasses.fields(cls)
    names = frozenset(f.name for f in fs)
    if (hasattr(cls, "__post_init__") or not cls.__dictoffset__
            or names.intersection(slot_names(cls)) or not all(f.init for f in fs)):
        return None
    return names


def evolve(obj, /, **changes):
    """``dataclasses.replace(obj, **changes)`` for a loop's frozen state, without running
    ``__init__`` (``replace`` reads every field through ``getattr``: a few hundred Python calls
    per Newton solve of a small model). The same new object: the old fields, then the changes;
    a class ``replace`` would treat differently goes through ``replace``."""
    cls = type(obj)
    names = _init_fields(cls)
    if names is None or not changes.keys() <= names:
        return dataclasses.replace(obj, **changes)
    new = object.__new__(cls)
    d = new.__dict__
    d.update(obj.__dict__)
    d.update(changes)
    return new


@dataclass(frozen=True)
class Next(Generic[S]):
    """What one :meth:`Solver.step` did: the next ``state``, ``spent`` units of the budget
    (0 when the step only decided the end; ``terminate`` then says so) and the history
    ``rows`` it produced, in order."""

    state: S
    spent: int = 1
    rows: tuple[Row, ...] = ()


class Solver(Generic[S]):
    """The contract :func:`iterate` runs. States are frozen (``dataclasses.replace`` makes the
    next one); nothing but the loop appends history rows.

    * ``init(*args) -> S``: the first state.
    * ``terminate(state) -> (done, status)``: pure (no evaluation, no mutation): stop now, and
      why (``status`` None while not done).
    * ``step(state, left) -> Next[S]``: one iteration; ``left``: budget still available.
    * ``out_of_budget``: the status the loop gives when the budget runs out first.
    * ``close(state, status, used) -> rows``: rows that end the run (default none).
    * ``postprocess(state, status, used)``: the result.
    """

    out_of_budget: Status = Status.MAX_ITERATIONS

    def init(self, *args) -> S:
        raise NotImplementedError

    def terminate(self, state: S) -> tuple[bool, Status | None]:
        raise NotImplementedError

    def step(self, state: S, left: int) -> Next[S]:
        raise NotImplementedError

    def close(self, state: S, status: Status, used: int) -> tuple[Row, ...]:
        return ()

    def postprocess(self, state: S, status: Status, used: int) -> Any:
        raise NotImplementedError


def iterate(solver: Solver, budget: int, history, *args):
    """Run ``solver`` from ``init(*args)`` within ``budget`` units of work, appending the rows
    of every step and of ``close`` to ``history`` (anything with ``append(row)``); its
    ``postprocess``. A spent budget ends the run with ``solver.out_of_budget``."""
    budget = int(budget)
    state = solver.init(*args)
    used = 0
    while True:
        done, status = solver.terminate(state)
        if done:
            break
        if used >= budget:
            status = solver.out_of_budget
            break
        nxt = solver.step(state, budget - used)
        state = nxt.state
        for row in nxt.rows:
            history.append(row)
        used += nxt.spent
    for row in solver.close(state, status, used):
        history.append(row)
    return solver.postprocess(state, status, used)
