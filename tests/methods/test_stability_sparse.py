"""Sparse stability classification (models with more than ``DENSE_LIMIT`` coordinates).

* the LDL^T inertia helper against numpy ``eigh`` on random sparse symmetric matrices;
* with ``DENSE_LIMIT`` patched to 0 (every model on the sparse path), the same class, negative
  and zero counts as the dense path on stable, neutral, unstable (one and two negative
  eigenvalues), redundant, scalar-unknown, contact and stiff/soft models;
* real large models (600-link chains, 3600 coordinates > 3000): hanging (stable), hanging with
  spherical joints (600 neutral spins, each named by its link and axis) and upside down at
  the compressed catenary (598 unstable modes);
* a factorisation that cannot be trusted gives ``unknown`` with the reason, never a class.
"""
import numpy as np
import pytest
import scipy.sparse as sp

import poise.solvers.stability as stab
import poise.solvers.stability_sparse as stab_sparse
from poise.app.api import run_deck
from poise.gen.chain import build_chain_deck

from poise.gen.deck import Deck, rot_y, rot_z
from support.builders import stiff_soft_deck

from support.paths import DECKS


# ------------------------------------------------------------------ LDL^T inertia helper
def _random_symmetric(rng, n):
    A = sp.random(n, n, density=rng.uniform(0.05, 0.4), random_state=int(rng.integers(1 << 30)))
    A = (A + A.T) * rng.uniform(0.1, 10.0)
    d = rng.normal(size=n) * rng.choice([1e-3, 1.0, 100.0], size=n)
    return (A + sp.diags(d)).tocsc()


def test_ldlt_inertia_matches_eigh_on_random_sparse_matrices():
    rng = np.random.default_rng(1234)
    checked = 0
    for _ in range(300):
        n = int(rng.integers(1, 60))
        A = _random_symmetric(rng, n)
        w = np.linalg.eigvalsh(A.toarray())
        ref = (int(np.sum(w < 0)), 0, int(np.sum(w > 0)))
        for order in (None, rng.permutation(n)):
            F = stab.SymmetricLDL(A, order)
            assert F.ok, F.reason                     # non-zero diagonal: always a 1x1 pivot path
            if F.backward_error < np.abs(w).min():    # Weyl: then the counted inertia is exact
                assert F.inertia == ref, (n, F.inertia, ref)
                checked += 1
            x = np.arange(1.0, n + 1)
            if F.backward_error < 1e-10 * np.abs(w).min():
                np.testing.assert_allclose(A @ F.solve(x), x, rtol=1e-6, atol=1e-6)
    assert checked > 500


def test_ldlt_indefinite_kkt_and_refusals():
    # [[k, g], [g, 0]] (one negative, one positive eigenvalue): fine when the zero comes last
    A = sp.csc_matrix(np.array([[2.0, 1.0], [1.0, 0.0]]))
    F = stab.SymmetricLDL(A, np.array([0, 1]))
    assert F.ok and F.inertia == (1, 0, 1)
    # a zero pivot first: an off-diagonal pivot would be needed -> not a valid LDL^T
    F = stab.SymmetricLDL(sp.csc_matrix(np.array([[0.0, 1.0], [1.0, 0.0]])), np.array([0, 1]))
    assert not F.ok and "off-diagonal pivot" in F.reason
    # a tiny first pivot: valid factors, but the backward-error estimate exposes the growth
    F = stab.SymmetricLDL(sp.csc_matrix(np.array([[1e-12, 1.0], [1.0, 1.0]])), np.array([0, 1]))
    assert F.ok and F.backward_error > 1e-5


def test_ldlt_backward_error_empties_the_factor_copies_and_leaves_the_solves():
    # the estimate reads SciPy's cached CSC copies of L and U once and empties both (the
    # documented effect); the solves, which use SuperLU's own factors, give the same bits
    rng = np.random.default_rng(7)
    A = _random_symmetric(rng, 40)
    F = stab.SymmetricLDL(A, rng.permutation(40))
    assert F.ok and F.lu.L.nnz > 0 and F.lu.U.nnz > 0
    x = np.arange(1.0, 41.0)
    before = F.solve(x)
    berr = F.backward_error
    assert np.isfinite(berr) and berr > 0.0 and F.backward_error == berr
    for M in (F.lu.L, F.lu.U):
        assert M.shape == (40, 40) and M.nnz == 0 and M.indptr.size == 41
    assert np.array_equal(F.solve(x), before)


