"""Redundancy detection when pivot ratios do not separate dependent from nearly dependent rows
(very long closed loops): candidates are re-decided by projected, unsquared sines."""
import numpy as np
import scipy.sparse as sp

from poise.solvers.redundancy import _resolve_ambiguous, redundant_rows


def _matrix(seed=0):
    rng = np.random.default_rng(seed)
    base = sp.random(400, 900, density=0.01, random_state=seed, format="csr")
    base = base + sp.hstack([sp.identity(400), sp.csr_matrix((400, 500))]).tocsr()  # full rank
    c = rng.normal(size=400)
    exact = c @ base.toarray()                                 # dependent on the rows above
    u = rng.normal(size=900)
    u -= base.T @ np.linalg.lstsq(base.toarray().T, u, rcond=None)[0]   # orthogonal to them
    u /= np.linalg.norm(u)
    near = exact + 3e-3 * np.linalg.norm(exact) * u            # sine 3e-3: independent
    P = sp.vstack([base, sp.csr_matrix(near), sp.csr_matrix(exact)]).tocsr()
    return P


def test_projected_sines_separate_dependent_from_nearly_dependent_rows():
    P = _matrix()
    dep = _resolve_ambiguous(P, np.array([400, 401]), "NATURAL")
    assert list(dep) == [401]          # the exact combination; the row at sine 3e-3 stays


def test_redundant_rows_keeps_nearly_dependent_row():
    P = _matrix(1)
    red = redundant_rows(P, np.ones(P.shape[1]))
    assert list(red) == [401]
