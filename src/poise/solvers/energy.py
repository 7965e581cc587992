"""Potential energy of a model at a state (MKEAM's descent measure, ``--require-stable``)."""
from __future__ import annotations

import numpy as np

from poise.elements.kernel import slot_kinematics
from poise.model.model import EvalContext


def potential_energy(model, state) -> float:
    """Total potential energy of gravity and the force elements; NaN when a force element is
    not conservative."""
    m = model
    V = 0.0
    if m.gravity_on:
        V -= float(np.sum(m.body_mass[:, None] * state.pos * m.gravity[None, :]))
    fams = [f for f in m.families if not f.is_constraint]
    if not fams:
        return V
    P, A, pos = m.marker_kinematics(state)
    ctx = EvalContext(t=state.t, angle=state.angle)
    for fam in fams:
        fn = getattr(fam, "potential_energy", None)
        if fn is None:
            return np.nan
        kin = slot_kinematics(fam.markers, fam.slot_ml, fam.slot_kind, P, A, m.marker_body, pos)
        if getattr(fam, "potential_needs_ground", False):
            e = fn(kin, ctx, on_ground=m.marker_body[fam.markers] == m.nb)
        else:
            e = fn(kin, ctx)
        if e is None:
            return np.nan
        V += float(np.sum(e))
    return V