def test_ldlt_head_solves_are_the_full_solves_bit_for_bit():
    # ``solve_head`` (the mode operators): the right-hand side ``[v; 0]`` made in the
    # factorisation's order and the head of the solution gathered back, in groups of columns,
    # is ``solve`` of the zero-padded right-hand side to the last bit; so is the backward error
    # with or without the pivots read before it
    rng = np.random.default_rng(99)
    for _ in range(20):
        n = int(rng.integers(5, 60))
        A = _random_symmetric(rng, n)
        order = rng.permutation(n)
        F = stab.SymmetricLDL(A, order)
        built = []
        G = stab.SymmetricLDL(lambda A=A, built=built: built.append(1) or A, order)
        assert len(built) == 1 and F.ok == G.ok
        if not F.ok:
            continue
        assert G.inertia == F.inertia and np.array_equal(G.pivots, F.pivots)
        assert G.backward_error == F.backward_error > 0.0
        k = int(rng.integers(1, n + 1))
        for cols in ((), (1,), (3,), (9,)):
            v = rng.normal(size=(k,) + cols)
            b = np.zeros((n,) + cols)
            b[:k] = v
            x = F.solve(b)[:k]
            assert np.array_equal(F.solve_head(v, k), x)
            assert np.array_equal(F.solve(b.copy(), overwrite_b=True)[:k], x)
        P = stab.SymmetricLDL(A, None)
        if P.ok:
            v = rng.normal(size=(k, 5))
            b = np.zeros((n, 5))
            b[:k] = v
            assert np.array_equal(P.solve_head(v, k), P.solve(b)[:k])


def _unsorted(M, rng):
    """``M`` (CSR) with the entries of every row in a random order (as a sparse product gives)."""
    M = M.tocsr()
    idx, dat = M.indices.copy(), M.data.copy()
    for r in range(M.shape[0]):
        a, b = M.indptr[r], M.indptr[r + 1]
        p = a + rng.permutation(b - a)
        idx[a:b], dat[a:b] = M.indices[p], M.data[p]
    out = sp.csr_matrix((dat, idx, M.indptr.copy()), shape=M.shape)
    out.has_sorted_indices = False
    return out


def test_permuted_kkt_is_the_permuted_block_matrix_bit_for_bit():
    # the pencil's KKT matrix written straight into its elimination order is the very CSC
    # matrix (values, row indices in each column, column pointers) that the block matrix
    # permuted by fancy indexing gives: unsorted constraint rows, entries that cancel (dropped
    # by the sparse sum), a diagonal equal to the shift, no constraint rows at all
    rng = np.random.default_rng(7)
    for trial in range(40):
        nq = int(rng.integers(1, 40))
        m = 0 if trial % 5 == 0 else int(rng.integers(1, nq + 1))
        Kt = _random_symmetric(rng, nq).tocsr()
        Gt = sp.random(m, nq, density=rng.uniform(0.05, 0.5), format="csr",
                       random_state=int(rng.integers(1 << 30)))
        P = stab_sparse.SparsePencil.__new__(stab_sparse.SparsePencil)
        P.nq, P.m, P._pos = nq, m, None
        P.order = rng.permutation(nq + m)
        P.Gt = _unsorted(Gt, rng) if trial % 2 else Gt
        P._GtG, P._Gc, P.lean = (Gt.T @ Gt).tocsr(), None, bool(trial % 2)
        s, rho = float(rng.normal()), float(rng.choice([1.0, 16.0, 1.0 / 16.0]))
        if trial % 3 == 0 and P.GtG.nnz:             # cancellations: K = -rho GtG, diag = s
            GtG = (Gt.T @ Gt).tocsr()
            K = (-rho * GtG).tolil()
            K[0, 0] = s + rho * GtG[0, 0]
            Kt = K.tocsr()
        P.Kt = Kt
        ref = stab_sparse.symmetric_permutation(P.kkt(s, rho), P.order)
        got = P.permuted_kkt(s, rho)                  # (a lean pencil makes Gt^T Gt again)
        assert np.array_equal(P.permuted_kkt(s, rho).data, got.data)
        for a in ("data", "indices", "indptr"):
            assert np.array_equal(getattr(got, a), getattr(ref, a)), (trial, a)


