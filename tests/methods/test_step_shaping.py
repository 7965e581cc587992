"""Newton's step shaping: the neutral-direction filter asks the step limits only when its tail
share does not decide, and gives the same step whether ``limited`` is a bool or asked lazily;
its second solve only when ``S`` is not small on the step; the certifying chord step."""
from __future__ import annotations

import numpy as np
import pytest

from poise.deck.parser import load_deck
from poise.gen.chain import build_chain_deck
from poise.model.compile import compile_model
from poise.solvers.data import SolveData
from poise.solvers.newton import Scales
from poise.solvers.redundancy import detect_redundancy
from poise.solvers.settings import StaticSettings
from poise.solvers.steps import (CHORD_STEP, TAIL_SHARE, chord_step, limit_step, mass_times,
                                 neutral_filtered, step_size)


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


def test_mass_times_of_a_batch_is_each_case_s_product(tmp_path, monkeypatch):
    # the batched sweep path (``CaseBatch._may_filter``) takes the cases' products at once:
    # each row is the case's own product (to round-off: numpy's einsum sums a batch's 3-term
    # products in another order); a single product is the same by strided views or by gathers
    model, st, _, x = _setup(tmp_path, 1e-3)
    rng = np.random.default_rng(3)
    states = [model.retract(st, 1e-2 * rng.standard_normal(model.nq)) for _ in range(3)]
    V = rng.standard_normal((3, model.nq))
    Jg = np.stack([model.world_inertia(s) for s in states])
    many = mass_times(model, None, V, Jg)
    assert model.rigid_blocks() and many.shape == V.shape
    strided = [mass_times(model, s, V[c]) for c, s in enumerate(states)]
    for c in range(3):
        np.testing.assert_allclose(many[c], strided[c], rtol=1e-14, atol=1e-14 * np.abs(
            strided[c]).max())
        assert np.array_equal(many[c][model.trans_idx], strided[c][model.trans_idx])
    monkeypatch.setattr(type(model), "rigid_blocks", lambda self: False)   # by gathers
    for c, s in enumerate(states):
        assert mass_times(model, s, V[c]).tobytes() == strided[c].tobytes()


def test_a_stalled_line_search_by_each_of_its_three_tests():
    # Newton and the batched sweep path decide with the same test (newton.stalled)
    from poise.solvers.newton import ALPHA_STALL, ARMIJO, stalled
    halving = (16.0, 8.0, 4.0, 2.0)
    assert not stalled(halving, 1.0, 1.0, 2)                       # Armijo decrease at alpha 1
    assert stalled((16.0, 12.0, 9.0), 1.0, 1.0, 2)                 # not halved in 2 iterations
    assert not stalled((16.0, 12.0, 9.0), 1.0, 1.0, 3)             # (a window not yet full)
    assert stalled(halving, 1.0, 0.5 * ALPHA_STALL, 2)             # cut too short
    assert stalled(halving, (1 - ARMIJO) * 2.0 * 1.0000001, 1.0, 2)   # no Armijo decrease
    assert not stalled(halving, (1 - ARMIJO) * 2.0, 1.0, 2)
    assert stalled(halving, np.nan, 1.0, 2)                        # no finite trial merit


class _Counted:
    """A factorisation whose solves are counted."""

    def __init__(self, f):
        self.f, self.n = f, 0

    def solve(self, b, **kw):
        self.n += 1
        return self.f.solve(b, **kw)


@pytest.mark.parametrize("eps, solves", [(1e-2, 2), (1e-4, 1)])
def test_the_second_solve_only_when_s_is_not_small_on_the_step(tmp_path, eps, solves):
    """On the 12-link chain (no neutral direction) <Sx,Sx>_M / <x,Sx>_M is about eps / 2: at
    eps 1e-2 the filter makes both solves and gives (I - S)(I + 2S) x; at 1e-4 one, and its
    (I + S) x is that step up to 2 S^2 x, and closer than x to Newton's step without the
    regularisation (second order in eps/lambda, x first order)."""
    model, st, f, x = _setup(tmp_path, eps)
    nq, sc = model.nq, Scales(model, StaticSettings())
    g = _Counted(f)
    xf = neutral_filtered(model, st, g, x, eps, sc, 1e-12, False)   # tail share far above
    assert g.n == solves
    pad = np.zeros(model.nc)
    Sx = f.solve(np.concatenate([eps * mass_times(model, st, x[:nq]), pad]))
    two = x + Sx - 2.0 * f.solve(np.concatenate([eps * mass_times(model, st, Sx[:nq]), pad]))
    scale = float(np.max(np.abs(x)))
    if solves == 2:
        np.testing.assert_allclose(xf, two, rtol=0, atol=1e-12 * scale)
        return
    np.testing.assert_allclose(xf, x + Sx, rtol=0, atol=1e-15 * scale)
    assert 0 < np.max(np.abs(xf - two)) <= 1e-6 * scale
    # Newton's step of the unregularised KKT matrix (the chain has no neutral direction)
    data = SolveData.for_model(model, detect_redundancy(model, st))
    ev0 = data.evaluate(model, st, "jacobian", eps=0.0)
    exact = data.factor(ev0.J).solve(-np.concatenate([ev0.r, ev0.phi]))
    assert np.max(np.abs(xf - exact)) < 1e-3 * np.max(np.abs(x - exact))


