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


def _kept(M, keep):
    """``M`` without its entries where ``keep`` is False (a copy only when one goes)."""
    if keep.all():
        return M
    M = M.copy()
    M.data[~keep] = 0.0
    M.eliminate_zeros()
    return M


def prune_noise(Ks):
    """Drop the entries of sparse Ks at round-off level of both rows they couple (``|K_ij| <=
    NOISE_REL max(max_k |K_ik|, max_k |K_jk|)``): a perturbation of the size of the rounding in
    those rows, but equilibration would otherwise scale a 1e-19-relative coupling next to a
    zero diagonal (a box's yaw on a plane) up to unit size and count a negative eigenvalue."""
    a, rmax, rows = _row_max(Ks)
    return _kept(Ks, a > NOISE_REL * np.maximum(rmax[rows], rmax[Ks.indices]))


def prune_rows(G):
    """Drop the entries of sparse constraint rows ``G`` at round-off level of their row
    (``|G_ij| <= NOISE_REL max_k |G_ik|``): a coordinate that no constraint really involves
    and no stiffness couples (a free spin about a link's own axis) would otherwise be scaled
    until that rounding is of unit size, and the SVD would count it as constrained."""
    G = G.tocsr()
    a, rmax, rows = _row_max(G)
    return _kept(G, a > NOISE_REL * rmax[rows])


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

    The KKT matrix is never assembled: its row maxima are those of ``Ks``, ``G^T`` (``G`` by
    columns) and ``G``, each taken over preallocated buffers (a maximum is exact, so the
    factors are those of the assembled matrix)."""
    nq = Ks.shape[0]
    cap = coordinate_caps(Ks)
    Ks = Ks.tocsr()
    parts = [_RowMaxima(Ks.indptr, Ks.indices, Ks.data, 0, 0)]
    if G.shape[0]:
        Gr, Gc = G.tocsr(), G.tocsc()
        parts += [_RowMaxima(Gc.indptr, Gc.indices, Gc.data, 0, nq),   # rows of G^T
                  _RowMaxima(Gr.indptr, Gr.indices, Gr.data, nq, 0)]
    n = nq + G.shape[0]
    D = np.ones(n) if start is None else np.concatenate(start)
    np.minimum(D[:nq], cap, out=D[:nq])
    r, e = np.empty(n), np.empty(n)
    Dq, rq = D[:nq], r[:nq]
    scratch = _Scratch()
    for _ in range(iters):
        r[:] = 0.0
        for pt in parts:
            pt.into(r, D, scratch)
        r[r <= 0.0] = 1.0                              # an all-zero row keeps its scale
        rq[(Dq >= cap) & (rq < 1.0)] = 1.0             # at its cap: as far as it goes
        np.subtract(r, 1.0, out=e)
        if np.abs(e, out=e).max() <= tol:              # (NaN: not within)
            break
        D /= np.sqrt(r, out=r)
        np.minimum(Dq, cap, out=Dq)
    return D[:nq], D[nq:]


#: entries of a block (:class:`_RowMaxima`) per pass: the pass buffers, shared by the blocks
#: and the sweeps, stay a few MB however large the model (no fresh pages per block)
PASS_ENTRIES = 1 << 18

#: distinct row lengths of a block laid out by length (:class:`_RowMaxima`); a block with more
#: is reduced by segments
MAX_LENGTHS = 16


class _Scratch:
    """Two ``(w, k)`` buffers and a ``(k,)`` one, views of flat arrays kept across the blocks
    and sweeps of one equilibration (grown, never shrunk)."""

    def __init__(self):
        self.flat = np.empty((2, 0))
        self.mflat = np.empty(0)

    def take(self, w, k):
        if self.flat.shape[1] < w * k:
            self.flat = np.empty((2, w * k))
        if self.mflat.size < k:
            self.mflat = np.empty(k)
        return (self.flat[0, :w * k].reshape(w, k), self.flat[1, :w * k].reshape(w, k),
                self.mflat[:k])


class _RowMaxima:
    """Row maxima of ``|M| * D[row] * D[col]`` for a compressed block ``M`` of the KKT matrix
    at row offset ``r0`` and column offset ``c0`` (the same products, in the same order, as on
    the assembled matrix). The rows are grouped by their number of entries ``w`` (a few
    lengths: a model's rows repeat a few patterns), each group laid out ``(w, rows)``: its row
    factors are one broadcast and its maxima ``w - 1`` elementwise passes over exactly its
    entries, instead of a gather and a segmented reduction; a block of many lengths is reduced
    by segments."""

    def __init__(self, indptr, indices, data, r0, c0):
        cnt = np.diff(indptr)
        a = np.abs(data)
        lengths = np.flatnonzero(np.bincount(cnt)) if cnt.size else cnt
        lengths = lengths[lengths > 0]
        self.padded = a.size > 0 and len(lengths) <= MAX_LENGTHS
        if self.padded:
            # per length w: (target rows, |entries| (w, rows), their columns (w, rows))
            self.groups = []
            for w in lengths.tolist():
                rows = np.flatnonzero(cnt == w)
                # the entries row by row (contiguous reads), then laid out (w, rows)
                at = indptr[:-1][rows][:, None] + np.arange(w)
                target = rows + r0
                if target[-1] - target[0] == target.size - 1:     # a range: a slice (views)
                    target = slice(int(target[0]), int(target[-1]) + 1)
                cols = indices[at].astype(np.intp).T.copy()
                if c0:
                    cols += c0
                self.groups.append((target, a[at].T.copy(), cols))
        else:
            nz = cnt > 0
            self.target = np.nonzero(nz)[0] + r0
            self.a = a
            self.rows = np.repeat(np.arange(r0, r0 + len(cnt)), cnt)
            self.cols = (indices + c0 if c0 else indices).astype(np.intp)
            self.starts = indptr[:-1][nz]
            self.buf = np.empty(self.a.shape)
            self.tmp = np.empty(self.a.shape)

    def _padded_into(self, r, D, scratch):
        """The groups' maxima in passes of at most ``PASS_ENTRIES`` entries over ``scratch``'s
        two buffers (the maxima are exact: the passes give the same factors)."""
        for t, a, cols in self.groups:
            w, rows = a.shape
            step = max(1, PASS_ENTRIES // w)
            for j0 in range(0, rows, step):
                j1 = min(j0 + step, rows)
                tj = (slice(t.start + j0, t.start + j1) if isinstance(t, slice) else t[j0:j1])
                buf, tmp, m = scratch.take(w, j1 - j0)
                np.multiply(a[:, j0:j1], D[tj], out=buf)
                np.take(D, cols[:, j0:j1], out=tmp, mode="clip")   # valid: no copy of out
                np.multiply(buf, tmp, out=buf)
                np.maximum.reduce(buf, axis=0, out=m)
                _max_into(r, tj, m)

    def into(self, r, D, scratch=None):
        if self.padded:
            self._padded_into(r, D, _Scratch() if scratch is None else scratch)
            return
        if not self.a.size:
            return
        np.take(D, self.rows, out=self.buf, mode="clip")      # valid indices: no copy of out
        np.multiply(self.a, self.buf, out=self.buf)
        np.take(D, self.cols, out=self.tmp, mode="clip")
        np.multiply(self.buf, self.tmp, out=self.buf)
        _max_into(r, self.target, np.maximum.reduceat(self.buf, self.starts))


def _max_into(r, t, m):
    """``r[t] = max(r[t], m)`` (``t`` a slice: in place on the view; else indices, ``m``
    overwritten)."""
    if isinstance(t, slice):
        rt = r[t]
        np.maximum(rt, m, out=rt)
    else:
        np.maximum(r[t], m, out=m)
        r[t] = m


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
