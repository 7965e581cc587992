"""Gram matrices ``A = P P^T`` of a column-scaled constraint Jacobian ``P``, factorised.

Redundancy detection reads the symmetric pivots of such a matrix in deck order and projects
rows on the span of others; the least-squares multipliers solve its normal equations. A deck's
constraint Jacobian is often *banded* in deck order (chains, ladders, tracks: each joint couples
neighbouring bodies); then LAPACK's banded Cholesky (``pbtrf``) factorises it in that order with
no fill outside the band, several times faster than SuperLU's general machinery. Otherwise
SuperLU in symmetric mode (diagonal pivots, ``perm`` column order). Either way the pivots are
those of ``A = L D L^T`` in the factorisation's order.
"""
from __future__ import annotations

import numpy as np

from poise.solvers.superlu import lean

BAND_FILL = 4    # banded storage at most this many times the stored lower triangle


def scaled(Pq, col_scale):
    """``Pq diag(col_scale)`` as CSR (one pass over the entries, no diagonal-matrix product);
    it shares ``Pq``'s pattern arrays (CSR ``Pq``: neither is changed in place)."""
    import scipy.sparse as sp  # lazy: sparse systems only
    Pq = sp.csr_matrix(Pq)
    return sp.csr_matrix((Pq.data * col_scale[Pq.indices], Pq.indices, Pq.indptr),
                         shape=Pq.shape)


def gram(P):
    """``P P^T`` (CSR, rows of ``P`` in order)."""
    return (P @ P.T).tocsr()


def banded_gram(P):
    """``(A, ab, d)``: the Gram matrix ``A`` of ``P`` (:func:`gram`), its lower band ``ab``
    (:func:`band`; None when not banded) and its diagonal ``d`` (read off the band when there
    is one: the same values, no pass over ``A``)."""
    A = gram(P)
    ab = band(A)
    return A, ab, (A.diagonal() if ab is None else ab[0].copy())


def may_be_banded(P) -> bool:
    """False when the Gram matrix of the CSR ``P`` is certainly not banded (:func:`band`),
    from ``P``'s pattern alone: its band spans, for some column, the first to the last row
    with an entry in it, and its lower triangle has at most ``c (c + 1) / 2`` entries for each
    column with ``c`` entries."""
    n = P.shape[0]
    if n == 0 or P.nnz == 0:
        return True
    rows = np.repeat(np.arange(n), np.diff(P.indptr))
    lo = np.full(P.shape[1], n)
    hi = np.full(P.shape[1], -1)
    np.minimum.at(lo, P.indices, rows)
    np.maximum.at(hi, P.indices, rows)
    c = np.bincount(P.indices, minlength=P.shape[1]).astype(float)
    return n * (int(np.max(hi - lo)) + 1) <= BAND_FILL * float(np.sum(c * (c + 1) / 2) + n)


def band(A):
    """Lower band storage ``ab[i - j, j] = A[i, j]`` of the CSR matrix ``A`` (symmetric), or None
    when its band in this order would store more than ``BAND_FILL`` times its lower triangle."""
    n, ind = A.shape[0], A.indices
    off = np.repeat(np.arange(n, dtype=ind.dtype), np.diff(A.indptr)) - ind
    low = np.flatnonzero(off >= 0)
    o = off[low].astype(np.intp)
    width = int(o.max()) if len(o) else 0
    if n * (width + 1) > BAND_FILL * max(len(low), 1):
        return None
    ab = np.zeros((n, width + 1))          # stored column by column, as LAPACK reads it
    ab.ravel()[ind[low] * (width + 1) + o] = A.data[low]
    return ab.T                             # ab[i - j, j] = A[i, j]


class BandedCholesky:
    """``A = L L^T`` of a symmetric positive definite matrix in lower band storage ``ab``
    (:func:`band`), eliminated in row order: ``pivots[k] = L_kk^2`` (row k's pivot of
    ``L D L^T``), ``solve(b)`` (``b`` a vector or columns). ``own``: ``ab`` may be factorised
    in place (column-major, as :func:`band` stores it: no copy). Raises ``ValueError`` when it
    is not numerically positive definite."""

    def __init__(self, ab, own: bool = False):
        import scipy.linalg as sla  # lazy: sparse systems only
        try:
            self._cb = sla.cholesky_banded(ab, overwrite_ab=own, lower=True,
                                           check_finite=False)
        except np.linalg.LinAlgError:
            raise ValueError("not positive definite") from None
        self.pivots = self._cb[0] ** 2
        if not np.all(np.isfinite(self.pivots)):
            raise ValueError("not finite")

    def solve(self, b):
        import scipy.linalg as sla  # lazy: sparse systems only
        return sla.cho_solve_banded((self._cb, True), b, check_finite=False)


