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


def _chain_phi_q(links):
    """Phi_q of a ``links``-link hanging chain (both ends pinned: 3 redundant equations) at its
    start (the arc through both pins), the model and its redundant rows."""
    import tempfile
    from pathlib import Path

    from poise.deck.parser import load_deck
    from poise.gen.chain import build_chain_deck
    from poise.model.compile import compile_model
    from poise.solvers.redundancy import detect_redundancy
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "chain.xml"
        p.write_text(build_chain_deck(links, "revolute"))
        model = compile_model(load_deck(p))
    state = model.initial_state()
    red = detect_redundancy(model, state)
    J = model.evaluate(state, need_jac=True).J
    return model, sp.csr_matrix(J[model.nq:, :model.nq]), red


def test_left_null_basis_of_a_long_loop_is_accurate():
    """The coefficients of the removed rows on the kept ones come from normal equations, which
    square the loop's condition: with rotation columns scaled by 1/L and one refinement step
    they match an independent solve of the augmented system [[I, P_i^T], [P_i, 0]] (condition
    not squared), and so do the rows called "not unique". (Unscaled and unrefined, a 3000-link
    chain's basis was 8 % off, a 10^4-link chain's 96 %, with 13 rows wrongly called unique.)"""
    import scipy.sparse.linalg as spla

    from poise.solvers.redundancy import column_scale, dependent_rows, left_null_basis
    model, P, red = _chain_phi_q(3000)
    assert len(red) == 3
    active = np.ones(P.shape[0], bool)
    active[red] = False
    cs = column_scale(model)
    Y = left_null_basis(P, active, cs)
    # the reference: the same null space through the augmented system (SuperLU, COLAMD)
    Ps = (P @ sp.diags(cs)).tocsr()
    ind = np.flatnonzero(active)
    Pi = Ps[ind]
    K = sp.bmat([[sp.identity(P.shape[1]), Pi.T], [Pi, None]]).tocsc()
    rhs = np.zeros((K.shape[0], len(red)))
    rhs[:P.shape[1]] = -Ps[red].toarray().T
    ref = np.zeros_like(Y)
    ref[red, np.arange(len(red))] = 1.0
    ref[ind] = spla.splu(K).solve(rhs)[P.shape[1]:]
    assert np.abs(Y - ref).max() <= 1e-7 * np.abs(ref).max()
    assert np.abs(Ps.T @ Y).max() <= 1e-12 * np.abs(Ps).max() * np.abs(Y).max()
    assert np.array_equal(dependent_rows(active, Y), dependent_rows(active, ref))
    # the gap the threshold (1e-8 of the largest entry) sits in is clean: no row near it
    share = np.abs(ref).max(axis=1) / np.abs(ref).max()
    assert not np.any((share > 1e-10) & (share < 1e-6))