def test_gtg_is_scipys_product_bit_for_bit():
    # the pencil's Gt^T Gt (its rows times Gt, indices sorted in place) is the very CSR matrix
    # scipy's product converted to CSR gives: sorted and unsorted Gt, empty rows and columns,
    # no constraint rows; the CSC kept beside it is Gt's
    rng = np.random.default_rng(5)
    for trial in range(40):
        nq = int(rng.integers(1, 40))
        m = 0 if trial % 7 == 0 else int(rng.integers(1, 2 * nq + 1))
        Gt = _random_csr(rng, m, nq, 0.02, 0.5)
        P = stab_sparse.SparsePencil.__new__(stab_sparse.SparsePencil)
        P.Gt = _unsorted(Gt, rng) if trial % 2 else Gt
        P._GtG = P._Gc = None
        ref = (P.Gt.T @ P.Gt).tocsr()
        got = P.GtG
        assert got.format == "csr" and got.has_sorted_indices
        for a in ("data", "indices", "indptr"):
            assert np.array_equal(getattr(got, a), getattr(ref, a)), (trial, a)
        assert (P.Gc != Gt.tocsc()).nnz == 0


def _random_csr(rng, nr, nc, lo, hi):
    return sp.random(nr, nc, density=rng.uniform(lo, hi), format="csr",
                     random_state=int(rng.integers(1 << 30)))


def test_diagonal_scaling_is_scipys_products_bit_for_bit():
    # the pencil's scaled blocks (diag(r) M diag(c), and the Jacobian's blocks M diag(c)) are
    # the very CSR arrays that scipy's sparse products give (one product: the same entries in
    # M's sorted order, where scipy reverses each row): exact zeros dropped (explicit zeros,
    # products that underflow), empty first/last rows, int dtypes
    rng = np.random.default_rng(11)
    for trial in range(60):
        n, k = int(rng.integers(1, 30)), int(rng.integers(1, 30))
        M = _random_csr(rng, n, k, 0.0, 0.6)
        if M.nnz and trial % 3 == 0:
            M.data[rng.random(M.nnz) < 0.3] = 0.0          # explicit zeros in the pattern
        if M.nnz and trial % 4 == 1:
            M.data[0] = 1e-300                             # (1e-300 r) c underflows to 0
        r = rng.uniform(0.1, 10.0, n) * (1e-20 if trial % 4 == 1 else 1.0)
        c = rng.uniform(0.1, 10.0, k) * (1e-20 if trial % 4 == 1 else 1.0)
        ref = (sp.diags(r) @ M @ sp.diags(c)).tocsr()
        got = stab_sparse._diag_scaled(M, r, c)
        ref1 = (M @ sp.diags(c)).tocsr()
        ref1.sort_indices()
        got1 = stab_sparse._scaled_block(M.copy(), None, c)
        for g, f in ((got, ref), (got1, ref1)):
            for a in ("data", "indices", "indptr"):
                x, y = getattr(g, a), getattr(f, a)
                assert x.dtype == y.dtype and np.array_equal(x, y), (trial, a)


def _kkt_blocks(rng, trial):
    """A random stiffness ``Ks`` (n x n) and constraint rows ``G`` (m x n, maybe none), CSR,
    entries of either sign over 16 decades: empty rows, a long row, an empty ``Ks``."""
    n, m = int(rng.integers(1, 40)), int(rng.integers(0, 30)) * (trial % 5 != 0)
    Ks = _random_csr(rng, n, n, 0.0 if trial % 7 == 0 else 0.02, 0.3)
    G = _random_csr(rng, m, n, 0.02, 0.3)
    if m and trial % 4 == 0:
        G = sp.vstack([G, sp.csr_matrix(np.ones((1, n)))]).tocsr()   # one long row
    for M in (Ks, G):
        M.data *= rng.choice([-1.0, 1.0], size=M.nnz) * 10.0 ** rng.uniform(-8, 8, M.nnz)
    return Ks, G


