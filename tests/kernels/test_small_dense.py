"""The dense slot pass of small models (poise.model.small_dense) against the generic engine.

The small pass sums the same terms in another order (one slot map product instead of per-family
scatters and the fixed-pattern assembly), so residual, constraint values and KKT Jacobian agree
to round-off, not to the bit; its slot kinematics are the generic ones bit for bit. Models that
do not qualify (scalar unknowns, too many unknowns) keep the generic engine.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from poise.deck.parser import load_deck
from poise.elements.kernel import slot_kinematics
from poise.model.compile import compile_model
from poise.model.evaluate import evaluate
from poise.model.small_dense import SMALL_MAX
from poise.solvers.equilibrate import equilibrate_dense

DECKS = Path(__file__).resolve().parents[2] / "decks"
SMALL = ["fourbar_spring.xml", "pendulum_multiturn.xml", "chain_10_spherical.xml", "double_pendulum.xml",
         "bushing_block.xml", "elem_point_springs.xml", "contact_box_plane.xml",
         "elem_gear_pair.xml", "qs_slider_crank_rev.xml"]


def _model(name):
    return compile_model(load_deck(str(DECKS / name)))


def _moved(model, seed):
    rng = np.random.default_rng(seed)
    st = model.initial_state()
    st = model.retract(st, 1e-2 * rng.standard_normal(model.nq) * model.q_scale
                       / model.q_scale.max())
    st.lam = 10.0 * rng.standard_normal(model.nc)
    return st


@pytest.mark.parametrize("name", SMALL)
def test_small_pass_is_the_generic_evaluation(name):
    model = _model(name)
    assert model.small is not None
    generic = dataclasses.replace(model, small=None)
    rng = np.random.default_rng(7)
    for seed in range(3):
        st = _moved(model, seed)
        active = None if seed == 0 else rng.random(model.nc) > 0.25
        for what in ("jacobian", "phi_q", "residual"):
            a = evaluate(model, st, what, active=active, eps_mass=0.37)
            b = evaluate(generic, st, what, active=active, eps_mass=0.37)
            for k in ("r", "phi", "J"):
                x, y = getattr(a, k), getattr(b, k)
                if y is None:
                    assert x is None
                    continue
                assert isinstance(x, np.ndarray) and x.shape == y.shape
                scale = max(float(np.max(np.abs(y), initial=0.0)), 1e-300)
                assert np.max(np.abs(x - y), initial=0.0) <= 1e-13 * scale, (what, k)
            if what != "residual":
                assert np.array_equal(a.inertia, b.inertia)


@pytest.mark.parametrize("name", SMALL)
def test_small_kinematics_are_the_slot_kinematics(name):
    model = _model(name)
    st = _moved(model, 3)
    P, A, pos = model.marker_kinematics(st)
    kins = model.small.kinematics(P, A, pos)
    for fi, fam in enumerate(model.families):
        if fam.n == 0:
            continue
        ref = slot_kinematics(fam.markers, fam.slot_ml, fam.slot_kind, P, A, model.marker_body,
                              pos, fam.pattern.slots)
        assert kins[fi].Y.tobytes() == ref.Y.tobytes()
        assert kins[fi].V.tobytes() == ref.V.tobytes()
        assert np.array_equal(kins[fi].pt, ref.pt)


def test_deferred_jacobian_is_assembled_again_the_same():
    model = _model("fourbar_spring.xml")
    st = _moved(model, 5)
    ev = evaluate(model, st, "defer", eps_mass=0.1)
    pend = ev._pending
    J1 = model.jacobian(ev).copy()
    ev.J, ev._pending = None, pend          # the kept outputs are read only: the same matrix
    assert model.jacobian(ev).tobytes() == J1.tobytes()


def test_models_outside_the_small_pass():
    assert _model("elem_diff_integrator.xml").small is None      # scalar unknowns
    big = _model("mkeam_chain_20.xml")
    assert big.N > SMALL_MAX and big.small is None


def test_one_frame_equilibration_is_the_frames_loop():
    rng = np.random.default_rng(11)
    for _ in range(300):
        n, m = int(rng.integers(1, 16)), int(rng.integers(0, 12))
        K = rng.standard_normal((1, n, n)) * 10.0 ** rng.integers(-8, 8, (1, n, n))
        K = K + np.swapaxes(K, 1, 2)
        K[rng.random((1, n, n)) < 0.5] = 0.0
        G = rng.standard_normal((1, m, n)) * 10.0 ** rng.integers(-8, 8, (1, m, n))
        G[rng.random((1, m, n)) < 0.6] = 0.0
        one = equilibrate_dense(K, G)
        two = equilibrate_dense(np.concatenate([K, K]), np.concatenate([G, G]))  # frames loop
        assert one[0][0].tobytes() == two[0][0].tobytes()
        assert one[1][0].tobytes() == two[1][0].tobytes()


@pytest.mark.parametrize("name", ["fourbar_spring.xml", "chain_10_spherical.xml",
                                  "contact_box_plane.xml", "mkeam_inverted_pendulum.xml"])
def test_one_frame_classification_is_the_frames_path(name):
    from poise.solvers.stability import _dense_frames
    model = _model(name)
    rng = np.random.default_rng(13)
    for seed in range(3):
        st = _moved(model, seed) if seed else model.initial_state()
        J = np.asarray(evaluate(model, st, "jacobian").J)
        active = np.ones(model.nc, bool)
        if seed == 2:
            active[rng.random(model.nc) < 0.2] = False
        one = _dense_frames(model, J[None], active, np.ones(1, bool))[0]
        two = _dense_frames(model, np.stack([J, J]), active, np.ones(2, bool))[0]   # stacked
        assert (one.klass, one.n_negative, one.n_zero, one.modes) == \
            (two.klass, two.n_negative, two.n_zero, two.modes)
        assert np.float64(one.min_eigenvalue).tobytes() == np.float64(two.min_eigenvalue).tobytes()
        assert repr(one.mode_list) == repr(two.mode_list)
        assert len(one.vectors) == len(two.vectors)
        assert all(a.tobytes() == b.tobytes() for a, b in zip(one.vectors, two.vectors))
