"""Checks of the one loop's contract (poise.solvers.iterate) shared by the solver tests."""
from dataclasses import FrozenInstanceError, fields

import pytest


def assert_frozen_and_pure(solver, state, data):
    """``state`` is frozen, and ``solver.terminate`` evaluates nothing: the per-solve
    counters of ``data`` do not move however often it is asked."""
    with pytest.raises(FrozenInstanceError):
        setattr(state, fields(state)[0].name, None)
    before = data.as_dict()
    for _ in range(3):
        solver.terminate(state)
    assert data.as_dict() == before
