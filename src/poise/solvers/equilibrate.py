"""Symmetric equilibration of the stability KKT matrix ``[[K_s, G^T], [G, 0]]`` with a
round-off-aware cap: sparse (one configuration) and dense (a stack of frames).

Both classification paths and the descent's pencils count the eigenvalues of the reduced
stiffness after a diagonal congruence ``D`` (Sylvester: the inertia is unchanged) that gives
every row of ``D |KKT| D`` a largest entry of about 1 (Ruiz): a stiff/soft mix (1e9 N/m next to
1 N/m) is then judged per direction, not against the stiffest. A coordinate whose row holds
only rounding errors (a free spin: its diagonal and couplings are 1e-16 x its neighbours', of
either sign) must not be scaled up to unit size, or the sign of that rounding decides its
label. So coordinate ``i`` is never scaled beyond ``1 / sqrt(DIAG_FLOOR R_i)``, ``R_i`` the
largest absolute row sum of ``K_s`` among ``i`` and the coordinates it is coupled to: the
round-off of an entry (``NOISE_REL`` x the larger of its rows' sums) stays below a tenth of the
zero threshold ``ZERO_REL``. The cap is local: a part of the model decoupled from a stiff one
keeps its own scale. docs/stability.md.
"""
from __future__ import annotations

import numpy as np

from poise.core.lean import where
from poise.core.permutation import inverse
from poise.solvers.linalg import kept_entries
from poise.solvers.stability_modes import DIAG_FLOOR, NOISE_REL


def _row_max(M):
    """``(|entries|, largest |entry| of each row, row of each entry)`` of csr matrix ``M``."""
    a = np.abs(M.data)
    cnt = np.diff(M.indptr)
    nz = cnt > 0
    rmax = np.zeros(M.shape[0])
    if a.size:
        rmax[nz] = np.maximum.reduceat(a, M.indptr[:-1][nz])
    return a, rmax, np.repeat(np.arange(M.shape[0]), cnt)


def prune_noise(Ks):
    """Drop the entries of sparse Ks at round-off level of both rows they couple (``|K_ij| <=
    NOISE_REL max(max_k |K_ik|, max_k |K_jk|)``): a perturbation of the size of the rounding in
    those rows, but equilibration would otherwise scale a 1e-19-relative coupling next to a
    zero diagonal (a box's yaw on a plane) up to unit size and count a negative eigenvalue."""
    a, rmax, rows = _row_max(Ks)
    return kept_entries(Ks, a > NOISE_REL * np.maximum(rmax[rows], rmax[Ks.indices]))


def prune_rows(G):
    """Drop the entries of sparse constraint rows ``G`` at round-off level of their row
    (``|G_ij| <= NOISE_REL max_k |G_ik|``): a coordinate that no constraint really involves
    and no stiffness couples (a free spin about a link's own axis) would otherwise be scaled
    until that rounding is of unit size, and the SVD would count it as constrained."""
    G = G.tocsr()
    a, rmax, rows = _row_max(G)
    return kept_entries(G, a > NOISE_REL * rmax[rows])


def prune_rows_dense(G):
    """:func:`prune_rows` of a stack of dense constraint rows (F, m, n)."""
    B = np.abs(G)
    return where(B > NOISE_REL * B.max(axis=2, keepdims=True, initial=0.0), G, 0.0)


def prune_noise_dense(Ks):
    """:func:`prune_noise` of a stack of dense symmetric matrices (F, n, n)."""
    A = np.abs(Ks)
    rmax = A.max(axis=2)
    keep = A > NOISE_REL * np.maximum(rmax[:, :, None], rmax[:, None, :])
    return where(keep, Ks, 0.0)


def _cap(R, nbr):
    return where(nbr > 0.0, 1.0 / np.sqrt(DIAG_FLOOR * where(nbr > 0.0, nbr, 1.0)), np.inf)


def coordinate_caps(Ks) -> np.ndarray:
    """Largest scaling of each coordinate of sparse Ks (module docstring): ``1 / sqrt(DIAG_FLOOR
    max(R_i, max_{K_ij != 0} R_j))``, ``R`` the absolute row sums; inf for an all-zero row."""
    A = abs(Ks).tocsr()
    R = np.asarray(A.sum(axis=1)).ravel()
    nbr = R.copy()
    cnt = np.diff(A.indptr)
    nz = cnt > 0
    if A.nnz:
        nbr[nz] = np.maximum(nbr[nz], np.maximum.reduceat(R[A.indices], A.indptr[:-1][nz]))
    return _cap(R, nbr)


