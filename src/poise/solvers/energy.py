"""Potential energy of a model at a state (MKEAM's descent measure, ``--require-stable``)."""
from __future__ import annotations

from poise.model.evaluate import evaluate


def potential_energy(model, state) -> float:
    """Total potential energy of gravity and the force elements; NaN when a force element is
    not conservative (the evaluation engine's ``"energy"``)."""
    return evaluate(model, state, "energy")
