"""linalg.Factor of a sparse matrix: the pivots are read only when asked (SuperLU's ``.U``
copies both factors), and a singular or non-finite matrix is still refused, naming its row."""
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


def test_non_finite_sparse_matrix_refused():
    """At the factorisation (a non-finite pivot) or at the solve (a non-finite solution)."""
    for bad in ([[1.0, 0.0], [0.0, np.nan]], [[np.inf, 1.0], [1.0, 1.0]], [[1.0, np.nan], [0.0, 1.0]]):
        with pytest.raises(SingularMatrix):
            Factor(sp.csr_matrix(np.array(bad))).solve(np.ones(2))


def test_exactly_singular_sparse_matrix_refused():
    A = sp.csr_matrix(np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(SingularMatrix):
        Factor(A)
