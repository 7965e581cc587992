"""linalg.Factor of a sparse matrix: the pivots are read only when asked (SuperLU's ``.U``
copies both factors), and a singular or non-finite matrix is still refused, naming its row;
factors kept without their matrix solve plainly, as do the unchecked solves."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from poise.solvers.linalg import Factor, SingularMatrix


def test_regular_sparse_factor_solves_and_names_its_smallest_pivot():
    A = sp.csr_matrix(np.diag([4.0, 1e-6, 2.0]) + np.diag([1.0, 1.0], 1))
    f = Factor(A)
    b = np.array([1.0, 2.0, 3.0])
    assert np.allclose(A @ f.solve(b), b, rtol=0, atol=1e-12)
    assert f.pivot_row == 1                  # the 1e-6 pivot, row 1


def test_a_factor_without_its_matrix_solves_plainly():
    """``drop_matrix``: the sparse factors stay, the matrix goes (no refinement residuals),
    and the solves agree with the refined ones; equilibrated factors too. Numpy's small dense
    path keeps its matrix (it solves with it)."""
    rng = np.random.default_rng(3)
    M = sp.random(40, 40, density=0.2, random_state=4) + sp.diags(np.linspace(1.0, 1e3, 40))
    b = rng.standard_normal(40)
    for eq in (False, True):
        f = Factor(sp.csr_matrix(M), equilibrate=eq)
        ref = f.solve(b)
        f.drop_matrix()
        assert f.J is None
        np.testing.assert_allclose(f.solve(b), ref, rtol=1e-12, atol=1e-15)
    d = Factor(M.toarray())
    d.drop_matrix()
    assert d.J is not None and np.allclose(M @ d.solve(b), b)


def test_unchecked_solves_are_the_factors_own():
    """``Factor.unchecked``: the solves without the refinement check, equilibrated or not, for
    every path (sparse, numpy's small dense, LAPACK dense): the checked solve's result when its
    check needs no refinement step, and no residual is formed (the matrix is not read)."""
    rng = np.random.default_rng(5)
    M = sp.random(150, 150, density=0.05, random_state=6) + sp.diags(np.linspace(1.0, 1e3, 150))
    b = rng.standard_normal(150)
    for J in (sp.csr_matrix(M), M.toarray()[:40, :40], M.toarray()):
        for eq in (False, True):
            f = Factor(J, equilibrate=eq)
            bb = b[:J.shape[0]]
            ref = f.solve(bb)
            assert np.allclose(J @ ref, bb, rtol=0, atol=1e-10)
            x = f.unchecked.solve(bb)
            assert x.tobytes() == ref.tobytes()
            if not f.numpy:          # (numpy's small dense path solves with its matrix)
                f.J = None           # no residual can be formed: the same plain solve
                assert f.unchecked.solve(bb).tobytes() == ref.tobytes()


def test_column_ordered_factorisation_from_csr_is_the_selected_one():
    """A matrix with the assembler's column order is factorised as ``J[:, order]``: built from
    the CSR matrix in one conversion, the very matrix the CSC column selection gives (bitwise
    the same solutions), unsorted and duplicate CSR entries included."""
    import scipy.sparse.linalg as spla

    from poise.solvers.linalg import _columns_ordered
    rng = np.random.default_rng(8)
    M = (sp.random(60, 60, density=0.1, random_state=9) + sp.diags(rng.uniform(1, 2, 60))).tocsr()
    order = rng.permutation(60)
    A = _columns_ordered(M, order)
    ref = M.tocsc()[:, order]
    for a, r in ((A.indptr, ref.indptr), (A.indices, ref.indices), (A.data, ref.data)):
        np.testing.assert_array_equal(a, r)
    # unsorted column indices and a duplicate entry in row 0 (summed by neither)
    D = sp.csr_matrix((np.r_[1.0, 2.0, 3.0, 4.0], np.r_[2, 0, 2, 1], np.r_[0, 3, 4]),
                      shape=(2, 3))
    o = np.array([2, 0, 1])
    np.testing.assert_array_equal(_columns_ordered(D, o).toarray(), D.toarray()[:, o])
    M.poise_column_order = lambda: order
    b = rng.standard_normal(60)
    x = Factor(M).solve(b)
    lu = spla.splu(ref, permc_spec="NATURAL")
    y = np.empty(60)
    y[order] = lu.solve(b)
    np.testing.assert_array_equal(x, y)


def test_non_finite_sparse_matrix_refused():
    """At the factorisation (a non-finite pivot) or at the solve (a non-finite solution)."""
    for bad in ([[1.0, 0.0], [0.0, np.nan]], [[np.inf, 1.0], [1.0, 1.0]], [[1.0, np.nan], [0.0, 1.0]]):
        with pytest.raises(SingularMatrix):
            Factor(sp.csr_matrix(np.array(bad))).solve(np.ones(2))


def test_exactly_singular_sparse_matrix_refused():
    A = sp.csr_matrix(np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(SingularMatrix):
        Factor(A)


# ---------------------------------------------------------------- small dense (numpy) path
def _culprit(J):
    return int(np.argmax(np.abs(np.linalg.svd(J)[2][-1])))


def test_small_dense_factor_decides_like_the_singular_values():
    """Regular, graded and (nearly) singular small matrices: refused exactly when
    sigma_min <= 1e-15 sigma_max, naming the row of the weakest singular direction; a regular
    one names that row too when asked (computed on demand)."""
    rng = np.random.default_rng(7)
    U, _ = np.linalg.qr(rng.standard_normal((12, 12)))
    V, _ = np.linalg.qr(rng.standard_normal((12, 12)))
    for smin in (1.0, 1e-8, 1e-12, 1e-14, 1e-16, 1e-18, 0.0):
        J = U @ np.diag(np.r_[np.ones(11), smin]) @ V.T
        sv = np.linalg.svd(J, compute_uv=False)
        singular = sv[-1] <= 1e-15 * sv[0]
        if singular:
            with pytest.raises(SingularMatrix) as e:
                Factor(J)
            assert e.value.row == _culprit(J)
        else:
            f = Factor(J)
            if smin >= 1e-8:
                b = np.arange(12.0)
                assert np.allclose(J @ f.solve(b), b, rtol=0, atol=1e-6)
            assert f.pivot_row == _culprit(J)
        assert singular == (smin <= 1e-16)


def test_small_dense_factor_refuses_non_finite_and_exactly_singular():
    with pytest.raises(SingularMatrix):
        Factor(np.array([[1.0, np.nan], [0.0, 1.0]]))
    with pytest.raises(SingularMatrix) as e:
        Factor(np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]]))
    assert e.value.row in (0, 1)


def test_stored_zeros_are_not_factorised():
    """``stored_nonzeros``: a matrix with stored exact zeros (an assembled pattern's entries
    that are zero for this model) is factorised without them: the same matrix and pivots, the
    factors without the fill those entries would add, and the caller's arrays untouched (they
    may be a reused layout's); a matrix without stored zeros is passed on as it is."""
    from poise.solvers.linalg import stored_nonzeros
    rng = np.random.default_rng(7)
    n = 300
    M = (sp.random(n, n, density=0.01, random_state=8) + sp.diags(np.linspace(1.0, 1e2, n)))
    M = sp.csc_matrix(M)
    # stored zeros: every pair (i, j), (j, i) of a random set, as a block pattern would have
    zi, zj = rng.integers(0, n, 400), rng.integers(0, n, 400)
    Md = M.toarray()
    mask = Md != 0.0
    mask[np.r_[zi, zj], np.r_[zj, zi]] = True
    r, c = np.nonzero(mask)
    A = sp.csc_matrix((Md[r, c], (r, c)), shape=(n, n))   # M's values in a wider pattern
    assert np.count_nonzero(A.data == 0.0) > 500
    data, indices, indptr = A.data.copy(), A.indices.copy(), A.indptr.copy()
    B = stored_nonzeros(A)
    assert np.array_equal(A.data, data) and np.array_equal(A.indices, indices)
    assert np.array_equal(A.indptr, indptr)                        # the caller's arrays
    assert B.nnz == np.count_nonzero(data) and np.all(B.data != 0.0)
    assert (B != A).nnz == 0 and B.has_sorted_indices
    assert stored_nonzeros(B) is B
    full = Factor(A)                                  # (COLAMD path: a plain CSC/CSR matrix)
    plain = Factor(sp.csc_matrix(M))
    assert full.lu.nnz == plain.lu.nnz
    b = rng.standard_normal(n)
    np.testing.assert_allclose(full.solve(b), plain.solve(b), rtol=1e-12, atol=1e-14)
    assert np.allclose(A @ full.solve(b), b, rtol=0, atol=1e-10)
