"""Detection of redundant constraint equations, and the check that the removed ones still hold.

The constraint Jacobian is scaled (rotation columns by 1/L so every coordinate is a length) and
the Gram matrix ``A = Phi_q D^2 Phi_q^T`` is factorised with symmetric diagonal pivoting in the
natural (deck) order. For a positive semi-definite matrix this is Cholesky with a rank test: the
pivot of row k divided by ``A_kk`` is the squared sine of the angle between row k and the span of
the rows before it, so a ratio below ``RATIO_TOL`` marks row k as dependent on earlier rows
(deck order: the later equation is the one removed).
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError
from poise.core.lean import cholesky, solve
from poise.elements.context import row_where
from poise.model.evaluate import Evaluation
from poise.model.evaluate import evaluate as _evaluate
from poise.solvers.gram import (BandedCholesky, SymmetricLU, banded_gram, gram, projected,
                                scaled, without)
from poise.solvers.superlu import lean

RATIO_TOL = 1e-9     # always redundant below this pivot ratio
RATIO_MAX = 1e-5     # never redundant above this pivot ratio
GAP_MIN = 1e3        # a gap of this factor between sorted ratios separates the two groups
SHIFT = 1e-13
ORDERING_NATURAL_MAX = 20000
DENSE_MAX_ROWS = 300     # up to this many rows: numpy Cholesky in deck order (no scipy import)
AMBIGUOUS_MIN = 1e-12    # pivot ratios in [AMBIGUOUS_MIN, RATIO_MAX): re-decided accurately
AMBIGUOUS_MAX = 200      # at most this many candidate rows are re-decided
SINE_TOL = 1e-7          # unsquared sine below which a candidate row is dependent


def redundant_rows(Phi_q, col_scale: np.ndarray) -> np.ndarray:
    """Indices of redundant rows of ``Phi_q`` (nc, nq).

    Parameters
    ----------
    Phi_q : sparse or dense (nc, nq)
    col_scale : (nq,) column scaling (1 for translations, 1/L for rotations)
    """
    nc = Phi_q.shape[0]
    if nc == 0:
        return np.zeros(0, int)
    if nc <= DENSE_MAX_ROWS:
        red = _dense_natural(Phi_q, col_scale)
        if red is not None:
            return red
    P = scaled(Phi_q, col_scale)
    A, ab, d = banded_gram(P)     # banded in deck order: Cholesky in that order
    empty = d <= 1e-300
    dd = np.where(empty, 1.0, d)
    shift = np.where(empty, 1.0, SHIFT * d)
    perm = "NATURAL" if nc <= ORDERING_NATURAL_MAX else "MMD_AT_PLUS_A"
    try:
        if ab is not None:
            F = BandedCholesky(_shifted(ab, shift), own=True)
        else:
            import scipy.sparse as sp  # lazy: sparse systems only
            A = (A + sp.diags(shift)).tocsr()
            F = SymmetricLU(A, perm)
            del A
    except ValueError:
        # fall back to a dense rank-revealing QR (small systems only)
        return _dense_redundant(P.toarray())
    ratio = F.pivots / dd
    del F
    thr = rank_threshold(ratio[~empty])
    red = np.nonzero((ratio < thr) | empty)[0]
    amb = np.nonzero(~empty & (ratio < RATIO_MAX) & (ratio >= AMBIGUOUS_MIN))[0]
    if 0 < len(amb) <= AMBIGUOUS_MAX:
        dep = _resolve_ambiguous(P, np.nonzero(~empty & (ratio < RATIO_MAX))[0], perm, ab)
        if dep is not None:
            out = empty.copy()                  # (np.union1d: a hash of every row)
            out[dep] = True
            red = np.nonzero(out)[0]
    return red


def _shifted(ab, shift):
    """A copy of the band ``ab`` with ``shift`` added to its diagonal (column-major)."""
    ab = ab.copy(order="F")
    ab[0] += shift
    return ab


def _resolve_ambiguous(P, cand, perm, ab=None):
    """Decide which rows ``cand`` (deck order) of the scaled ``P`` are dependent, accurately.

    The Cholesky pivots of the Gram matrix measure dependence by *squared* sines, so in very long
    closed loops rounding lifts dependent rows (1e-8 for a 100 000-link loop) to within a factor
    of a few hundred of independent but nearly dependent rows (4e-6) and no gap separates them.
    Here each candidate row is projected on the complement of the span of the other rows (the
    certainly independent ones) by corrected semi-normal equations — one refinement step gives
    QR-like accuracy — and the projections are orthogonalised in deck order: a candidate whose
    remaining component is below ``SINE_TOL`` of its norm (an unsquared sine) is dependent on
    the rows before it. ``ab``: the band of ``P``'s Gram matrix, if banded (the candidates are
    taken out of it in place, :func:`~poise.solvers.gram.without`), else SuperLU in the order
    ``perm``.
    Returns None if the factorisation fails (the gap rule stands).
    """
    PC = P[cand].toarray()                                          # (c, nq)
    off = None
    try:
        if ab is not None:
            PI, off = P, cand
            F = BandedCholesky(without(ab, cand, own=True), own=True)
        else:
            keep = np.ones(P.shape[0], bool)    # (np.setdiff1d: a hash of every row)
            keep[cand] = False
            PI = P[np.nonzero(keep)[0]]
            F = SymmetricLU(gram(PI), perm)
    except ValueError:
        return None
    R = projected(PI, F, PC.T.copy(), off)                          # (nq, c) residuals
    del F
    norms = np.linalg.norm(PC, axis=1)
    Q = []
    dep = []
    for j, k in enumerate(cand):
        v = R[:, j].copy()
        for _ in range(2):                                          # re-orthogonalised
            for q in Q:
                v -= (q @ v) * q
        nv = float(np.linalg.norm(v))
        if nv <= SINE_TOL * max(norms[j], 1e-300):
            dep.append(int(k))
        else:
            Q.append(v / nv)
    return np.array(dep, int)


def rank_threshold(ratio: np.ndarray) -> float:
    """Pivot-ratio threshold from the largest gap among the small ratios.

    Rounding in long closed loops lifts the pivots of dependent rows above machine precision
    (about 1e-9 for a 10 000-link loop) while independent rows of long loops come close to
    dependence (about 1e-4). Numerical rank is therefore decided by the largest gap (a factor
    >= ``GAP_MIN``) among ratios below ``RATIO_MAX``; without such a gap, ``RATIO_TOL`` applies.
    """
    r = np.sort(ratio[ratio < RATIO_MAX * GAP_MIN])
    r = np.maximum(r, 1e-300)
    thr = RATIO_TOL
    if len(r) >= 2:
        lg = np.log10(r)
        gaps = np.diff(lg)
        k = int(np.argmax(gaps))
        if gaps[k] >= np.log10(GAP_MIN) and r[k] < RATIO_MAX:
            thr = max(thr, float(np.sqrt(r[k] * r[k + 1])))
    elif len(r) == 1 and r[0] < RATIO_MAX * 1e-2:
        thr = max(thr, float(r[0]) * 10)
    return thr


def _dense_natural(Phi_q, col_scale):
    """Small systems: dense Cholesky of the same shifted Gram matrix in deck order (numpy only).

    The pivots ``L_kk**2`` are exactly those of the sparse path; returns None when the shifted
    Gram matrix is not numerically positive definite (the caller then uses the sparse path).
    """
    P = (Phi_q.toarray() if hasattr(Phi_q, "toarray") else np.asarray(Phi_q, float)) * col_scale
    A = P @ P.T
    n = A.shape[0]
    diag = A.reshape(-1)[::n + 1]            # the diagonal, a view (np.diag's entries)
    d = diag.copy()
    empty = d <= 1e-300
    diag += np.where(empty, 1.0, SHIFT * d)
    try:
        Lc = cholesky(A)
    except np.linalg.LinAlgError:
        return None
    ratio = Lc.reshape(-1)[::n + 1] ** 2 / np.where(empty, 1.0, d)
    thr = rank_threshold(ratio[~empty])
    return np.nonzero((ratio < thr) | empty)[0]


def _dense_redundant(P):
    import scipy.linalg as sla
    q, r, piv = sla.qr(P.T, mode="economic", pivoting=True)
    dg = np.abs(np.diag(r))
    rel = (dg / max(dg.max(), 1e-300)) ** 2
    rank = int(np.sum(rel >= rank_threshold(rel)))
    return np.sort(piv[rank:])


def min_norm_multipliers(lam, active, row_weight, Y):
    """Minimum-norm multipliers equivalent to ``lam`` (which is zero on inactive rows).

    Among all ``mu`` with ``Phi_q^T mu = Phi_q^T lam`` returns the one minimising
    ``sum(row_weight * mu**2)``. Uses the left null space of ``Phi_q``: for each redundant row k,
    ``y_k = e_k - Phi_ind-coefficients`` from the normal equations of the independent rows
    (``Y``, :func:`left_null_basis`).
    """
    red = np.nonzero(~active)[0]
    if len(red) == 0:
        return lam
    Wy = row_weight[:, None] * Y
    M = Y.T @ Wy
    mu = lam - Y @ solve(M, Wy.T @ lam)
    return mu


def dependent_rows(active, Y, rel=1e-8) -> np.ndarray:
    """Rows taking part in a dependency (their multipliers are not unique): every row with a
    non-negligible entry in a left null vector of ``Phi_q``, removed or kept (``Y``:
    :func:`left_null_basis`)."""
    if np.all(active):
        return np.zeros(0, int)
    Y = np.abs(Y)
    return np.nonzero(_row_max(Y) > rel * Y.max())[0]


def _row_max(A):
    """``A.max(axis=1)`` of a tall array of a few columns, column by column (numpy's reduction
    along a short inner axis costs ~30 ns an entry: 1.7 ms for 50 000 x 3, this 0.1 ms; the
    same maxima)."""
    if not 0 < A.shape[1] <= 64:
        return A.max(axis=1)
    m = A[:, 0].copy()
    for j in range(1, A.shape[1]):
        np.maximum(m, A[:, j], out=m)
    return m


def left_null_basis(Phi_q, active, col_scale):
    """Columns ``y_k = e_k - (coefficients of row k on the independent rows)`` for each removed
    row k: a basis of the left null space of ``Phi_q`` (``y^T Phi_q = 0``).

    The coefficients solve the normal equations of the independent rows, which square their
    condition: ``col_scale`` (:func:`column_scale`: rotation columns by 1/L; the null space does
    not depend on it) and one step of refinement against ``Phi_q`` keep them
    accurate (unscaled, a 10^4-link chain's came out 96 % off, and 13 joints' reactions were
    called unique that are not)."""
    red = np.nonzero(~active)[0]
    if Phi_q.shape[0] <= DENSE_MAX_ROWS:    # numpy only: no scipy import on small decks
        P = Phi_q.toarray() if hasattr(Phi_q, "toarray") else np.asarray(Phi_q, float)
        P = P * col_scale
        ind = np.nonzero(active)[0]
        Pi = P[ind]
        G = Pi @ Pi.T
        Y = np.zeros((P.shape[0], len(red)))
        Y[red, np.arange(len(red))] = 1.0
        Y[ind] = -solve(G, Pi @ P[red].T)
        if len(red):
            Y[ind] -= solve(G, Pi @ (P.T @ Y))
        return Y
    P = scaled(Phi_q, col_scale)
    ind = np.nonzero(active)[0]
    Pi = P[ind]
    lu = _gram_factor(Pi)
    Y = np.zeros((P.shape[0], len(red)))
    if len(red):      # every removed row at once: the same sums and column solves as one by one
        Y[ind] = -lu.solve(Pi @ np.asfortranarray(P[red].toarray().T))
        Y[red, np.arange(len(red))] = 1.0
        Y[ind] -= lu.solve(Pi @ np.asfortranarray(P.T @ Y))     # the refinement step
    return Y


def _gram_factor(Pi):
    """A factorisation of the Gram matrix ``Pi Pi^T`` of the independent rows (positive
    definite), with a ``solve``: LAPACK's banded Cholesky in row order when it is banded there
    (chains, ladders: as the redundancy test's, :mod:`poise.solvers.gram`), else SuperLU."""
    A, ab, _ = banded_gram(Pi)
    if ab is not None:
        try:
            return BandedCholesky(ab, own=True)
        except ValueError:          # not numerically positive definite: SuperLU's LU decides
            A = gram(Pi)
    import scipy.sparse.linalg as spla
    return spla.splu(A.tocsc(), **lean(A.shape[0]))


def detect_redundancy(model, state, workspace=None, evaluation=None) -> np.ndarray:
    """Redundant constraint rows of ``model`` at ``state`` (all rows evaluated); ``workspace``:
    the solve's (the evaluation fills the assembly buffer the solve reuses). ``evaluation``:
    the Jacobian evaluation at ``state`` with every row active, if the caller made it (the
    static prologue: it serves the assembly and the multipliers too, :func:`without_rows`)."""
    if model.nc == 0:
        return np.zeros(0, int)
    J = (evaluation.J if evaluation is not None
         else model.evaluate(state, need_jac=True, workspace=workspace).J)
    Pq = J[model.nq:, :model.nq]
    del J                 # the KKT matrix (the workspace keeps its buffer): only Phi_q is needed
    return redundant_rows(Pq, column_scale(model))


def column_scale(model) -> np.ndarray:
    """(nq,) scaling of ``Phi_q``'s columns that makes every coordinate a length: rotations by
    1/L (the redundancy test's and the left null basis's)."""
    return np.where(model.q_kind == 1, 1.0 / model.L, 1.0)


def without_rows(model, ev, active):
    """The evaluation ``ev`` (every constraint row active, Jacobian assembled) as an evaluation
    with only the ``active`` rows reads — bit for bit: the residual does not depend on the
    rows' activity; inactive rows read 0 in ``phi``, have no constraint Jacobian (row and
    transposed column zero) and 1 on their multiplier diagonal
    (:func:`poise.model.evaluate.jacobian`). ``ev``'s Jacobian is changed in place (its
    column order kept). None when the model has a reaction feed (its coupling block depends
    on the rows) or ``ev`` has no Jacobian: the caller evaluates afresh."""
    if model.reaction_feed is not None or ev.J is None:
        return None
    active = np.asarray(active, bool)
    off = np.nonzero(~active)[0] + model.nq
    J = ev.J
    if len(off):
        if hasattr(J, "indptr"):                  # CSR of the fixed pattern, sorted rows
            # a few rows' entries are searched where they are; else one pass over the matrix
            few = J.indptr[off + 1].sum() - J.indptr[off].sum() <= TRANSPOSED_SHARE * J.nnz
            at = _transposed(J, off) if few else None
            if at is None:
                bad = np.zeros(J.shape[1], bool)
                bad[off] = True
                at = bad[J.indices]
            J.data[at] = 0.0                      # transposed columns (and the diagonals)
            for k in off:
                lo, hi = J.indptr[k], J.indptr[k + 1]
                J.data[lo:hi] = 0.0
                J.data[lo + np.searchsorted(J.indices[lo:hi], k)] = 1.0
        else:
            J[off, :] = 0.0
            J[:, off] = 0.0
            J[off, off] = 1.0
    return Evaluation(r=ev.r, phi=np.where(active, ev.phi, 0.0), J=J, workspace=ev.workspace)


#: rows' entries searched one row at a time up to this many (beyond: one pass over the matrix)
TRANSPOSED_MAX = 4096
#: ... and only when they are at most this share of the matrix's entries (:func:`without_rows`:
#: one vectorised pass over a small matrix costs less than the searches, a Python step each)
TRANSPOSED_SHARE = 1e-3


def _transposed(J, off):
    """Positions in ``J.data`` of the entries of columns ``off`` of the sorted CSR ``J``: the
    entry ``(j, k)`` for every ``j`` in row ``k``'s pattern. The KKT pattern is structurally
    symmetric in its multiplier rows and columns (each constraint block is registered with
    its transpose, :func:`poise.model.layout._blocks`; no reaction feed here), so these are
    all of them, found in the few rows concerned instead of a pass over every entry. None
    when they are too many to search row by row, or one is missing (the caller then passes
    over the matrix)."""
    ind, ptr = J.indices, J.indptr
    rows = [ind[ptr[k]:ptr[k + 1]] for k in off]
    if sum(r.size for r in rows) > TRANSPOSED_MAX:
        return None
    at = []
    for k, cols in zip(off, rows):
        for j in cols:
            lo, hi = ptr[j], ptr[j + 1]
            p = lo + int(np.searchsorted(ind[lo:hi], k))
            if p >= hi or ind[p] != k:
                return None
            at.append(p)
    return np.array(at, np.intp)


def inconsistent_redundant(model, state, sc, data) -> str:
    """Removed (redundant) constraint rows violated at ``state`` beyond their tolerance.

    ``sc``: the solve's tolerance scales (:class:`~poise.solvers.newton.Scales`), ``data``: its
    :class:`~poise.solvers.data.SolveData`. Redundant rows are pinned inactive (``data.active``),
    so Newton never sees them; when the joints contradict each other (e.g. two hinges of one
    door on parallel but offset axes) the active rows can be met while a removed one is not.
    Returns a message naming the worst such row, or "".
    """
    active = data.active
    if model.nc == 0 or active is None or active.all():
        return ""
    try:
        if model.assembler.dense:      # small: the last evaluation's kept outputs serve
            phi = model.evaluate(state, need_jac=False, workspace=data.workspace).phi
        else:                          # large: the constraint values alone, every row
            phi = _evaluate(model, state, "phi", workspace=data.workspace)
    except EvaluationError:
        return ""
    z = np.where(active, 0.0, np.abs(phi) / sc.phi_tol)
    k = int(np.argmax(z))
    if not z[k] > 1.0:
        return ""
    ri = model.row_info[k]
    return (f"{row_where(ri)} equation {ri['equation']} "
            f"(removed as redundant) is violated by {abs(phi[k]):.6g} "
            f"(tolerance {sc.phi_tol[k]:.3g})")
