"""Gram matrices of the constraint Jacobian (solvers/gram.py): the banded Cholesky's pivots and
solves are those of the matrix (dense references), the candidates taken out of a band solve like
the Gram matrix of the other rows, the least-squares multipliers are the weighted least-squares
solution, and redundancy detection decides the same rows banded or through SuperLU."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import poise.solvers.gram as gram_mod
import poise.solvers.newton as newton_mod
from poise.deck.parser import load_deck
from poise.gen.chain import build_chain_deck
from poise.model.compile import compile_model
from poise.solvers.data import SolveData
from poise.solvers.gram import (BandedCholesky, SymmetricLU, band, banded_gram, gram,
                                least_squares, may_be_banded, projected, scaled, without)
from poise.solvers.reach import coord_weights
from poise.solvers.redundancy import detect_redundancy, without_rows


def _banded_rows(n=60, m=90, width=3, seed=0):
    """A CSR matrix whose row k touches columns near 1.5 k: its Gram matrix is banded."""
    rng = np.random.default_rng(seed)
    rows, cols = [], []
    for k in range(n):
        c = np.unique(np.clip(int(1.5 * k) + rng.integers(-width, width + 1, 4), 0, m - 1))
        rows += [k] * len(c)
        cols += list(c)
    return sp.csr_matrix((rng.standard_normal(len(rows)), (rows, cols)), shape=(n, m))


def _chain(tmp_path, n, shuffle=False):
    text = build_chain_deck(n, "revolute")          # a closed planar loop: 3 redundant rows
    if shuffle:             # the joints in another deck order: the Gram matrix is not banded
        lines = text.splitlines()
        at = [i for i, s in enumerate(lines) if "<Constraint_Joint" in s]
        order = np.random.default_rng(3).permutation(at)
        lines = [lines[order[at.index(i)]] if i in at else s for i, s in enumerate(lines)]
        text = "\n".join(lines)
    p = tmp_path / f"chain_{n}_{int(shuffle)}.xml"
    p.write_text(text)
    return compile_model(load_deck(str(p)))


def test_banded_cholesky_pivots_and_solves_are_those_of_the_matrix():
    P = _banded_rows()
    A = gram(P)
    ab = band(A)
    assert ab is not None and ab.shape[0] <= 8
    F = BandedCholesky(ab)
    D = A.toarray()
    L = np.linalg.cholesky(D)
    np.testing.assert_allclose(F.pivots, np.diag(L) ** 2, rtol=1e-12)
    np.testing.assert_allclose(SymmetricLU(A, "NATURAL").pivots, F.pivots, rtol=1e-10)
    b = np.random.default_rng(1).standard_normal((A.shape[0], 2))
    np.testing.assert_allclose(F.solve(b), np.linalg.solve(D, b), rtol=1e-9, atol=1e-12)


def test_the_banded_gram_diagonal_and_the_scaled_rows_are_those_of_the_matrix():
    P = _banded_rows().tolil()
    P[7, :] = 0.0                                        # an empty row: a zero diagonal
    P = sp.csr_matrix(P)
    w = np.random.default_rng(3).uniform(0.5, 2.0, P.shape[1])
    S = scaled(P, w)
    ref = sp.csr_matrix(P, copy=True)
    ref.data *= w[ref.indices]
    assert np.array_equal(S.data.view(np.int64), ref.data.view(np.int64))
    assert np.array_equal(S.indices, ref.indices) and np.array_equal(S.indptr, ref.indptr)
    A, ab, d = banded_gram(S)
    assert A is None and ab is not None and d[7] == 0.0
    A = gram(S)                                          # made block by block: the same bits
    assert np.array_equal(d.view(np.int64), A.diagonal().view(np.int64))
    assert np.array_equal(ab.view(np.int64), band(A).view(np.int64))
    d[0] = -1.0                                          # a copy, not a view of the band
    assert ab[0, 0] > 0.0


@pytest.mark.parametrize("block", [1, 7, 64, 8192])
def test_the_band_made_block_by_block_is_that_of_the_whole_gram_matrix(monkeypatch, block):
    monkeypatch.setattr(gram_mod, "BLOCK_ROWS", block)
    monkeypatch.setattr(gram_mod, "BLOCKED_ROWS", 0)       # every matrix block by block
    rng = np.random.default_rng(block)
    P = _banded_rows(seed=block)
    zeros = sp.csr_matrix(P, copy=True)                  # far entries stored as explicit zeros:
    zeros.data[zeros.indices > 1.5 * np.repeat(np.arange(60), np.diff(zeros.indptr))] = 0.0
    n = 100                  # a pattern that allows a band, values that do not fill it:
    ind = np.zeros(2 * n - 1, int)                       # rows i > 0: (i, 0) and (i, i)
    ind[2::2] = np.arange(1, n)
    val = np.r_[1.0, np.zeros(2 * n - 2)]
    val[2::2] = 1.0
    val[-2] = 0.1                                         # (n - 1, 0): one far Gram entry
    wide = sp.csr_matrix((val, ind, np.r_[0, np.arange(1, 2 * n, 2)]), shape=(n, n))
    assert gram_mod.may_be_banded(wide) and band(gram(wide)) is None
    for Q in (P, zeros, P[rng.permutation(60)], wide):
        A, ab, d = banded_gram(Q)
        ref = band(gram(Q))
        if ref is None:
            assert ab is None and (A != gram(Q)).nnz == 0
            continue
        assert A is None and ab.flags.f_contiguous
        assert ab.shape == ref.shape and np.array_equal(ab.view(np.int64), ref.view(np.int64))
        assert np.array_equal(d.view(np.int64), ref[0].view(np.int64))


def test_the_pattern_precheck_is_its_bound_on_the_band_and_the_lower_triangle():
    from poise.solvers.gram import BAND_FILL
    rng = np.random.default_rng(4)
    for n, m, width in ((60, 90, 3), (40, 200, 30), (80, 50, 1)):
        P = _banded_rows(n, m, width, seed=n).tolil()
        P[:, ::7] = 0.0                                  # empty columns
        P = sp.csr_matrix(P)
        P.eliminate_zeros()
        for Q in (P, P[rng.permutation(n)]):
            D = Q.toarray() != 0
            used = D.any(axis=0)
            rows = np.arange(n)[:, None]
            lo = np.where(D, rows, n).min(axis=0)[used]
            hi = np.where(D, rows, -1).max(axis=0)[used]
            c = D.sum(axis=0).astype(float)
            bound = n * (int(np.max(hi - lo)) + 1) <= BAND_FILL * (np.sum(c * (c + 1) / 2) + n)
            assert may_be_banded(Q) == bound


def test_the_pattern_precheck_never_refuses_a_banded_gram_matrix():
    for seed in range(6):
        P = _banded_rows(seed=seed)
        for Q in (P, P[np.random.default_rng(seed).permutation(P.shape[0])]):
            if not may_be_banded(Q):
                assert band(gram(Q)) is None
    assert may_be_banded(_banded_rows())
    assert not may_be_banded(_banded_rows()[np.random.default_rng(0).permutation(60)])


def test_band_refuses_a_matrix_whose_band_would_be_mostly_zeros():
    A = sp.identity(200, format="lil")
    A[199, 0] = A[0, 199] = 0.1                      # one far entry: a band of width 199
    assert band(A.tocsr()) is None
    with pytest.raises(ValueError):
        BandedCholesky(np.array([[1.0, -1.0, 1.0], [2.0, 0.0, 0.0]]))   # indefinite


def test_rows_taken_out_of_a_band_solve_like_the_gram_matrix_of_the_others():
    P = _banded_rows(seed=2)
    rows = np.array([7, 8, 30, 59])
    F = BandedCholesky(without(band(gram(P)), rows))
    keep = np.setdiff1d(np.arange(P.shape[0]), rows)
    Pk = P[keep].toarray()
    R = np.random.default_rng(4).standard_normal((P.shape[1], 3))
    got = projected(P, F, R, rows)
    ref = R - Pk.T @ np.linalg.solve(Pk @ Pk.T, Pk @ R)       # projection off the kept rows
    np.testing.assert_allclose(got, ref, atol=1e-10 * np.abs(R).max())
    b = np.asarray(P @ R)
    b[rows] = 0.0
    x = F.solve(b)
    assert np.all(x[rows] == 0.0)
    np.testing.assert_allclose(x[keep], np.linalg.solve(Pk @ Pk.T, b[keep]), rtol=1e-9)


def test_least_squares_is_the_weighted_least_squares_solution():
    rng = np.random.default_rng(5)
    P = _banded_rows(seed=5).tolil()
    active = np.ones(P.shape[0], bool)
    active[[4, 40]] = False
    P[4, :] = 0.0
    P[40, :] = 0.0
    P = P.tocsr()
    w = rng.uniform(0.1, 10.0, P.shape[1])
    g = rng.standard_normal(P.shape[1])
    counted = []
    lam = least_squares(P, w, g, active, lambda A, f: counted.append(1) or f(A))
    Pa = P[np.nonzero(active)[0]].toarray()
    ref = np.linalg.lstsq((Pa * w).T, w * g, rcond=None)[0]     # min || diag(w)(Pa^T l - g) ||
    np.testing.assert_allclose(lam[active], ref, rtol=1e-11, atol=1e-12 * np.abs(ref).max())
    assert np.all(lam[~active] == 0.0) and counted == [1]
    # an empty active row (a singular system): not this route
    assert least_squares(P, w, g, np.ones(P.shape[0], bool), lambda A, f: f(A)) is None


def test_least_squares_by_blocks_reads_the_pattern_width_once(monkeypatch):
    rng = np.random.default_rng(6)
    P = _banded_rows(seed=6)
    w = rng.uniform(0.1, 10.0, P.shape[1])
    g = rng.standard_normal(P.shape[1])
    active = np.ones(P.shape[0], bool)
    ref = least_squares(P, w, g, active, lambda A, f: f(A))
    monkeypatch.setattr(gram_mod, "BLOCKED_ROWS", 0)       # the band made block by block
    calls = []
    real = gram_mod.pattern_width
    monkeypatch.setattr(gram_mod, "pattern_width", lambda *a: calls.append(1) or real(*a))
    got = least_squares(P, w, g, active, lambda A, f: f(A))
    assert calls == [1] and ref is not None and np.array_equal(got, ref)


@pytest.mark.parametrize("shuffle", [False, True])
def test_initial_multipliers_of_a_sparse_chain_are_the_weighted_least_squares_ones(
        tmp_path, monkeypatch, shuffle):
    model = _chain(tmp_path, 120, shuffle)
    assert not model.assembler.dense
    state = model.initial_state()
    state.pos = state.pos + 1e-3 * np.sin(np.arange(state.pos.size)).reshape(state.pos.shape)
    data = SolveData.for_model(model)
    ev = data.evaluate(model, state, "phi_q", every_row=True)
    red = detect_redundancy(model, state, evaluation=ev)
    assert len(red) == 3
    data.set_redundancy(red)
    ev = without_rows(model, ev, data.mask(model))
    Q = -ev.r.copy()
    Pa = ev.J[model.nq:, :model.nq].toarray()[data.mask(model)]
    got = newton_mod.initial_multipliers(model, state, data, ev=ev)
    assert data.factorizations == 1
    # the least-squares optimality condition B (w Q - B^T lam) = 0, B = Pa diag(w), holds to
    # round-off (a dense SVD solution of this loop, condition 7e5, meets it only to 2e-15)
    B = Pa / np.sqrt(coord_weights(model))
    g = Q / np.sqrt(coord_weights(model))
    lam = got.lam[data.mask(model)]
    assert (np.linalg.norm(B @ (g - B.T @ lam))
            <= 1e-15 * np.linalg.norm(B) * np.linalg.norm(g))
    scale = np.abs(lam).max()
    assert np.all(got.lam[red] == 0.0)
    monkeypatch.setattr(newton_mod, "least_squares", lambda *a: None)    # the KKT system
    kkt = newton_mod.initial_multipliers(model, state, data)
    np.testing.assert_allclose(got.lam, kkt.lam, atol=1e-10 * scale)


@pytest.mark.parametrize("n", [120, 1000])
def test_redundancy_of_long_loops_is_the_same_banded_or_through_superlu(tmp_path, monkeypatch,
                                                                        n):
    model = _chain(tmp_path, n)
    state = model.initial_state()
    ev = model.evaluate(state, need_jac=True)
    red = detect_redundancy(model, state, evaluation=ev)
    last = 5 * (n + 1)
    assert list(red) == [last - 3, last - 2, last - 1]   # deck order: the closing joint's rows
    monkeypatch.setattr(gram_mod, "BAND_FILL", 0)            # no band: SuperLU's path
    assert gram_mod.banded_gram(sp.csr_matrix(ev.J[model.nq:, :model.nq]))[1] is None
    assert list(detect_redundancy(model, state, evaluation=ev)) == list(red)


def test_redundancy_of_a_loop_in_another_deck_order(tmp_path):
    model = _chain(tmp_path, 120, shuffle=True)
    state = model.initial_state()
    P = model.evaluate(state, need_jac=True).J[model.nq:, :model.nq]
    assert band(gram(sp.csr_matrix(P))) is None          # SuperLU's path
    red = detect_redundancy(model, state)
    assert len(red) == 3
    active = np.ones(model.nc, bool)
    active[red] = False
    Pa = P.toarray()[active] * np.where(model.q_kind == 1, 1 / model.L, 1.0)
    sv = np.linalg.svd(Pa / np.linalg.norm(Pa, axis=1)[:, None], compute_uv=False)
    assert sv[-1] > 1e-4                                # what is left is of full rank
