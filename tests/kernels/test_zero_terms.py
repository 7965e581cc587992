"""Terms that are zero are neither formed nor added; residual and Jacobian keep their bits.

Gravity acts at each body's CG marker, whose lever is exactly zero at every pose: its family
registers no tangent entry. A family with no reaction on any slot (a constraint family whose
multipliers are all zero, as the out-of-plane rows of a planar chain) adds no residual rows and
no tangent: the evaluation gives the bits of one that forms and adds those zeros.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from poise.elements.constraints import Perpendicular
from poise.elements.gravity import GravityLoad
from poise.elements.kernel import local_pattern, local_tangent, slot_kinematics
from poise.expr import EvalContext
from poise.model import evaluate as engine
from poise.model.workspace import Workspace
from support.builders import perturbed_chain


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """A 400-link chain (sparse, pooled assembly) at a perturbed pose with random multipliers."""
    return perturbed_chain(tmp_path_factory.mktemp("chain"), 400, 5)


def _family(model, cls) -> int:
    return next(i for i, f in enumerate(model.families) if isinstance(f, cls))


def _bits(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def test_gravity_has_a_zero_lever_and_registers_no_tangent(chain):
    model, st = chain
    fam = model.families[_family(model, GravityLoad)]
    assert local_pattern(fam).nk == 0 and fam.n == model.nb
    P, A, pos = model.marker_kinematics(st)
    kin = slot_kinematics(fam.markers, fam.slot_ml, fam.slot_kind, P, A, model.marker_body, pos)
    assert not kin.V.any()                  # the CG marker's lever, at a moved pose
    rho, G = fam.forces(kin, EvalContext(t=0.0), True)[:2]
    assert np.abs(rho).max(axis=1).min() > 0     # a load on every body ...
    # ... whose tangent formed without any declared structure (dense B^T G B + C) is zero
    Kl = local_tangent(kin, rho, G, fam.slot_ml, fam.K)
    assert Kl.shape == (fam.n, 6, 6) and not Kl.any()


def test_a_family_without_reactions_gives_the_bits_of_its_formed_zeros(chain, monkeypatch):
    model, st = chain
    perp = model.families[_family(model, Perpendicular)]
    lam = st.lam.copy()
    lam[np.asarray(perp.crow).ravel()] = 0.0          # no reaction on the perpendicular rows
    st0 = replace(st, lam=lam)
    assert np.count_nonzero(lam) == lam.size - perp.n * perp.m
    quiet, skipped = [], []
    no_reaction, no_tangent = engine._no_reaction, engine._no_tangent

    def spy_reaction(fam, kin, rho):
        out = no_reaction(fam, kin, rho)
        quiet.append((fam.name, out))
        return out

    def spy_tangent(G, q):
        out = no_tangent(G, q)
        skipped.append(out)
        return out
    monkeypatch.setattr(engine, "_no_reaction", spy_reaction)
    monkeypatch.setattr(engine, "_no_tangent", spy_tangent)
    ev = model.evaluate(st0, need_jac=True, eps_mass=1e-3, workspace=Workspace())
    # the perpendicular family alone has no reaction, and its tangent alone is skipped
    assert (perp.name, True) in quiet and sum(s for _, s in quiet) == 1
    assert sum(skipped) == 1
    # the reference: every family's residual rows and tangent formed and added
    monkeypatch.setattr(engine, "_no_reaction", lambda fam, kin, rho: False)
    ref = model.evaluate(st0, need_jac=True, eps_mass=1e-3, workspace=Workspace())
    assert _bits(ev.r, ref.r) and _bits(ev.phi, ref.phi)
    assert np.array_equal(ev.J.indices, ref.J.indices) and _bits(ev.J.data, ref.J.data)
    # the skipped tangent is zero there, not merely the same: with the rows' multipliers back,
    # the Jacobian differs (the test would pass vacuously if the family had no tangent)
    full = model.evaluate(st, need_jac=True, eps_mass=1e-3, workspace=Workspace())
    assert not _bits(full.J.data, ref.J.data)