def _ruiz_reference(Ks, G, start=None, iters=12, tol=0.1):
    """The equilibration written plainly on the assembled KKT matrix (its rows' maxima of
    ``(|m_ij| D_i) D_j`` by ``np.maximum.at``)."""
    from poise.solvers.equilibrate import coordinate_caps
    nq = Ks.shape[0]
    M = sp.bmat([[Ks, G.T], [G, None]], format="csr") if G.shape[0] else Ks
    n = M.shape[0]
    rows = np.repeat(np.arange(n), np.diff(M.indptr))
    a = np.abs(M.data)
    cap = coordinate_caps(Ks)
    D = np.ones(n) if start is None else np.concatenate(start)
    D[:nq] = np.minimum(D[:nq], cap)
    for _ in range(iters):
        r = np.zeros(n)
        np.maximum.at(r, rows, (a * D[rows]) * D[M.indices])
        r[r <= 0.0] = 1.0
        rq = r[:nq]
        rq[(D[:nq] >= cap) & (rq < 1.0)] = 1.0
        if np.abs(r - 1.0).max() <= tol:
            break
        D = D / np.sqrt(r)
        D[:nq] = np.minimum(D[:nq], cap)
    return D[:nq], D[nq:]


def test_equilibration_is_the_plain_ruiz_scaling_bit_for_bit(monkeypatch):
    # the KKT rows' scaled maxima, the coordinates' rows grouped by pattern and the constraint
    # rows by length (a few patterns) or the assembled matrix reduced by segments (many), in
    # passes of any size, are the maxima of the products (|m_ij| D_i) D_j to the last bit,
    # on the unknowns renumbered; and the factors are those of the plain Ruiz iteration on the
    # assembled matrix (from ones, and from given factors)
    import poise.solvers.equilibrate as eqm
    rng = np.random.default_rng(3)
    moved = 0
    for trial in range(40):
        Ks, G = _kkt_blocks(rng, trial)
        nq, n = Ks.shape[0], Ks.shape[0] + G.shape[0]
        M = sp.bmat([[Ks, G.T], [G, None]], format="csr") if G.shape[0] else Ks
        D = 10.0 ** rng.uniform(-4, 4, n)
        rows = np.repeat(np.arange(n), np.diff(M.indptr))
        ref = np.zeros(n)
        np.maximum.at(ref, rows, (np.abs(M.data) * D[rows]) * D[M.indices])
        start = (10.0 ** rng.uniform(-2, 2, nq), 10.0 ** rng.uniform(-2, 2, n - nq))
        want = [_ruiz_reference(Ks, G), _ruiz_reference(Ks, G, start)]
        moved += bool(np.any(np.concatenate(want[0]) != 1.0))      # (the scaling did work)
        for lengths in (1 << 20, 0):                      # grouped by pattern, by segments
            monkeypatch.setattr(eqm, "MAX_LENGTHS", lengths)
            for passes in (eqm.PASS_ENTRIES, int(rng.integers(1, 12))):
                monkeypatch.setattr(eqm, "PASS_ENTRIES", passes)
                rm = eqm._KKTRows(Ks, G)
                assert rm.padded == (lengths > 0)
                assert np.array_equal(np.sort(rm.order), np.arange(n))
                assert np.all(rm.order[:nq] < nq)          # the coordinates first
                r = np.zeros(n)
                rm.into(r, D[rm.order], eqm._Scratch())
                assert np.array_equal(r, ref[rm.order]), (trial, lengths, passes)
                for w, got in zip(want, (eqm.equilibrate(Ks, G), eqm.equilibrate(Ks, G, start=start))):
                    assert all(np.array_equal(x, y) for x, y in zip(got, w)), (trial, lengths)
            monkeypatch.undo()
    assert moved >= 30