def equilibrate(Ks, G, iters=12, tol=0.1, start=None):
    """Symmetric Ruiz scaling ``D`` of the sparse KKT matrix ``[[Ks, G^T], [G, 0]]``: every row
    of ``D |KKT| D`` has a largest entry in ``[1 - tol, 1 + tol]``, except that coordinate
    ``i`` is never scaled beyond :func:`coordinate_caps`. Returns the coordinate and row
    factors (``start``: the factors to start from, e.g. a nearby configuration's).

    The sweeps run on the unknowns renumbered by :class:`_KKTRows` (rows of one pattern
    together, coordinates first): each row's maximum is written in place, with no scatter;
    a maximum is exact and the other steps act entry by entry, so the factors are those of the
    assembled matrix in its own numbering."""
    nq = Ks.shape[0]
    cap = coordinate_caps(Ks)
    rows = _KKTRows(Ks.tocsr(), G)
    at = rows.order                                   # the unknown at each renumbered place
    D = np.ones(len(at)) if start is None else np.concatenate(start)[at]
    cap = cap[at[:nq]]
    n = len(at)
    np.minimum(D[:nq], cap, out=D[:nq])
    r, e = np.zeros(n), np.empty(n)
    Dq, rq = D[:nq], r[:nq]
    scratch = _Scratch()
    for _ in range(iters):
        rows.into(r, D, scratch)
        r[r <= 0.0] = 1.0                              # an all-zero row keeps its scale
        rq[(Dq >= cap) & (rq < 1.0)] = 1.0             # at its cap: as far as it goes
        np.subtract(r, 1.0, out=e)
        if np.abs(e, out=e).max() <= tol:              # (NaN: not within)
            break
        D /= np.sqrt(r, out=r)
        np.minimum(Dq, cap, out=Dq)
    out = np.empty(n)
    out[at] = D
    return out[:nq], out[nq:]


#: entries of a group (:class:`_KKTRows`) per pass: the two pass buffers, shared by the groups
#: and the sweeps, stay within a core's L2 cache however large the model (no fresh pages per
#: group, no trip to memory between a pass's products and its maxima)
PASS_ENTRIES = 1 << 16

#: distinct row patterns of the KKT matrix laid out by pattern (:class:`_KKTRows`); a matrix
#: with more is reduced by segments
MAX_LENGTHS = 16


class _Scratch:
    """Two ``(w, k)`` buffers, views of one flat array kept across the groups and sweeps of one
    equilibration (grown, never shrunk)."""

    def __init__(self):
        self.flat = np.empty((2, 0))

    def take(self, w, k):
        if self.flat.shape[1] < w * k:
            self.flat = np.empty((2, w * k))
        return self.flat[0, :w * k].reshape(w, k), self.flat[1, :w * k].reshape(w, k)


def kkt_rows(Ks, G, Gc=None):
    """``[[Ks, G^T], [G, 0]]`` (CSR ``Ks``, ``G``) as CSR, by scipy's compiled stacking (no
    block matrix of COO triplets); ``Gc``: ``G`` in CSC, if at hand."""
    import scipy.sparse as sp
    n = Ks.shape[0] + G.shape[0]
    if not G.shape[0]:
        return Ks
    Gc = G.tocsc() if Gc is None else Gc
    upper = sp.hstack([Ks, Gc.T], format="csr")             # (a CSC's transpose is CSR)
    lower = sp.csr_matrix((G.data, G.indices, G.indptr), shape=(G.shape[0], n))
    return sp.vstack([upper, lower], format="csr")


