"""Big families' kernel outputs made in chunks of instances give bitwise the whole family's.

:mod:`poise.elements.chunked` splits families above ``2 * CHUNK`` instances (10^5-link chains);
here ``CHUNK`` is lowered so that a 700-link chain's ``Perpendicular`` family (1402 instances,
no kept slot index) is split, and every output of an evaluation (residual, constraint values,
KKT Jacobian, with and without removed rows) must keep its bits.
"""
from __future__ import annotations

import re

import numpy as np
import pytest

import poise.elements.chunked as chunked
import poise.model.model as model_mod
from poise.core.errors import EvaluationError
from poise.model.assembly import Scatter
from poise.model.workspace import Workspace
from support.builders import perturbed_chain


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    return perturbed_chain(tmp_path_factory.mktemp("chain"), 700, 5)


def _outputs(model, st):
    active = np.ones(model.nc, bool)
    active[[4, 40, 401]] = False
    ws, out = Workspace(), []
    for act in (None, active):
        ev = model.evaluate(st, need_jac=True, eps_mass=1e-3, active=act, workspace=ws)
        res = model.evaluate(st, need_jac=False, active=act, workspace=ws)
        out += [ev.r, ev.phi, ev.J.data, res.r, res.phi]
    out += list(model.marker_kinematics(st)[:2])
    return out


def test_chunked_evaluation_keeps_every_bit(chain, monkeypatch):
    model, st = chain
    whole = _outputs(model, st)
    monkeypatch.setattr(chunked, "CHUNK", 200)
    monkeypatch.setattr(model_mod, "CHUNK", 200)
    calls = []
    orig = chunked.tangent_compact
    monkeypatch.setattr(chunked, "tangent_compact",
                        lambda kin, *a, **kw: calls.append(kin.pt.shape[0]) or orig(kin, *a, **kw))
    parts = _outputs(model, st)
    assert calls and max(calls) <= 200 and min(calls) >= 100      # really split, balanced
    assert len(whole) == len(parts)
    for a, b in zip(whole, parts):
        assert a.shape == b.shape and a.tobytes() == b.tobytes()


def test_a_non_finite_chunk_names_its_instance(chain, monkeypatch):
    model, st = chain
    monkeypatch.setattr(chunked, "CHUNK", 200)
    bad = st.copy()
    bad.lam = bad.lam.copy()
    fam = max((f for f in model.families if f.is_constraint), key=lambda f: f.n)
    k = fam.n - 3                                     # in the last chunk
    bad.lam[fam.crow[k, 0]] = np.inf
    name = (fam.element_locs[k].prefix() if fam.element_locs
            else f"element family {fam.name} (instance {k}) ")
    with pytest.raises(EvaluationError, match=re.escape(name)), np.errstate(invalid="ignore"):
        model.evaluate(bad, need_jac=False)         # inf x 0 in the kernel: NaN, as intended


def test_scatter_parts_sum_like_one_scatter():
    rng = np.random.default_rng(1)
    idx = rng.integers(-1, 50, 40000)
    vals = rng.standard_normal(40000)
    s = Scatter(50, idx)
    one, parts = np.zeros(50), np.zeros(50)
    s.add(one, vals)
    s.add_parts(parts, [vals[:123], vals[123:30000], vals[30000:]])
    assert one.tobytes() == parts.tobytes()
    with pytest.raises(ValueError):
        s.add_parts(parts, [vals[:10]])