# ------------------------------------------------------------------ sparse == dense
def _both(monkeypatch, run):
    """Run twice: dense (default) and with every model on the sparse path."""
    dense = run()
    monkeypatch.setattr(stab, "DENSE_LIMIT", 0)
    sparse = run()
    monkeypatch.undo()
    out = []
    for a in (dense, sparse):
        assert a.converged, a.message
        d = a.datasets
        n = int(d["frames/n_modes"][0])
        out.append((str(d["frames/stability"][0]), int(d["frames/n_negative"][0]),
                    int(d["frames/n_zero"][0]), str(d["frames/stability_modes"][0]),
                    float(d["frames/min_stiffness_eigenvalue"][0]),
                    [(str(d["modes/class"][k]), int(d["modes/body"][k]),
                      str(d["modes/kind"][k]), d["modes/direction"][k]) for k in range(n)]))
    return out


def _deck_file(name, **over):
    return lambda: run_deck(str(DECKS / name), overrides=over or None).analyses[0]


def inverted_double_pendulum():
    """Two 300 mm links standing upright on REVOLUTE joints (axes along Z), started exactly at
    that equilibrium: two negative eigenvalues (both links fall)."""
    d = Deck()
    d.ground()
    R = rot_z(np.pi / 2)                      # link x axis along +Y
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 20, (0, 150, 0), R, mass=1.0, inertia=(5, 7500, 7500))
    d.marker(21, 2, (0, 0, 0))
    d.marker(22, 2, (0, 300, 0))
    d.body(3, 30, (0, 450, 0), R, mass=1.0, inertia=(5, 7500, 7500))
    d.marker(31, 3, (0, 300, 0))
    d.joint(1, "REVOLUTE", 21, 101)
    d.joint(2, "REVOLUTE", 31, 22)
    return d


def universal_inverted_pendulum():
    m, l = 2.0, 400.0
    d = Deck()
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 20, (0, l / 2, 0), rot_z(np.pi / 2), mass=m,
           inertia=(10, m * l * l / 12, m * l * l / 12))
    d.marker(21, 2, (0, 0, 0), rot_y(np.pi / 2))
    d.joint(1, "UNIVERSAL", 21, 101)
    return d


def universal_hanging_pendulum():
    """The pendulum of :func:`universal_inverted_pendulum` hanging: stable, its two swings
    (about the two cross axes) exactly degenerate."""
    m, l = 2.0, 400.0
    d = Deck()
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 20, (0, -l / 2, 0), rot_z(-np.pi / 2), mass=m,
           inertia=(10, m * l * l / 12, m * l * l / 12))
    d.marker(21, 2, (0, 0, 0), rot_y(np.pi / 2))
    d.joint(1, "UNIVERSAL", 21, 101)
    return d


def stiff_soft():
    return stiff_soft_deck()