class _KKTRows:
    """Row maxima of ``(|KKT_ij| D_i) D_j`` for the KKT matrix of ``Ks`` (CSR) and ``G``
    (the products of the assembled matrix, in their order), on the unknowns renumbered by
    ``order`` (``order[p]``: the unknown at place ``p``).

    With a few row patterns (a model's rows repeat a few), the coordinates' rows are ordered
    by their numbers of ``Ks`` and ``G^T`` entries, then the constraint rows by length
    (stable): each pattern is a range of places, its entries laid out ``(w, rows)``, so that
    its row factors are one broadcast and its maxima ``w - 1`` elementwise passes written
    straight into the range (no scatter). With many patterns the rows keep their numbering and
    the assembled matrix is reduced by segments."""

    def __init__(self, Ks, G):
        nq, m = Ks.shape[0], G.shape[0]
        n = nq + m
        blocks = [(Ks, 0)]                     # (CSR rows, offset of their column numbers)
        if m:
            Gr, Gc = G.tocsr(), G.tocsc()
            blocks.append((Gc.T, nq))          # (a CSC's transpose is CSR: the rows of G^T)
        kk = np.diff(Ks.indptr)
        kg = np.diff(blocks[1][0].indptr) if m else np.zeros(nq, np.int64)
        base = int(kg.max(initial=0)) + 1
        key = kk * base + kg                   # a coordinate row's pattern: (kk, kg)
        keys = np.flatnonzero(np.bincount(key)) if nq else key
        lens = np.diff(Gr.indptr) if m else np.zeros(0, np.int64)
        lengths = np.flatnonzero(np.bincount(lens)) if m else lens
        self.padded = len(keys) + len(lengths) <= MAX_LENGTHS
        if not self.padded:
            self.order = np.arange(n)
            M = kkt_rows(Ks, G)
            cnt = np.diff(M.indptr)
            nz = cnt > 0
            self.target = np.flatnonzero(nz)
            self.a = np.abs(M.data)
            self.rows = np.repeat(np.arange(n), cnt)
            self.cols = M.indices.astype(np.intp)
            self.starts = M.indptr[:-1][nz]
            self.buf, self.tmp = np.empty(self.a.shape), np.empty(self.a.shape)
            return
        # places: the coordinates by pattern, then the constraint rows by length; each range
        # with the blocks holding its rows' entries: [(CSR rows, column offset, count)]
        spans = [(np.flatnonzero(key == c), [(b, c0, int(w)) for (b, c0), w in
                                             zip(blocks, divmod(c, base))])
                 for c in keys.tolist()]
        spans += [(nq + np.flatnonzero(lens == w), [(Gr, 0, w)]) for w in lengths.tolist()]
        self.order = np.concatenate([rows for rows, _ in spans]) if spans else np.arange(n)
        place = inverse(self.order)
        self.groups = []                    # (places, |entries| (w, rows), their places)
        p = 0
        for rows, parts in spans:
            k = rows.size
            w = sum(c for _, _, c in parts)
            if w:
                a, cols = np.empty((w, k)), np.empty((w, k), np.intp)
                j = 0
                local = rows - (nq if rows[0] >= nq else 0)          # rows of their block
                for M, c0, c in parts:
                    if c:       # the entries row by row (contiguous reads), laid out (c, rows)
                        at = M.indptr[:-1][local][:, None] + np.arange(c)
                        np.abs(M.data[at].T, out=a[j:j + c])
                        cols[j:j + c] = place[M.indices[at] + c0 if c0 else M.indices[at]].T
                        j += c
                self.groups.append((slice(p, p + k), a, cols))
            p += k

    def into(self, r, D, scratch):
        """``r[p]``: the maximum of row ``order[p]`` for ``D`` (renumbered); an empty row's
        ``r`` is left as it is."""
        if not self.padded:
            if self.a.size:
                np.take(D, self.rows, out=self.buf, mode="clip")   # valid: no copy of out
                np.multiply(self.a, self.buf, out=self.buf)
                np.take(D, self.cols, out=self.tmp, mode="clip")
                np.multiply(self.buf, self.tmp, out=self.buf)
                r[self.target] = np.maximum.reduceat(self.buf, self.starts)
            return
        for t, a, cols in self.groups:
            w, k = a.shape
            step = max(1, PASS_ENTRIES // w)
            for j0 in range(t.start, t.stop, step):
                j1 = min(j0 + step, t.stop)
                buf, tmp = scratch.take(w, j1 - j0)
                c = slice(j0 - t.start, j1 - t.start)
                np.multiply(a[:, c], D[j0:j1], out=buf)
                np.take(D, cols[:, c], out=tmp, mode="clip")       # valid: no copy of out
                np.multiply(buf, tmp, out=buf)
                np.maximum.reduce(buf, axis=0, out=r[j0:j1])


def equilibrate_dense(Ks, G, iters=12, tol=0.1):
    """:func:`equilibrate` of a stack of dense KKT matrices, ``Ks`` (F, n, n) and ``G``
    (F, m, n), each frame iterated as it would be alone (a frame whose rows are within ``tol``
    keeps its factors). Returns ``Dq`` (F, n), ``Dl`` (F, m)."""
    F, n = Ks.shape[:2]
    m = G.shape[1]
    if F == 1:
        Dq, Dl = _equilibrate_one(Ks[0], G[0], iters, tol)
        return Dq[None], Dl[None]
    A, B = np.abs(Ks), np.abs(G)
    mx = np.maximum.reduce                   # the reductions without their Python wrappers
    R = np.add.reduce(A, axis=2)
    nbr = np.maximum(R, mx(where(A > 0.0, R[:, None, :], 0.0), axis=2, initial=0.0))
    cap = _cap(R, nbr)
    Dq, Dl = np.minimum(np.ones((F, n)), cap), np.ones((F, m))
    bufA, bufB = np.empty_like(A), np.empty_like(B)
    go = np.ones(F, bool)
    for _ in range(iters):
        rq = mx(np.multiply(A, Dq[:, None, :], out=bufA), axis=2, initial=0.0)
        if m:
            rq = np.maximum(rq, mx(np.multiply(B, Dl[:, :, None], out=bufB), axis=1, initial=0.0))
        rq *= Dq
        rl = mx(np.multiply(B, Dq[:, None, :], out=bufB), axis=2, initial=0.0) * Dl
        rq[(rq <= 0.0) | ((Dq >= cap) & (rq < 1.0))] = 1.0   # all-zero row, or at its cap
        rl[rl <= 0.0] = 1.0
        if F == 1:       # one frame (a static solve's): it stops when within tol (NaN: never)
            if mx(np.abs(rq - 1.0), axis=None, initial=0.0) <= tol \
                    and mx(np.abs(rl - 1.0), axis=None, initial=0.0) <= tol:
                break
        else:
            go &= ~(np.logical_and.reduce(np.abs(rq - 1.0) <= tol, axis=1)
                   & np.logical_and.reduce(np.abs(rl - 1.0) <= tol, axis=1))
            if not np.logical_or.reduce(go):
                break
            rq[~go], rl[~go] = 1.0, 1.0
        Dq = np.minimum(Dq / np.sqrt(rq), cap)
        Dl = Dl / np.sqrt(rl)
    return Dq, Dl


def _equilibrate_one(Ks, G, iters, tol):
    """:func:`equilibrate_dense` of one frame (a static solve's), ``Ks`` (n, n), ``G`` (m, n),
    on 2-d arrays (the frames' cap, without the stacking): the absolute KKT matrix ``M = [[A,
    B^T], [B, 0]]`` (``A = |Ks|``, ``B = |G|``) with one scaling ``[Dq; Dl]`` (no cap on
    ``Dl``), so that an iteration is one product and one maximum per row: the same products and
    maxima as the frames' loop, the same factors."""
    n, m = Ks.shape[0], G.shape[0]
    mx = np.maximum.reduce                   # the reductions without their Python wrappers
    M = np.zeros((n + m, n + m))
    A = M[:n, :n]
    np.abs(Ks, out=A)
    M[n:, :n] = G
    np.abs(M[n:, :n], out=M[n:, :n])
    M[:n, n:] = M[n:, :n].T
    R = np.add.reduce(A, axis=1)
    cap = _cap(R, np.maximum(R, mx(where(A > 0.0, R, 0.0), axis=1, initial=0.0)))
    capx = np.concatenate([cap, np.full(m, np.inf)])
    D = np.concatenate([np.minimum(1.0, cap), np.ones(m)])
    buf = np.empty_like(M)
    for _ in range(iters):
        r = mx(np.multiply(M, D, out=buf), axis=1, initial=0.0)
        r *= D
        # at its cap: at least 1 (a True is 1; NaN stays); then an all-zero row: 1
        np.maximum(r, D >= capx, out=r)
        r[r <= 0.0] = 1.0
        if mx(np.abs(r - 1.0), axis=None, initial=0.0) <= tol:     # (NaN: never)
            break
        D = np.minimum(D / np.sqrt(r), capx)
    return D[:n], D[n:]
