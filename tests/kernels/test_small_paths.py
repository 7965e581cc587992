"""The small-model fast paths give the generic paths' numbers bit for bit.

Small families keep a ``SlotIndex`` (slot gathers, masks, slot rounds); cross products, skew
matrices and Rodrigues' formulas take shortcuts on small arrays or ordinary angles;
``poise.core.lean`` replaces numpy's convenience wrappers. Each is compared here with the
generic computation it stands for, on random layouts (equal bytes, not a tolerance: the
digests of the example decks must not move).
"""
from __future__ import annotations

import numpy as np
import pytest

from poise.core.lean import all_finite, norm, row_norms
from poise.elements import kernel as K
from poise.elements import rotation as R
from poise.elements.slot_index import SlotIndex, slot_rounds


def _cross_ref(a, b):
    a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
    out = np.empty(a.shape)
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


@pytest.mark.parametrize("shape", [(3,), (1, 3), (4, 2, 3), (3000, 4, 3)])
def test_cross_and_skew_small_and_large(shape):
    rng = np.random.default_rng(1)
    a, b = rng.standard_normal(shape), rng.standard_normal(shape)
    a[rng.random(shape) < 0.2] = -0.0
    assert K.cross3(a, b).tobytes() == _cross_ref(a, b).tobytes()
    S = R.skew(a)
    assert S.shape == shape + (3,)
    u = rng.standard_normal(shape)
    assert np.allclose(np.einsum("...ij,...j->...i", S, u), np.cross(a, u), rtol=1e-12, atol=1e-12)
    assert np.array_equal(np.signbit(np.diagonal(S, axis1=-2, axis2=-1)), np.zeros(shape, bool))
    assert np.array_equal(S, -np.swapaxes(S, -1, -2))


@pytest.mark.parametrize("n", [1, 8, 3000])
def test_column_and_row_products(n):
    rng = np.random.default_rng(2)
    v, M = rng.standard_normal((3, n)), rng.standard_normal((3, 3, n))
    Mn = np.moveaxis(M, -1, 0)                      # (n, 3, 3)
    sk = R.skew(v.T)                                # (n, 3, 3)
    assert np.allclose(np.moveaxis(K._cross_cols(v, M), -1, 0), sk @ Mn)
    assert np.allclose(np.moveaxis(K._cross_rows(M, v), -1, 0), Mn @ sk)
    # small and large paths: the same products
    cols = np.stack([_cross_ref(v[:, i], M[:, j, i]) for i in range(n) for j in range(3)])
    assert K._cross_cols(v, M).transpose(2, 1, 0).reshape(-1, 3).tobytes() == cols.tobytes()


def test_slot_rounds_are_the_slot_loop():
    rng = np.random.default_rng(3)
    for _ in range(300):
        k_, s_, n = int(rng.integers(1, 5)), int(rng.integers(1, 13)), int(rng.integers(1, 3))
        ml = rng.integers(0, k_, s_).tolist()
        blk = rng.standard_normal((n, s_, 3, 3))
        base = rng.standard_normal((n, 6 * k_, 6 * k_))
        loop = base.copy()
        for s in range(s_):
            k = ml[s]
            loop[:, 6 * k + 3:6 * k + 6, 6 * k + 3:6 * k + 6] += blk[:, s]
        rounds = base.copy()
        diag = np.einsum("nkikj->nkij", rounds.reshape(n, k_, 6, k_, 6)[:, :, 3:, :, 3:])
        for ks, ss in slot_rounds(ml):
            diag[:, ks] += blk[:, ss]
        assert rounds.tobytes() == loop.tobytes()
        # one bincount of the entries, then the blocks in slot order: the loop's sums
        ix = SlotIndex(np.zeros((n, k_), int), ml, np.zeros((n, s_), int), np.zeros(1, int),
                       connection=True)
        assert ix.add_connection(base, blk, k_).tobytes() == loop.tobytes()


def test_slot_index_sums_are_the_generic_ones():
    rng = np.random.default_rng(4)
    for t in range(300):
        n, k_, s_ = int(rng.integers(1, 5)), int(rng.integers(1, 4)), int(rng.integers(1, 12))
        ml = rng.integers(0, k_, s_)
        kind = np.where(rng.random((1, s_)) < 0.4, 0, rng.integers(1, 4, (1, s_))).repeat(n, 0)
        if t % 4 == 0:                  # a slot that is a point in some instances only
            kind[0, 0], kind[-1, 0] = 0, 1
        markers = rng.integers(0, 6, (n, k_))
        body = rng.integers(0, 4, 6)
        P, A, pos = rng.standard_normal((6, 3)), rng.standard_normal((6, 3, 3)), \
            rng.standard_normal((4, 3))
        ix = K.SlotIndex(markers, ml, kind, body, 2, connection=True)   # sums' targets kept
        fast = K.slot_kinematics(markers, ml, kind, P, A, body, pos, ix)
        slow = K.slot_kinematics(markers, ml, kind, P, A, body, pos)
        assert fast.Y.tobytes() == slow.Y.tobytes() and fast.V.tobytes() == slow.V.tobytes()
        assert slow.rounds is None and (ix.rounds is None) == bool(t % 4 == 0 and n > 1)
        rho, py = rng.standard_normal((n, 3 * s_)), rng.standard_normal((n, 2, 3 * s_))
        assert K.local_residual(fast, rho, k_).tobytes() == \
            K.local_residual(slow, rho, k_).tobytes()
        assert K.constraint_jacobian_local(fast, py, k_).tobytes() == \
            K.constraint_jacobian_local(slow, py, k_).tobytes()
        assert fast.B.tobytes() == slow.B.tobytes()