CASES = {
    # name: (runner, expected (class, n_negative, n_zero))
    "stable_chain": (_deck_file("chain_10.xml"), ("stable", 0, 0)),
    "neutral_spherical_chain": (_deck_file("chain_10_spherical.xml"), ("neutral", 0, 10)),
    "inverted_pendulum_fim_s": (_deck_file("mkeam_inverted_pendulum.xml", method="FIM_S"),
                                ("unstable", 1, 0)),
    "redundant_fourbar": (_deck_file("fourbar_spring.xml"), ("stable", 0, 0)),
    "slider_crank": (_deck_file("slider_crank_load.xml"), ("stable", 0, 0)),
    "scalar_unknown_integrator": (_deck_file("elem_diff_integrator.xml"), ("unstable", 1, 0)),
    "box_on_plane_contact": (_deck_file("contact_box_plane.xml"), ("neutral", 0, 3)),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_sparse_path_matches_dense_on_decks(name, monkeypatch):
    run, expected = CASES[name]
    dense, sparse = _both(monkeypatch, run)
    assert dense[:3] == expected
    assert sparse[:3] == expected
    assert np.sign(dense[4]) == np.sign(sparse[4]) or expected[2] > 0
    if expected[0] == "stable":
        # the lowest Ritz pair of the Krylov iteration is converged: the dense eigh's value
        np.testing.assert_allclose(sparse[4], dense[4], rtol=1e-9)
    if name == "neutral_spherical_chain":
        assert sparse[3].count("neutral: body") == 6 and "neutral: ... 4 more" in sparse[3]
    if name == "inverted_pendulum_fim_s":
        # one degree of freedom: the same mode (the fall about the hinge axis, global Z,
        # sign-normalised), the same value [N/mm]
        for modes in (dense[5], sparse[5]):
            assert [m[:3] for m in modes] == [("unstable", 2, "rotation")]
            np.testing.assert_allclose(modes[0][3], [0.0, 0.0, 1.0], atol=1e-6)
        np.testing.assert_allclose(sparse[4], dense[4], rtol=1e-6)


@pytest.mark.parametrize("make, expected", [
    (inverted_double_pendulum, ("unstable", 2, 0)),
    (universal_inverted_pendulum, ("unstable", 2, 0)),
    (universal_hanging_pendulum, ("stable", 0, 0)),
    (stiff_soft, ("stable", 0, 0)),
])
def test_sparse_path_matches_dense_built(make, expected, monkeypatch, runner):
    dense, sparse = _both(monkeypatch, lambda: runner.api(make(), f"{make.__name__}.xml"))
    assert dense[:3] == sparse[:3] == expected
    if expected[0] == "stable":
        np.testing.assert_allclose(sparse[4], dense[4], rtol=1e-9)
    if expected[1]:
        assert sparse[3].count("unstable: body") == expected[1]
        assert sparse[4] < 0


def test_unreliable_factorisation_gives_unknown_with_reason(monkeypatch):
    monkeypatch.setattr(stab, "DENSE_LIMIT", 0)
    monkeypatch.setattr(stab_sparse, "BERR_MAX", 0.0)          # no factorisation is accurate enough
    a = run_deck(str(DECKS / "chain_10.xml")).analyses[0]
    assert a.converged
    assert a.datasets["frames/stability"][0] == "unknown"
    assert a.datasets["frames/n_negative"][0] == -1 and a.datasets["frames/n_zero"][0] == -1
    msg = str(a.datasets["frames/stability_modes"][0])
    # 60 coordinates + 55 - 3 (redundant) constraint rows
    assert msg.startswith("not classified: sparse inertia of the 112-unknown KKT matrix at "
                          "shift +")
    assert "backward error" in msg and "2 other augmentation weights failed too" in msg


def _solved(path):
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    from poise.app.runner import plan
    from poise.solvers.driver import Driver
    spec = load_deck(str(path))
    model = compile_model(spec)
    req = plan(spec, None)[0]
    drv = Driver(model, req, redundancy=None)
    state, ar = drv.run(model.initial_state(), index=0)
    assert ar.status == "converged"
    return model, state, drv


@pytest.mark.parametrize("name", ["chain_10.xml", "fourbar_spring.xml"])
def test_dependent_active_rows_are_dropped(name):
    """All constraint rows active (3 of them dependent): the KKT matrix is singular; the sparse
    path meets the zero/tiny pivot, finds the dependent rows with the redundancy test and
    classifies as the dense path (SVD null space) does."""
    model, state, drv = _solved(DECKS / name)
    assert len(drv.redundancy) == 3
    J = model.evaluate(state, need_jac=True).J
    dense = stab.classify(model, state, J=J)
    P = stab.SparsePencil(model, J)
    raw = stab.classify_pencil(model, P)
    assert raw.klass == "unknown" and P.singular
    sparse = stab.classify_sparse(model, J)
    assert (sparse.klass, sparse.n_negative, sparse.n_zero) == \
        (dense.klass, dense.n_negative, dense.n_zero) == ("stable", 0, 0)


def test_describe_vectorised_matches_per_body_loop():
    """``describe_mode`` (vectorised) names the same body and motion as the per-body loop it
    replaced, on rigid and point bodies."""
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model

    def loop(model, q):
        part = []
        for b in range(model.nb):
            o = model.body_off[b]
            t = q[o:o + 3]
            r = q[o + 3:o + 6] * model.body_scale[b] if model.body_kind[b] == 0 else np.zeros(3)
            part.append(np.linalg.norm(t) ** 2 + np.linalg.norm(r) ** 2)
        return int(model.body_id[int(np.argmax(part))])

    rng = np.random.default_rng(5)
    for name in ("chain_10.xml", "elem_point_springs.xml", "elem_point_pendulum.xml"):
        model = compile_model(load_deck(str(DECKS / name)))
        for _ in range(50):
            q = rng.normal(size=model.nq) * rng.choice([1e-3, 1.0, 1e3], size=model.nq)
            assert stab.describe_mode(model, q).body == loop(model, q)


# ------------------------------------------------------------------ real large models
def _chain(tmp_path, n, joint, up=False):
    txt = build_chain_deck(n, joint)
    if up:    # gravity +Y: the input arc relaxes to the compressed (inverted) catenary
        txt = txt.replace('grav_y="-9810."', 'grav_y="9810."')
    p = tmp_path / f"chain_{n}_{joint}_{'up' if up else 'down'}.xml"
    p.write_text(txt)
    a = run_deck(str(p)).analyses[0]
    assert a.converged, a.message
    return a


def test_large_hanging_chain_is_stable(tmp_path):
    a = _chain(tmp_path, 600, "revolute")               # 3600 coordinates > DENSE_LIMIT
    assert 6 * 600 > stab.DENSE_LIMIT
    d = a.datasets
    assert (d["frames/stability"][0], d["frames/n_negative"][0], d["frames/n_zero"][0]) == \
        ("stable", 0, 0)
    assert d["frames/stability_modes"][0] == ""
    # the lowest mode of a hanging chain: soft, but clearly positive (about 1.8e-3 N/mm)
    assert 1e-4 < d["frames/min_stiffness_eigenvalue"][0] < 1e-2


def test_large_spherical_chain_is_neutral_with_each_spin_named(tmp_path):
    a = _chain(tmp_path, 600, "spherical")
    d = a.datasets
    assert (d["frames/stability"][0], d["frames/n_negative"][0], d["frames/n_zero"][0]) == \
        ("neutral", 0, 600)
    modes = str(d["frames/stability_modes"][0]).split("; ")
    assert len(modes) == 7 and modes[-1] == "neutral: ... 594 more"
    assert d["frames/n_modes"][0] == 6
    ids = list(d["bodies/id"])
    for k in range(6):
        # the spin of link K about its own axis (a unit vector along the link's x axis)
        assert (d["modes/class"][k], d["modes/kind"][k]) == ("neutral", "rotation")
        ax = d["modes/direction"][k]
        x_link = d["bodies/orientation"][0, ids.index(int(d["modes/body"][k]))][:, 0]
        assert abs(np.linalg.norm(ax) - 1.0) < 1e-12
        assert abs(abs(ax @ x_link) - 1.0) < 1e-3, (ax, x_link)
    assert abs(d["frames/min_stiffness_eigenvalue"][0]) < 1e-10


def test_large_chain_upside_down_is_unstable(tmp_path):
    a = _chain(tmp_path, 600, "revolute", up=True)
    d = a.datasets
    assert d["bodies/position"][0][:, 1].max() < 0          # still below the supports
    # every in-plane degree of freedom (N - 2) buckles the compressed chain
    assert (d["frames/stability"][0], d["frames/n_negative"][0], d["frames/n_zero"][0]) == \
        ("unstable", 598, 0)
    modes = str(d["frames/stability_modes"][0]).split("; ")
    assert len(modes) == 7 and modes[-1] == "unstable: ... 592 more"
    assert d["frames/n_modes"][0] == 6
    for k in range(6):
        assert (d["modes/class"][k], d["modes/kind"][k]) == ("unstable", "rotation")
        # in-plane: about Z (sign-normalised: +Z)
        assert d["modes/direction"][k][2] > 0.995
        assert d["modes/eigenvalue"][k] < 0
    assert d["frames/min_stiffness_eigenvalue"][0] < 0


@pytest.mark.parametrize("name", ["chain_10.xml", "fourbar_spring.xml"])
def test_dense_pencil_inertia_matches_sparse_pencil(name):
    """The descent's dense pencil (small models) and the sparse one count the same inertia of
    the shifted KKT matrix at shifts below, at and above the reduced stiffness' spectrum, and
    solve the same system."""
    from poise.solvers.pencil_dense import DensePencil
    model, state, drv = _solved(DECKS / name)
    active = np.ones(model.nc, bool)
    active[np.asarray(drv.redundancy, int)] = False
    J = model.evaluate(state, need_jac=True, active=active).J
    Pd, Ps = DensePencil(model, J, active=active), stab.SparsePencil(model, J, active=active)
    assert Pd.m == Ps.m and np.array_equal(Pd.rows, Ps.rows)
    Kr = Pd.Kt                                   # scaled stiffness: its spread sets the shifts
    top = float(np.max(np.abs(np.linalg.eigvalsh(Kr))))
    seen = set()
    for s in (-2.0 * top, -1e-3 * top, 0.0, 1e-3 * top, 2.0 * top):
        Fd, Fs = Pd.ldl(s, 1.0), Ps.ldl(s, 1.0)
        if not Fs.ok:
            continue
        assert Fd.ok and Fd.n_negative == Fs.n_negative
        seen.add(Fd.n_negative - Pd.m)
        b = np.random.default_rng(3).standard_normal(Pd.nq + Pd.m)
        xd = Fd.solve(b)
        assert np.allclose(Pd.kkt(s, 1.0) @ xd, b, atol=1e-8 * np.abs(b).max())
    assert len(seen) >= 2          # both a positive definite and an indefinite reduced matrix



@pytest.mark.parametrize("joint, up, expected", [("revolute", False, ("stable", 0, 0)),
                                                 ("spherical", False, ("neutral", 0, 100)),
                                                 ("revolute", True, ("unstable", 98, 0))])
def test_elimination_order_from_the_solves_column_order(tmp_path, joint, up, expected):
    """The sparse classification ranks the bodies as the solve's KKT column order does (no
    minimum-degree ordering of its own): every constraint row still comes after each body it
    acts on, and the inertia and the lowest eigenvalue are those of its own order's."""
    txt = build_chain_deck(100, joint)
    if up:
        txt = txt.replace('grav_y="-9810."', 'grav_y="9810."')
    p = tmp_path / "chain.xml"
    p.write_text(txt)
    model, state, drv = _solved(p)
    assert not model.assembler.dense and model.nq > stab.DENSE_LIMIT
    active = drv.data.mask(model)
    J = model.evaluate(state, need_jac=True, eps_mass=0.0).J
    columns = model.assembler.column_order()
    P = stab_sparse.SparsePencil(model, J, active=active, kkt_columns=columns)
    assert sorted(P.order) == list(range(P.nq + P.m))
    grp = stab_sparse._coordinate_groups(model)
    at = np.argsort(P.order)
    last = np.zeros(int(grp.max()) + 1, np.int64)
    np.maximum.at(last, grp, at[:P.nq])           # each body's last coordinate
    G = P.Gt.tocsr()
    for i in range(P.m):
        acts = grp[G.indices[G.indptr[i]:G.indptr[i + 1]]]
        assert at[P.nq + i] > last[acts].max()
    a = stab_sparse.classify_sparse(model, J, active)
    b = stab_sparse.classify_sparse(model, J, active, kkt_columns=columns)
    assert (a.klass, a.n_negative, a.n_zero) == (b.klass, b.n_negative, b.n_zero) == expected
    np.testing.assert_allclose(b.min_eigenvalue, a.min_eigenvalue, rtol=1e-9, atol=1e-12)


def test_untrusted_count_in_the_solves_order_retries_in_the_pencils_own(tmp_path, monkeypatch):
    """A count the solve's column order does not give reliably is retried in the pencil's own
    minimum-degree order before the frame is called unknown."""
    p = tmp_path / "chain.xml"
    p.write_text(build_chain_deck(100, "revolute"))
    model, state, drv = _solved(p)
    active = drv.data.mask(model)
    J = model.evaluate(state, need_jac=True, eps_mass=0.0).J
    columns = model.assembler.column_order()
    own = stab_sparse.SparsePencil(model, J, active=active).order
    seen = []
    real = stab_sparse.classify_pencil

    def first_fails(m, P):
        seen.append(P.order)
        if len(seen) == 1:
            return stab.not_classified("not reliable (test)")
        return real(m, P)
    monkeypatch.setattr(stab_sparse, "classify_pencil", first_fails)
    info = stab_sparse.classify_sparse(model, J, active, kkt_columns=columns)
    assert len(seen) == 2 and np.array_equal(seen[1], own)
    assert (info.klass, info.n_negative, info.n_zero) == ("stable", 0, 0)
