"""Potential energy of a model at one frame: the sum of what the element types declare for
their families, read through a view of the frame's kinematics (MKEAM's descent measure and
restart rule, ``--require-stable``)."""
from __future__ import annotations

import numpy as np

from poise.elements.kernel import slot_kinematics
from poise.expr import EvalContext


def potential_energy(model, fr) -> float:
    """Potential energy at one frame: the sum of what the element types declare for their
    families (``Model.energy_terms``: gravity, springs, contacts, ...; constraints add nothing);
    NaN when one declares none (a non-conservative force: MKEAM's descent measure and restart
    rule, ``--require-stable``)."""
    V = 0.0
    view = _EnergyView(model, fr)
    for fi, fn in model.energy_terms:
        e = fn(model.families[fi], view)
        if e is None:
            return np.nan
        V += float(np.sum(e))
    return V


class _EnergyView:
    """What a declared ``potential_energy(fam, frame)`` reads at one frame
    (:mod:`poise.elements.registry`): slot kinematics, time and angles, fixed markers."""

    def __init__(self, model, fr):
        self.model, self.fr = model, fr
        self.ctx = EvalContext(t=fr.ctx.t, angle=fr.ctx.angle, workspace=fr.ws)

    def kinematics(self, fam):
        fr = self.fr
        return slot_kinematics(fam.markers, fam.slot_ml, fam.slot_kind, fr.P, fr.A, fr.mb,
                               fr.pos)

    def on_ground(self, fam):
        """(n, K) bool: which of each instance's markers are fixed."""
        return self.fr.mb[fam.markers] == self.model.nb