def test_screw_exp_closed_forms_are_the_series_path():
    rng = np.random.default_rng(5)
    for shape in [(3,), (4, 3), (2, 3, 3)]:
        for scale in (1e-5, 0.3, 3.0):
            w = rng.standard_normal(shape) * scale
            th, Kw, KK = R._axis_parts(w)
            E, V = R.screw_exp(w)
            assert E.tobytes() == R._expm(th, Kw, KK).tobytes()
            assert V.tobytes() == R._left_jacobian(th, Kw, KK).tobytes()
    E, V = R.screw_exp(np.zeros((2, 3)))                # zero angle: the series
    assert np.array_equal(E, np.broadcast_to(np.eye(3), (2, 3, 3)))
    assert np.array_equal(V, np.broadcast_to(np.eye(3), (2, 3, 3)))


def test_lean_is_numpy():
    rng = np.random.default_rng(6)
    for shape in [(3,), (20,), (20, 20), (5, 3)]:
        x = rng.standard_normal(shape) * 10.0 ** rng.integers(-100, 100, shape)
        assert norm(x).tobytes() == np.linalg.norm(x).tobytes()
        assert row_norms(x).tobytes() == np.linalg.norm(x, axis=-1).tobytes()
    assert all_finite(np.zeros(0)) and all_finite(np.ones((2, 3)))
    assert not all_finite(np.array([1.0, np.nan])) and not all_finite(np.array([[np.inf]]))


def test_lean_decompositions_are_numpy():
    from poise.core import lean
    rng = np.random.default_rng(7)
    for n in (1, 6, 38):
        a = rng.standard_normal((n, n))
        s = a + a.T
        for got, ref in zip(lean.svd(a), np.linalg.svd(a)):
            assert got.tobytes() == ref.tobytes()
        for got, ref in zip(lean.eigh(s), np.linalg.eigh(s)):
            assert got.tobytes() == ref.tobytes()
        assert lean.eigvalsh(s).tobytes() == np.linalg.eigvalsh(s).tobytes()
    bad = np.full((4, 4), np.nan)
    for f in (lean.svd, lean.eigh, lean.eigvalsh):      # numpy's error, not NaNs
        with pytest.raises(np.linalg.LinAlgError):
            f(bad)


def test_lean_solves_and_joins_are_numpy():
    """``solve`` (one right-hand side or columns), ``cholesky`` and ``concatenate``: numpy's
    results bit for bit (empty systems too) and numpy's errors."""
    from poise.core import lean
    rng = np.random.default_rng(8)
    for n in (0, 1, 6, 38):
        a = rng.standard_normal((n, n))
        spd = a @ a.T + n * np.eye(n)
        for b in (rng.standard_normal(n), rng.standard_normal((n, 3))):
            assert lean.solve(a, b).shape == b.shape
            assert lean.solve(a, b).tobytes() == np.linalg.solve(a, b).tobytes()
        assert lean.cholesky(spd).tobytes() == np.linalg.cholesky(spd).tobytes()
        parts = (a, spd[:1], np.zeros((0, n)))
        assert np.array_equal(lean.concatenate(parts), np.concatenate(parts))
    with pytest.raises(np.linalg.LinAlgError):
        lean.solve(np.zeros((3, 3)), np.ones(3))                  # exactly singular
    with pytest.raises(np.linalg.LinAlgError):
        lean.cholesky(-np.eye(3))                                 # not positive definite
    assert lean.solve(np.eye(2, dtype=np.float32), np.ones(2)).tolist() == [1.0, 1.0]  # numpy's


def test_phi_q_jacobian_is_the_jacobian_without_tangents():
    """The static prologue's evaluation: the constraint blocks and the residual bit for bit
    those of the full Jacobian, no stiffness in the coordinate block."""
    from poise.app.api import solve
    from poise.app import deck_cache
    from poise.model.evaluate import evaluate
    from support.paths import DECKS
    deck_cache.clear()
    solve(str(DECKS / "fourbar_spring.xml"), quiet=True)
    model = next(iter(next(iter(deck_cache._entries.values())).models.values()))
    st = model.initial_state()
    st.lam = np.linspace(-2.0, 3.0, model.nc)
    full, part = evaluate(model, st, "jacobian"), evaluate(model, st, "phi_q")
    nq = model.nq
    assert part.r.tobytes() == full.r.tobytes() and part.phi.tobytes() == full.phi.tobytes()
    assert part.J[nq:].tobytes() == full.J[nq:].tobytes()
    assert part.J[:nq, nq:].tobytes() == full.J[:nq, nq:].tobytes()
    assert not np.any(part.J[:nq, :nq]) and np.abs(full.J[:nq, :nq]).max() > 0
    deck_cache.clear()