class SymmetricLU:
    """SuperLU of a symmetric positive definite CSR ``A`` in symmetric mode (diagonal pivots)
    in the column order ``perm`` (``NATURAL``: row order): ``pivots[k]`` is row k's pivot,
    ``solve(b)``. Raises ``ValueError`` when a pivot is exactly zero or SuperLU pivoted off the
    diagonal."""

    def __init__(self, A, perm: str = "MMD_AT_PLUS_A"):
        import scipy.sparse.linalg as spla  # lazy: sparse systems only
        try:
            self._lu = spla.splu(A.tocsc(), permc_spec=perm, diag_pivot_thresh=0.0,
                                 options=dict(SymmetricMode=True), **lean(A.shape[0]))
        except RuntimeError:
            raise ValueError("exactly singular") from None
        if not np.array_equal(self._lu.perm_r, self._lu.perm_c):
            raise ValueError("pivoted off the diagonal")
        self.pivots = self._lu.U.diagonal()[self._lu.perm_r]

    def solve(self, b):
        return self._lu.solve(np.asarray(b, float))


def without(ab, rows):
    """The band ``ab`` of a Gram matrix with ``rows`` taken out: zero in their rows and columns,
    1 on their diagonal (a copy). It solves for the other rows exactly as the Gram matrix of
    those alone, and gives exactly 0 on ``rows`` when the right-hand side is 0 there."""
    ab = ab.copy(order="F")
    w = ab.shape[0] - 1
    o = np.arange(w + 1)
    ab[:, rows] = 0.0                                  # column j: ab[i - j, j]
    i = rows[:, None]
    j = i - o[None, :]                                  # row i: ab[o, i - o]
    ok = j >= 0
    ab[np.broadcast_to(o, j.shape)[ok], j[ok]] = 0.0
    ab[0, rows] = 1.0
    return ab


def projected(P, F, R, off=None):
    """``R - P^T A^-1 P R`` for ``A = P P^T`` factorised as ``F``: the columns of ``R`` projected
    on the complement of the row space of ``P`` by corrected semi-normal equations (a solve and
    one correction: QR-like accuracy without a QR). ``off``: rows of ``P`` taken out of ``F``
    (:func:`without`), as if they were zero."""
    for _ in range(2):
        y = np.asarray(P @ R)
        if off is not None:
            y[off] = 0.0
        R = R - P.T @ F.solve(y)
    return R


def least_squares(Pq, w, g, active, factor):
    """``lam`` minimising ``|| diag(w) (Pq^T lam - g) ||`` over the ``active`` rows of ``Pq``
    (CSR, inactive rows zero; their ``lam`` 0), from the normal equations ``A lam = P w g`` of
    ``P = Pq diag(w)`` by corrected semi-normal equations, or None when that route does not
    apply: ``A`` not banded (:func:`band`), an active row empty or ``A`` not numerically
    positive definite (the caller solves its augmented system). ``factor(A, factorise)``: the
    caller's counted factorisation (:meth:`poise.solvers.data.SolveData.factor`)."""
    P = scaled(Pq, w)
    if not may_be_banded(P):
        return None
    A, ab, d = banded_gram(P)
    del A
    off = ~np.asarray(active, bool)
    if ab is None or np.any(d[~off] <= 0.0):
        return None
    ab[0, off] += 1.0                                   # inactive rows: lam = 0
    try:
        F = factor(ab, lambda ab: BandedCholesky(ab, own=True))
    except ValueError:
        return None
    gw = w * g
    lam = F.solve(P @ gw)
    lam = lam + F.solve(P @ (gw - P.T @ lam))          # one correction (CSNE)
    return lam if np.all(np.isfinite(lam)) else None
