"""Detection of redundant constraint equations.

The constraint Jacobian is scaled (rotation columns by 1/L so every coordinate is a length) and
the Gram matrix ``A = Phi_q D^2 Phi_q^T`` is factorised with symmetric diagonal pivoting in the
natural (deck) order. For a positive semi-definite matrix this is Cholesky with a rank test: the
pivot of row k divided by ``A_kk`` is the squared sine of the angle between row k and the span of
the rows before it, so a ratio below ``RATIO_TOL`` marks row k as dependent on earlier rows
(deck order: the later equation is the one removed).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

RATIO_TOL = 1e-9
SHIFT = 1e-13
ORDERING_NATURAL_MAX = 20000


def redundant_rows(Phi_q, col_scale: np.ndarray) -> np.ndarray:
    """Indices of redundant rows of ``Phi_q`` (nc, nq).

    Parameters
    ----------
    Phi_q : sparse or dense (nc, nq)
    col_scale : (nq,) column scaling (1 for translations, 1/L for rotations)
    """
    P = sp.csr_matrix(Phi_q) @ sp.diags(col_scale)
    nc = P.shape[0]
    if nc == 0:
        return np.zeros(0, int)
    A = (P @ P.T).tocsc()
    d = A.diagonal().copy()
    empty = d <= 1e-300
    dd = np.where(empty, 1.0, d)
    A2 = (A + sp.diags(np.where(empty, 1.0, SHIFT * d))).tocsc()
    perm = "NATURAL" if nc <= ORDERING_NATURAL_MAX else "MMD_AT_PLUS_A"
    lu = spla.splu(A2, permc_spec=perm, diag_pivot_thresh=0.0,
                   options=dict(SymmetricMode=True))
    u = lu.U.diagonal()
    if not np.array_equal(lu.perm_r, lu.perm_c):
        # fall back to a dense rank-revealing QR (small systems only)
        return _dense_redundant(P.toarray())
    ratio = u[lu.perm_r] / dd
    red = np.nonzero((ratio < RATIO_TOL) | empty)[0]
    return red


def _dense_redundant(P):
    import scipy.linalg as sla
    q, r, piv = sla.qr(P.T, mode="economic", pivoting=True)
    dg = np.abs(np.diag(r))
    rank = int(np.sum(dg > RATIO_TOL ** 0.5 * max(dg.max(), 1e-300)))
    return np.sort(piv[rank:])


def min_norm_multipliers(Phi_q, lam, active, row_weight):
    """Minimum-norm multipliers equivalent to ``lam`` (which is zero on inactive rows).

    Among all ``mu`` with ``Phi_q^T mu = Phi_q^T lam`` returns the one minimising
    ``sum(row_weight * mu**2)``. Uses the left null space of ``Phi_q``: for each redundant row k,
    ``y_k = e_k - Phi_ind-coefficients`` from the normal equations of the independent rows.
    """
    red = np.nonzero(~active)[0]
    if len(red) == 0:
        return lam
    P = sp.csr_matrix(Phi_q)
    ind = np.nonzero(active)[0]
    Pi = P[ind]
    G = (Pi @ Pi.T).tocsc()
    lu = spla.splu(G)
    Y = np.zeros((P.shape[0], len(red)))
    for c, k in enumerate(red):
        rhs = Pi @ P[k].toarray().ravel()
        coef = lu.solve(rhs)
        Y[k, c] = 1.0
        Y[ind, c] = -coef
    Wy = row_weight[:, None] * Y
    M = Y.T @ Wy
    mu = lam - Y @ np.linalg.solve(M, Wy.T @ lam)
    return mu