def test_euler_parameters_are_the_formula_sums():
    """The gathered form adds the same entries in the same order as the written formula."""
    rng = np.random.default_rng(7)
    Rs = R.expm_so3(rng.standard_normal((50, 3)) * 3.0)
    Rs = np.concatenate([Rs, R.expm_so3(np.array([[np.pi, 0, 0], [0, 0, np.pi]])), np.eye(3)[None]])
    d0, d1, d2 = Rs[:, 0, 0], Rs[:, 1, 1], Rs[:, 2, 2]
    diag = np.stack([1 + d0 + d1 + d2, 1 + d0 - d1 - d2, 1 - d0 + d1 - d2, 1 - d0 - d1 + d2], 1)
    k = np.argmax(diag, axis=1)
    q = R.euler_parameters(Rs)
    # the largest |q_k| comes from its own diagonal entry: 4 q_k^2 = diag_k
    qk = q[np.arange(len(Rs)), k]
    assert np.allclose(4 * qk ** 2, diag[np.arange(len(Rs)), k], rtol=1e-12, atol=1e-15)
    assert np.allclose(R.expm_so3(R.rotation_vector(Rs)), Rs, atol=1e-12)
    assert np.all((q[:, 0] > 0) | ((q[:, 0] == 0) & (q[:, 1:] != 0).any(axis=1)))


def _many_instances(rng, n, mixed, other):
    """Slot kinematics of ``n`` random instances (1-3 markers, 1-5 slots, points and axes;
    ``mixed``: the first slot is a point in every other instance, an axis ``other`` else)."""
    k_, s_ = int(rng.integers(1, 4)), int(rng.integers(1, 6))
    ml = rng.integers(0, k_, s_)
    kind = np.where(rng.random((1, s_)) < 0.5, 0, rng.integers(1, 4, (1, s_))).repeat(n, 0)
    if mixed:
        kind[::2, 0], kind[1::2, 0] = 0, other
    markers = rng.integers(0, 9, (n, k_))
    body = rng.integers(-1, 5, 9)
    P, A, pos = rng.standard_normal((9, 3)), rng.standard_normal((9, 3, 3)), \
        rng.standard_normal((5, 3))
    return K.slot_kinematics(markers, ml, kind, P, A, body, pos), k_, s_


def test_entry_major_constraint_jacobian_is_the_instance_major_one():
    # made component by component over the instances (and chunk by chunk, with removed rows)
    # it is the same bits as constraint_jacobian_local's entries
    from poise.elements.chunked import constraint_values
    rng = np.random.default_rng(5)
    for t in range(12):
        n, m = 700 + t, 1 + t % 3
        kin, k_, s_ = _many_instances(rng, n, t % 3 == 0, 2)
        py = rng.standard_normal((n, m, 3 * s_))
        py[:, :, ::4] = -0.0
        ref = K.constraint_jacobian_local(kin, py, k_)                 # (n, m, 6K)
        pidx = None if t % 2 else np.flatnonzero(rng.random(m * 6 * k_) < 0.6)
        act = rng.random((n, m)) < (0.9 if t % 4 else 1.1)
        want = (ref * act[:, :, None] if not act.all() else ref).reshape(n, -1)
        want = want if pidx is None else want[:, pidx]
        whole = constraint_values(kin, py, k_, act, pidx, None)
        parts = constraint_values(kin, py, k_, act, pidx, [(0, 300), (300, n)])
        assert whole.tobytes() == np.ascontiguousarray(want).tobytes()
        assert parts.tobytes() == whole.tobytes()


def test_many_instances_local_residual_is_the_slot_loop():
    # from MAJOR_MIN instances the residual is made component-major: the same bits
    rng = np.random.default_rng(6)
    for t in range(8):
        n = 600 + t
        kin, k_, s_ = _many_instances(rng, n, t % 2 == 0, 3)
        rho = rng.standard_normal((n, 3 * s_))
        rho[::3, 1] = -0.0
        big = K.local_residual(kin, rho, k_)
        small = np.concatenate([K.local_residual(K.SlotKinematics(
            Y=kin.Y[a:a + 100], V=kin.V[a:a + 100], pt=kin.pt[a:a + 100], slot_ml=kin.slot_ml,
            K=kin.K), rho[a:a + 100], k_) for a in range(0, n, 100)])
        assert big.shape == (n, 6 * k_) and big.tobytes() == small.tobytes()
