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


def banded_gram(P, PT=None, width=None):
    """``(A, ab, d)``: the Gram matrix of ``P`` (CSR) as its lower band ``ab`` (:func:`band`)
    and diagonal ``d`` with ``A`` None, or, when it is not banded, as the CSR ``A``
    (:func:`gram`) with ``ab`` None. ``PT``: :func:`transposed` ``P``, if the caller has it
    (its stored zeros are dropped); ``width``: :func:`pattern_width` of ``P``, if the caller
    has it (not None: it admits the blocks; the band is as wide as ``PT`` without its stored
    zeros).

    From ``BLOCKED_ROWS`` rows on, a band the pattern allows (:func:`may_be_banded`) is made
    block by block (:func:`_band_by_blocks`) and ``A`` is never held: there ``A`` and
    :func:`band`'s index arrays are too large for the allocator to reuse (fresh pages each
    time, hundreds of MB at 10^5 links). Either way the band is kept as :func:`band` decides."""
    if P.shape[0] < BLOCKED_ROWS:
        width = None
    else:
        PT = transposed(P) if PT is None else PT
        width = pattern_width(P, PT) if width is None else width
    if width is not None:
        PT.eliminate_zeros()                # stored zeros make no product: a narrower band
        ab = _band_by_blocks(P, _span(PT))
        A = gram(P) if ab is None else None
    else:
        A = gram(P)
        ab = band(A)
    if ab is None:
        return A, None, A.diagonal()
    return None, ab, ab[0].copy()


#: rows from which :func:`banded_gram` makes a band block by block
BLOCKED_ROWS = 1 << 17


def may_be_banded(P, PT=None) -> bool:
    """False when the Gram matrix of the CSR ``P`` is certainly not banded (:func:`band`),
    from ``P``'s pattern alone: its band spans, for some column, the first to the last row
    with an entry in it, and its lower triangle has at most ``c (c + 1) / 2`` entries for each
    column with ``c`` entries. ``PT``: :func:`transposed` ``P``, if the caller has it."""
    return pattern_width(P, PT) is not None


def transposed(P):
    """``P^T`` (``P`` CSR) as CSR: ``P``'s columns, the rows in each ascending (the order
    SciPy's conversion writes them in; sorted here if not)."""
    PT = P.T.tocsr()
    if not PT.has_sorted_indices:
        PT.sort_indices()
    return PT


def pattern_width(P, PT=None):
    """The band width of the Gram matrix of the CSR ``P`` allowed by its pattern: the largest
    of its columns' last row less first row; None when :func:`may_be_banded` refuses the
    pattern. ``PT``: :func:`transposed` ``P``, if the caller has it."""
    n = P.shape[0]
    PT = transposed(P) if PT is None else PT
    width = _span(PT)
    c = np.diff(PT.indptr).astype(float)
    if n * (width + 1) > BAND_FILL * float(np.sum(c * (c + 1) / 2) + n):
        return None
    return width


def _span(PT):
    """The largest last row less first row of a column of ``P`` (``PT``: :func:`transposed`),
    0 when it has no entry: no two rows further apart share a column."""
    c = np.diff(PT.indptr)
    used = c > 0
    if not used.any():
        return 0
    return int(np.max(PT.indices[PT.indptr[1:][used] - 1] - PT.indices[PT.indptr[:-1][used]]))


#: rows of the Gram matrix made at once (:func:`_band_by_blocks`: their products stay in cache)
BLOCK_ROWS = 8192


def _band_by_blocks(P, width):
    """The lower band of ``P P^T`` in :func:`band`'s layout, or None when :func:`band` would
    refuse it, made ``BLOCK_ROWS`` rows at a time into storage of the pattern's ``width``.

    Rows ``r0:r1`` of the product are those of ``P[r0:r1] P[c0:r1]^T`` (``c0 = r0 - width``:
    no entry of the band lies further left) in the columns these rows use: SciPy's product
    sums each entry on its own, over the row's entries in their order, and drops exact zeros,
    so they are ``P P^T``'s bit for bit; and its work arrays span the block, not the matrix."""
    import scipy.sparse as sp  # lazy: sparse systems only
    n = P.shape[0]
    ptr, ind, data = P.indptr, P.indices, P.data
    rows = np.zeros((n, width + 1))         # rows[j, o] = A[j + o, j]
    flat = rows.reshape(-1)
    used, low = 0, 0
    for r0 in range(0, n, BLOCK_ROWS):
        r1 = min(n, r0 + BLOCK_ROWS)
        c0 = max(0, r0 - width)
        e0, e1 = ptr[c0], ptr[r1]
        if e1 == e0:
            continue
        cols = ind[e0:e1]
        lo = int(cols.min())
        cols = cols - lo
        span = int(cols.max()) + 1
        W = sp.csr_matrix((data[e0:e1], cols, ptr[c0:r1 + 1] - e0), shape=(r1 - c0, span))
        b0 = ptr[r0] - e0
        B = sp.csr_matrix((data[e0 + b0:e1], cols[b0:], ptr[r0:r1 + 1] - ptr[r0]),
                          shape=(r1 - r0, span)) @ W.T
        j = B.indices.astype(np.intp)
        off = np.repeat(np.arange(r0 - c0, r1 - c0), np.diff(B.indptr)) - j
        at = np.flatnonzero(off >= 0)
        o = off[at]
        if len(o):
            used = max(used, int(o.max()))
        if used > width:       # a stored zero times a non-finite value: the whole product
            return band(gram(P))
        low += len(at)
        flat[(j[at] + c0) * (width + 1) + o] = B.data[at]
    if n * (used + 1) > BAND_FILL * max(low, 1):
        return None
    if used < width:
        rows = np.ascontiguousarray(rows[:, :used + 1])
    return rows.T                           # ab[i - j, j] = A[i, j], column-major


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


def without(ab, rows, own: bool = False):
    """The band ``ab`` of a Gram matrix with ``rows`` taken out: zero in their rows and columns,
    1 on their diagonal (a copy; ``own``: ``ab`` itself, changed in place when column-major).
    It solves for the other rows exactly as the Gram matrix of those alone, and gives exactly
    0 on ``rows`` when the right-hand side is 0 there."""
    ab = np.asfortranarray(ab) if own else ab.copy(order="F")
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
    PT = transposed(P)
    width = pattern_width(P, PT)        # (banded_gram's too, from BLOCKED_ROWS rows on)
    if width is None:
        return None
    _, ab, d = banded_gram(P, PT, width)
    del PT
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
