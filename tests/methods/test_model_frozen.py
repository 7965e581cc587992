"""The compiled model is immutable all the way down; a solve keeps its data in the workspace.

After solving an example deck, every array reachable from each compiled model (families,
kernels' parameters, expression programs, splines, the assembler, frame hooks, tuples / dicts /
lists inside) is read-only, and no object reachable from the model changed: no attribute added
or removed, no container grown, no array changed, nothing new reachable. A write to a compiled
model or one of its families fails.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import poise.app.runner as runner_mod
import poise.model.compile as compile_mod
from poise.app import deck_cache
from poise.app.api import run_deck

from support.paths import DECKS
from support.reach import reachable, snapshot

#: decks whose solves cover every path (redundant rows, MKEAM, quasi-static FIM_S and FIM_D,
#: expression forces reading reactions, curves, user routines, contact, scalar unknowns)
QUICK = ["chain_10.xml", "qs_pendulum_ramp.xml", "elem_cvcv_cam_qs.xml",
         "expr_reaction_load.xml", "elem_user_forces.xml", "contact_sphere_plane.xml",
         "elem_diff_integrator_qs.xml", "elem_gcon_parabola.xml"]
ALL = sorted(p.name for p in DECKS.glob("*.xml"))
if (DECKS / "adm").is_dir():
    ALL += sorted(f"adm/{p.name}" for p in (DECKS / "adm").iterdir()
                  if p.suffix in (".adm", ".acf", ".xml"))


def _solve_and_check(deck, overrides, monkeypatch):
    compiled = []
    real = compile_mod.compile_model

    def spy(*a, **k):
        m = real(*a, **k)
        compiled.append((m, snapshot(m)))
        return m

    monkeypatch.setattr(compile_mod, "compile_model", spy)
    monkeypatch.setattr(runner_mod, "compile_model", spy)
    opts = {"allow_user_code": True} if "user" in deck else {}
    if deck == "adm/adm_commands.adm":                # its CAD contact needs --ignore CONTACT
        opts["ignore"] = ("CONTACT",)
    deck_cache.clear()     # compiled here (not reused from an earlier test): the model a later
    res = run_deck(str(DECKS / deck), overrides, quiet=True, **opts)   # solve may reuse
    assert res.analyses and compiled
    for m, before in compiled:
        after = reachable(m)
        writeable = [p for o, p in after.values()
                     if isinstance(o, np.ndarray) and o.flags.writeable]
        assert not writeable, f"{len(writeable)} writeable arrays, e.g. {writeable[:5]}"
        new = [p for k, (o, p) in after.items() if k not in before]
        assert not new, f"{len(new)} objects reachable only after the solve, e.g. {new[:5]}"
        changed = [p for k, (p, s) in before.items() if k in after and
                   _state(after[k][0]) != s]
        assert not changed, f"changed during the solve: {changed[:5]}"
    return compiled


def _state(o):
    from support.reach import state
    return state(o)


@pytest.mark.parametrize("deck", QUICK)
def test_solve_leaves_the_model_unchanged(deck, monkeypatch):
    _solve_and_check(deck, None, monkeypatch)


@pytest.mark.parametrize("deck, overrides", [
    ("chain_10.xml", {"method": "MKEAM"}),
    ("pendulum_multiturn.xml", {"require_stable": True}),
])
def test_other_methods_leave_the_model_unchanged(deck, overrides, monkeypatch):
    _solve_and_check(deck, overrides, monkeypatch)


def test_a_sparse_solve_leaves_the_model_unchanged(tmp_path, monkeypatch):
    # a sparse model's factorisations make its pattern's column order at the first use: kept
    # beside the assembler (Assembler.ordered), the compiled model stays as compile made it
    from poise.gen.chain import build_chain_deck
    deck = tmp_path / "chain_120.xml"
    deck.write_text(build_chain_deck(120))
    (m, _), = _solve_and_check(str(deck), None, monkeypatch)
    assert not m.assembler.dense
    order = m.assembler.ordered()
    assert order is m.assembler.ordered() and not order.flags.writeable
    assert all(order is not o for o, _ in reachable(m).values())


@pytest.mark.slow
@pytest.mark.parametrize("deck", [d for d in ALL if d not in QUICK])
def test_every_example_deck_leaves_its_models_unchanged(deck, monkeypatch):
    _solve_and_check(deck, None, monkeypatch)


def test_writes_to_a_compiled_model_fail():
    from poise.deck.parser import load_deck
    m = compile_mod.compile_model(load_deck(str(DECKS / "expr_reaction_load.xml")))
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.L = 2.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.cache = {}
    with pytest.raises(ValueError):
        m.body_mass[0] = 1.0
    for fam in m.families:
        with pytest.raises(dataclasses.FrozenInstanceError):
            fam.gcol = None
        with pytest.raises(dataclasses.FrozenInstanceError):
            fam.scratch = 1
        with pytest.raises(ValueError):
            fam.markers[0, 0] = 0
    with pytest.raises(AttributeError):
        m.assembler.buffer = np.zeros(3)
    with pytest.raises(AttributeError):
        m.reaction_feed.cache = {}
