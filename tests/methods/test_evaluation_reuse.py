"""A small model's evaluations at a state already evaluated in the solve reuse its family
outputs (:mod:`poise.model.recent`): every reused result is bitwise the evaluation it
replaces (residual, constraint values, Jacobian under any row mask and mass shift, and an
evaluation that differs only in the multipliers); a sparse model's static prologue start
serves Newton's first iterate."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from poise.deck.parser import load_deck
from poise.model.compile import compile_model
from poise.model.evaluate import evaluate
from poise.model.workspace import Workspace
from support.builders import perturbed_chain

DECKS = Path(__file__).resolve().parents[2] / "decks"


@pytest.fixture(scope="module", params=["fourbar_spring.xml", "pendulum_multiturn.xml"])
def model_state(request):
    model = compile_model(load_deck(str(DECKS / request.param)))
    st = model.initial_state()
    st.lam = np.linspace(-3.0, 5.0, model.nc)        # multipliers enter G and the residual
    return model, st


def _same(a, b):
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def test_reused_evaluations_are_bitwise_fresh_ones(model_state):
    model, st = model_state
    ws = Workspace()
    first = evaluate(model, st, "jacobian", workspace=ws)        # every row, eps 0: kept
    rng = np.random.default_rng(3)
    for what, eps in (("residual", 0.0), ("defer", 1e-5), ("jacobian", 0.0), ("jacobian", 1e-5)):
        mask = rng.random(model.nc) > 0.3
        again = evaluate(model, st, what, active=mask, eps_mass=eps, workspace=ws)
        fresh = evaluate(model, st, what, active=mask, eps_mass=eps)     # own workspace
        assert _same(again.r, fresh.r) and _same(again.phi, fresh.phi)
        if what != "residual":
            assert _same(model.jacobian(again), model.jacobian(fresh))
    assert _same(first.J, evaluate(model, st, "jacobian").J)


def test_new_multipliers_reuse_the_forces_only(model_state):
    model, st = model_state
    ws = Workspace()
    evaluate(model, st, "defer", workspace=ws)
    st2 = st.copy()
    st2.lam = st.lam * 0.5 + 1.0
    again = evaluate(model, st2, "jacobian", eps_mass=1e-5, workspace=ws)
    fresh = evaluate(model, st2, "jacobian", eps_mass=1e-5)
    assert _same(again.r, fresh.r) and _same(again.phi, fresh.phi) and _same(again.J, fresh.J)
    assert not _same(again.r, evaluate(model, st, "residual").r)   # the multipliers count


def test_a_moved_state_is_evaluated_again(model_state):
    model, st = model_state
    ws = Workspace()
    evaluate(model, st, "jacobian", workspace=ws)
    st2 = st.copy()
    st2.pos[0, 0] += 1e-3
    again = evaluate(model, st2, "jacobian", workspace=ws)
    fresh = evaluate(model, st2, "jacobian")
    assert _same(again.r, fresh.r) and _same(again.phi, fresh.phi) and _same(again.J, fresh.J)
    assert not _same(again.phi, evaluate(model, st, "residual").phi)


def test_sparse_prologue_outputs_serve_newtons_first_iterate(tmp_path, monkeypatch):
    """A sparse model keeps the outputs of a constraint-Jacobian-only ("phi_q") evaluation, the
    static prologue's start: the same pose with new multipliers (Newton's first iterate) calls
    no force kernel again, and its residual and Jacobian are bitwise a fresh evaluation's."""
    model, st = perturbed_chain(tmp_path, 120, seed=5)
    assert not model.assembler.dense
    ws = Workspace()
    st0 = st.copy()
    st0.lam[:] = 0.0
    pro = evaluate(model, st0, "phi_q", workspace=ws)
    assert pro.inertia is None            # no mass shift: the world inertias are not made
    calls = []
    for cls in {type(fam) for fam in model.families if not fam.is_constraint}:
        monkeypatch.setattr(cls, "forces",
                            lambda *a, _o=cls.forces, **k: calls.append(1) or _o(*a, **k))
    again = evaluate(model, st, "defer", eps_mass=1e-4, workspace=ws)
    assert calls == []
    Ja = model.jacobian(again)
    monkeypatch.undo()
    fresh = evaluate(model, st, "jacobian", eps_mass=1e-4)
    assert _same(again.r, fresh.r) and _same(again.phi, fresh.phi)
    assert _same(Ja.data, fresh.J.data) and _same(Ja.indices, fresh.J.indices)
    assert _same(again.inertia, model.world_inertia(st))