def test_the_chord_step_is_taken_where_it_does_what_newtons_would(tmp_path):
    """``chord_step``: nothing without a kept factorisation; at an iterate within tolerance the
    kept factorisation's step when it is CHORD_STEP below max_error; elsewhere only when its
    contraction since the kept step is Newton's quadratic phase and leaves at most CHORD_STEP
    of the residual and step tolerances."""
    model, st, f, x = _setup(tmp_path, 1e-3)
    sc = Scales(model, StaticSettings())
    tol = sc.max_error
    b = -x                                  # any right-hand side: its step is f^-1 b
    size = step_size(f.solve(b)[:model.nq], sc)

    def scaled(s):                          # the right-hand side whose step has size s
        return (s / size) * b

    assert chord_step(None, b, sc, 0.5) is None
    # certifying: within tolerance, 1e-2 below max_error, whatever the step before
    small = scaled(0.5 * CHORD_STEP * tol)
    np.testing.assert_allclose(chord_step((f, 1e-300), small, sc, 0.5), f.solve(small),
                               rtol=1e-12, atol=0)
    big = 2.0 * CHORD_STEP * tol
    assert chord_step((f, 2.0 * big), scaled(big), sc, 0.5) is None   # contraction 0.5
    assert chord_step((f, 1.0), small, sc, 1.5) is not None      # contraction 5e-11: converging
    # converging: contraction 1e-4 from a step 1e-3 (1e-7), residual 50x the tolerance
    mid = scaled(1e-7)
    assert chord_step((f, 1e-3), mid, sc, 50.0) is not None
    assert chord_step((f, 1e-3), mid, sc, 500.0) is None          # 5e-2 of the tolerance left
    assert chord_step((f, 1e-6), mid, sc, 5.0) is None            # contraction 0.1: not yet
    assert chord_step((f, 1e-3), scaled(1e-3), sc, 1.0) is None  # 1 x 1e-3: beyond tolerance


def test_the_certifying_step_saves_the_last_factorisation(tmp_path, monkeypatch):
    """A smooth solve ends with chord steps (Newton's quadratic phase): fewer factorisations
    than its Newton iterations plus the prologue's, the same iterations and answer as when
    every step factorises (chord steps refused)."""
    import poise.solvers.steps as steps
    from poise.app.runner import run_deck
    p = tmp_path / "chain.xml"
    p.write_text(build_chain_deck(80))                # sparse (N 885): chord steps
    ra = run_deck(str(p))
    a = ra.analyses[0]
    assert a.converged
    its = int(a.datasets["frames/iterations"][0])
    assert ra.counts["factorizations"] < its + 1       # prologue 1 + Newton's, fewer than its
    ev = list(a.datasets["iterations/event"])
    chords = ev.count("newton-chord")                 # the history names the chord steps
    assert chords >= 1 and ra.counts["factorizations"] == its + 1 - chords
    monkeypatch.setattr(steps, "CHORD_STEP", -1.0)    # no chord step is small enough
    rb = run_deck(str(p))
    b = rb.analyses[0]
    assert b.converged and int(b.datasets["frames/iterations"][0]) == its
    assert rb.counts["factorizations"] == its + 1
    assert "newton-chord" not in list(b.datasets["iterations/event"])
    L = float(np.max(np.abs(b.datasets["bodies/position"])))
    np.testing.assert_allclose(a.datasets["bodies/position"], b.datasets["bodies/position"],
                               rtol=0, atol=1e-9 * L)
