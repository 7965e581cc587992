"""Newton's step shaping: the neutral-direction filter asks the step limits only when its tail
share does not decide, and gives the same step whether ``limited`` is a bool or asked lazily."""
from __future__ import annotations

import numpy as np

from poise.deck.parser import load_deck
from poise.gen.chain import build_chain_deck
from poise.model.compile import compile_model
from poise.solvers.data import SolveData
from poise.solvers.newton import Scales
from poise.solvers.redundancy import detect_redundancy
from poise.solvers.settings import StaticSettings
from poise.solvers.steps import TAIL_SHARE, limit_step, mass_times, neutral_filtered


def _setup(tmp_path, eps):
    p = tmp_path / "chain.xml"
    p.write_text(build_chain_deck(12))
    model = compile_model(load_deck(str(p)))
    st = model.initial_state()
    st.lam[:] = np.random.default_rng(2).standard_normal(model.nc)
    data = SolveData.for_model(model, detect_redundancy(model, st))   # a closed loop: 3 rows
    ev = data.evaluate(model, st, "jacobian", eps=eps)
    f = data.factor(ev.J)
    x = f.solve(-np.concatenate([ev.r, ev.phi]))
    return model, st, f, x


def test_the_limits_are_asked_only_when_the_tail_share_does_not_decide(tmp_path):
    eps = 1e-2
    model, st, f, x = _setup(tmp_path, eps)
    settings = StaticSettings()
    sc = Scales(model, settings)
    asked = []

    def limited():
        asked.append(1)
        return limit_step(model, st, x[:model.nq], settings)[0] < 1.0

    reg = eps * mass_times(model, st, x[:model.nq])
    shares = []
    for zinf in (1e-12, 1e12):         # the tail share far above, then far below TAIL_SHARE
        share = float(np.max(np.abs(reg) / sc.r_tol)) / zinf
        shares.append(share)
        asked.clear()
        lazy = neutral_filtered(model, st, f, x, eps, sc, zinf, limited)
        assert len(asked) == (0 if share > TAIL_SHARE else 1)
        eager = neutral_filtered(model, st, f, x, eps, sc, zinf, limited())
        assert (lazy is None) == (eager is None)
        if lazy is not None:
            assert lazy.tobytes() == eager.tobytes()
    assert shares[0] > TAIL_SHARE >= shares[1]      # both branches of the test were taken


def test_mass_times_with_the_inertias_given_is_the_same_product(tmp_path):
    model, st, _, x = _setup(tmp_path, 1e-3)
    v = x[:model.nq]
    Jg = model.mass_blocks(st)[1]
    assert mass_times(model, st, v, Jg).tobytes() == mass_times(model, st, v).tobytes()
    # M v by the dense mass matrix: body masses on translations, world inertias on rotations
    M = np.zeros((model.nq, model.nq))
    M[model.trans_idx, model.trans_idx] = np.repeat(model.body_mass, 3)
    r = model.rot_idx.reshape(-1, 3)
    for b, blk in enumerate(Jg):
        M[np.ix_(r[b], r[b])] = blk
    np.testing.assert_allclose(mass_times(model, st, v), M @ v, rtol=1e-13, atol=1e-12)
