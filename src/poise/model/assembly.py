"""Sparse assembly with a pattern built once.

Blocks of (row, col) index arrays are registered at compile time (``-1`` marks an entry that
does not exist, e.g. a ground coordinate). The union pattern is sorted once; every later
assembly is one ``np.bincount`` of the concatenated values into the CSR data array (or into a
dense array for small systems). The assembler is part of the immutable model; the
fill-reducing column order of its pattern is made at its first use, once per model, and kept
beside it (:meth:`Assembler.ordered`); the value
buffers live in the solve's workspace (:class:`poise.model.workspace.Workspace`); a sparse
matrix carries its order as a :class:`KKTMatrix`.
"""
from __future__ import annotations

import sys
from functools import cache, partial

import numpy as np

from poise.core import memory, per_object
from poise.core.permutation import inverse

# sums of more entries than this go into reused buffers (np.add.at), smaller ones into fresh
# arrays (np.bincount: the same sums, no pool to look after)
POOL_ABOVE = 1 << 15

#: assembler -> its fill-reducing column order (:meth:`Assembler.ordered`), kept beside it
_ORDERS = per_object.table()


class Assembler:
    """Fixed-pattern assembler for an ``N x N`` matrix, unchanged once made (the compiled
    model seals its arrays); the column order of its pattern, made at its first use, is kept
    beside it (:meth:`ordered`), not in it.

    Parameters
    ----------
    N : int
        Matrix size.
    blocks : iterable of (rows, cols)
        Integer arrays of equal shape; flattened in C order. Entries with a negative row or
        column are ignored. Values passed to :meth:`assemble` must follow the same order and
        shapes. Read once, in order: a generator (the model's layout) or a list, which is
        consumed (its items are released as they are read: the pattern of a large model is
        not held twice).
    dense : bool
        Produce dense ``ndarray`` instead of CSR.
    groups : (N,) ints or None
        Group of each unknown for the fill-reducing column order (:meth:`ordered`): it depends
        on the pattern alone, so every factorisation of every solve of the model reuses it.
    """

    __slots__ = ("N", "dense", "groups", "sizes", "nnz", "indices", "indptr", "slot",
                 "slot_all", "__weakref__")

    def __init__(self, N: int, blocks, dense: bool = False, groups=None):
        self.N = N
        self.dense = dense
        self.groups = groups
        self.indices = self.indptr = None
        sizes = []
        keys = []                           # valid entries' keys row * N + col, per block
        valids = []                         # per block: None (all valid) or the valid mask
        for rows, cols in _consumed(blocks):
            rows = np.asarray(rows).ravel()
            cols = np.asarray(cols).ravel()
            v = (rows >= 0) & (cols >= 0)
            sizes.append(rows.size)
            if v.all():
                v = None
            else:
                rows, cols = rows[v], cols[v]
            key = np.multiply(rows, N, dtype=np.int64)
            key += cols
            keys.append(key)
            valids.append(v)
            del rows, cols, key
        self.sizes = tuple(sizes)
        if dense:
            self.nnz = N * N
            self.slot = np.concatenate(keys) if keys else np.zeros(0, np.int64)
            uniq = None
        else:
            uniq = _sorted_union(keys)
            self.nnz = uniq.size
            self.indices = (uniq % N).astype(np.int32)
            self.indptr = np.searchsorted(uniq, np.arange(N + 1, dtype=np.int64) * N
                                          ).astype(np.int32)
            self.slot = None
        # one slot per registered entry (valid or not): invalid entries go to the extra bin
        # ``nnz``, so assembly needs no boolean gather of the values; block by block, so that
        # the keys of one block at a time are alive beside the slots
        # pooled (large) patterns keep their slots as int32: half the largest array of the
        # model (140 MB at 10^5 links); sums are made block by block, each block's indices
        # widened on the fly
        wide = self.nnz < POOL_ABOVE or self.nnz >= np.iinfo(np.int32).max
        self.slot_all = slot_all = np.empty(sum(sizes), np.intp if wide else np.int32)
        at = 0
        for k, (size, v) in enumerate(zip(sizes, valids)):
            key, keys[k] = keys[k], None
            part = slot_all[at:at + size]
            at += size
            s = key if dense else _positions(uniq, key)
            if v is None:
                part[:] = s
            else:
                part[:] = self.nnz
                part[v] = s
            del key, s
        del keys, valids, uniq

    def assemble(self, values, workspace=None):
        """Assemble the matrix from a list of value arrays (same order/shapes as the blocks);
        ``workspace``: the solve's (its value buffer, below ``POOL_ABOVE`` entries, or its data
        buffers above, are reused: no fresh pages for every assembly; its column order is the
        sparse matrix's).

        A block's values may also be :class:`Zeros` (every value 0) or :class:`Few` (0 but at
        a few of its entries): the same matrix, bit for bit (every sum starts from +0.0, so it
        is never -0.0 and adding a zero leaves it as it is), without a pass over the zeros."""
        if workspace is None or self.nnz < POOL_ABOVE:
            buf = (np.empty(self.slot_all.size) if workspace is None
                   else workspace.scratch(self, _Scratch).values(self.slot_all.size))
            vals = np.concatenate([v.dense() if isinstance(v, Zeros)
                                   else np.asarray(v, float).ravel() for v in values], out=buf)
            data = np.bincount(self.slot_all, weights=vals, minlength=self.nnz + 1)[:self.nnz]
        else:
            # the same sums (each entry from 0, values added in registration order) into a
            # buffer no live matrix uses any more: a fresh array per assembly costs its page
            # faults again (at 10^5 links more than the sums themselves); block by block, so
            # that the values are never copied into one array of every entry (at 10^5 links
            # 140 MB held for the solve)
            # in chunks of _CHUNK entries: np.add.at widens int32 slots to intp, and a block's
            # widened slots in one piece would be fresh pages (above malloc's reuse) every time
            out = workspace.scratch(self, _Scratch).free_data(self.nnz + 1)
            at = 0
            for v in values:
                if isinstance(v, Zeros):
                    if isinstance(v, Few) and v.idx.size:
                        np.add.at(out, self.slot_all[at + v.idx], v.vals)
                    at += v.size
                    continue
                v = np.asarray(v, float).ravel()
                for i in range(0, v.size, _CHUNK):
                    np.add.at(out, self.slot_all[at + i:at + min(i + _CHUNK, v.size)],
                              v[i:i + _CHUNK])
                at += v.size
            if at != self.slot_all.size:
                raise ValueError(f"assemble: {at} values for {self.slot_all.size} entries")
            data = out[:self.nnz]
        if self.dense:
            return data.reshape(self.N, self.N)
        M = _kkt_class()((data, self.indices, self.indptr), shape=(self.N, self.N))
        if self.groups is not None:
            M.poise_column_order = self.ordered                    # used by linalg.Factor
            if workspace is not None:
                M.poise_csc_layout = partial(self.csc_layout, workspace)
        return M

    def release(self, workspace, values: bool = False) -> None:
        """Drop the data buffers kept in ``workspace`` for reuse (a live matrix keeps its own)
        and the column-ordered layout: after a solver's iterations, so that later phases do not
        carry them; ``values``: the value buffer too (no assembly is coming soon)."""
        sc = workspace.scratch(self, _Scratch)
        sc.data = []
        sc.layout = None
        if values:
            sc.buf = None

    def csc_layout(self, workspace) -> "CSCLayout":
        """The :class:`CSCLayout` of this pattern in its column order (:meth:`ordered`), kept
        in ``workspace`` until :meth:`release`. Made at the first factorisation: building it
        costs about what the one-off column-ordered copy of the matrix costs (a CSC conversion),
        so waiting for a second factorisation would pay for both."""
        sc = workspace.scratch(self, _Scratch)
        if sc.layout is None:
            sc.layout = CSCLayout(self, self.ordered())
        return sc.layout

    def ordered(self) -> np.ndarray:
        """The fill-reducing column order (:meth:`column_order`), made at its first use and
        kept while the assembler lives (read-only; in a table beside it, so the compiled model
        stays as compile made it): every later factorisation of the model, in this solve or
        the next (frames, sweeps, other analyses), reads it. Not made at compile: a large
        deck's parsed elements are alive then, and what compile keeps or imports beside them
        raises the solve's peak memory."""
        return per_object.once_per(_ORDERS, self, self._read_only_order)

    def _read_only_order(self) -> np.ndarray:
        order = self.column_order()
        order.flags.writeable = False
        return order

    def pattern(self):
        """Structural pattern: ``(rows, cols)`` of every entry an assembly can fill, unique and
        row-major sorted (for a CSR assembler: the order of its ``data``). Dense assemblers keep
        the same pattern (only the storage is dense)."""
        if self.dense:
            keys = np.unique(np.asarray(self.slot, np.int64))
            return keys // self.N, keys % self.N
        rows = np.repeat(np.arange(self.N, dtype=np.int64), np.diff(self.indptr))
        return rows, self.indices.astype(np.int64)

    def column_order(self) -> np.ndarray:
        """Fill-reducing column order ``q`` (factorise ``A[:, q]`` in natural order), computed once.

        COLAMD runs on the quotient graph of the pattern: one node per group of unknowns
        (``groups``: a body's coordinates, one element's constraint rows). Ordering the
        quotient keeps each group contiguous, costs a fraction of one factorisation, and gives
        SuperLU the same fill as COLAMD on the element-dense pattern (structural zeros inside
        element blocks — which the fixed pattern omits — otherwise mislead COLAMD into a worse
        order). Made once per model (:meth:`ordered`).
        """
        import scipy.sparse as sp             # lazy: sparse models only
        import scipy.sparse.linalg as spla    # lazy
        grp = np.asarray(self.groups, np.int64)
        G = int(grp.max()) + 1 if grp.size else 0
        N = self.N
        # the quotient pattern E^T S E (E: unknown -> its group) without sparse products: the
        # pattern's rows merged group by group (rows taken in group order), columns renamed
        # to their group, duplicates summed (booleans: only the pattern counts)
        indptr, indices = self.indptr, self.indices
        if grp.size and not np.all(grp[1:] >= grp[:-1]):
            rows = np.argsort(grp, kind="stable")
            S = sp.csr_matrix((np.ones(self.nnz, bool), indices, indptr), shape=(N, N))[rows]
            indptr, indices, grp_rows = S.indptr, S.indices, grp[rows]
            del S
        else:
            grp_rows = grp
        cols = grp.astype(np.int32 if G < np.iinfo(np.int32).max else np.intp)[indices]
        qptr = indptr[np.searchsorted(grp_rows, np.arange(G + 1))]
        Q = sp.csr_matrix((np.ones(cols.size, bool), cols, qptr), shape=(G, G))
        del cols
        Q.sum_duplicates()
        Q = Q.tocsc().astype(float)
        Q.data[:] = 1.0
        Q = (Q + sp.identity(G, format="csc") * (G + 1.0)).tocsc()   # diagonally dominant
        # only the ordering is used: it is computed before the factorisation, whose panel
        # size does not change it (panel_size=1: a third less time at 10^5 links); mapped, as
        # the solvers' factorisations: in a large solve's kept heap SuperLU's reservations
        # (its fill estimate, ~1 GB at 10^5 links) would otherwise leave the heap a free top
        # that the next factorisation trims, with the freed pages Newton's first step reuses
        with memory.mapped(G):
            pc = spla.splu(Q, permc_spec="COLAMD", panel_size=1).perm_c
        return np.argsort(pc[grp], kind="stable")      # pc[g]: the rank of group g


class Zeros:
    """A block of ``size`` zero values for :meth:`Assembler.assemble` (nothing to add; the base
    of :class:`Few`)."""

    __slots__ = ("size",)

    def __init__(self, size: int):
        self.size = int(size)

    def dense(self) -> np.ndarray:
        return np.zeros(self.size)


class Few(Zeros):
    """A block of ``size`` values, zero but ``vals`` at the entries ``idx`` (ascending)."""

    __slots__ = ("idx", "vals")

    def __init__(self, size: int, idx, vals):
        super().__init__(size)
        self.idx = np.asarray(idx, np.intp)
        self.vals = np.asarray(vals, float)

    def dense(self) -> np.ndarray:
        out = np.zeros(self.size)
        out[self.idx] = self.vals
        return out


class CSCLayout:
    """A sparse assembler's matrices as SuperLU factorises them: ``A[:, order]`` in CSC, the
    pattern (row indices, column pointers) computed once and the values one gather of the CSR
    data into a reused buffer (instead of a CSC conversion and a column selection, two fresh
    copies of the matrix, per factorisation). ``kept``: ``(mask, layout)``, the layout of a
    part of its entries and what they were chosen for (:meth:`part`: those nonzero in the last
    matrix factorised, SuperLU's input), or None."""

    __slots__ = ("indices", "indptr", "take", "buf", "rows", "cols", "kept")

    def __init__(self, asm: Assembler, order: np.ndarray):
        import scipy.sparse as sp             # lazy: sparse models only
        # the CSR pattern with its columns renamed to their rank in ``order``, converted to CSC
        # with the CSR positions as values: one counting sort (rows come out ascending in
        # every column), no column selection and no float copy of the positions
        small = asm.nnz < np.iinfo(np.int32).max and asm.N < np.iinfo(np.int32).max
        idx = np.int32 if small else np.intp
        rank = inverse(order, idx)
        cols = rank[asm.indices]
        del rank
        A = sp.csr_matrix((np.arange(asm.nnz, dtype=idx), cols, asm.indptr),
                          shape=(asm.N, asm.N)).tocsc()
        del cols
        # int32 where it fits (half the memory); gathered in chunks, each widened on the fly
        self.take = A.data.astype(idx, copy=False)
        self.indices = A.indices.astype(np.int32, copy=False)
        self.indptr = A.indptr.astype(np.int32, copy=False)
        del A
        self.rows, self.cols = asm.indices, asm.indptr      # the CSR pattern it maps from
        self.buf = np.empty(asm.nnz)
        self.kept = None

    def part(self, take, indices, indptr, mask) -> "CSCLayout":
        """The layout of some of this one's entries (positions ``take`` in the CSR data, CSC
        ``indices``/``indptr``), kept in ``kept`` with ``mask`` (what they were chosen for: its
        user's test whether it still fits, :func:`poise.solvers.linalg.stored_nonzeros`)."""
        sub = object.__new__(CSCLayout)
        sub.take, sub.indices, sub.indptr = take, indices, indptr
        sub.rows, sub.cols = self.rows, self.cols
        sub.buf = np.empty(take.size)
        sub.kept = None
        self.kept = (mask, sub)
        return sub

    def fits(self, J) -> bool:
        """Whether ``J`` is a CSR matrix of this layout's pattern (its very index arrays)."""
        return _same(J.indices, self.rows) and _same(J.indptr, self.cols)

    def matrix(self, J):
        """``J[:, order]`` as a CSC matrix whose values live in this layout's buffer (valid
        until the next call: SuperLU copies what it keeps)."""
        import scipy.sparse as sp             # lazy
        take, buf = self.take, self.buf
        for i in range(0, take.size, _CHUNK):
            # mode="clip": the positions are valid; numpy's default ("raise") gathers into a
            # temporary copy of ``out`` and copies it back (a third more time per gather)
            np.take(J.data, take[i:i + _CHUNK], out=buf[i:i + _CHUNK], mode="clip")
        A = sp.csc_matrix((self.buf, self.indices, self.indptr), shape=J.shape, copy=False)
        A.has_canonical_format = True         # sorted rows, no duplicates: made so above
        return A


def _same(a, b) -> bool:
    """``a`` is the array ``b`` or a view of it (a matrix built on the assembler's arrays)."""
    return a is b or (a.base is b and a.shape == b.shape and a.dtype == b.dtype
                      and a.__array_interface__["data"] == b.__array_interface__["data"])


class _Scratch:
    """An assembler's scratch in a solve's workspace: the value buffer, the matrices' data
    buffers and the CSC layout."""

    __slots__ = ("buf", "data", "layout", "free_refs")

    DATA_BUFFERS = 2      # kept for reuse: the iterate's matrix and the one before it

    def __init__(self):
        self.buf = None
        self.data = []
        self.layout = None
        self.free_refs = -1

    def values(self, n: int) -> np.ndarray:
        if self.buf is None:
            self.buf = np.empty(n)
        return self.buf

    def free_data(self, n: int) -> np.ndarray:
        """A zeroed data buffer of ``n`` values that no matrix refers to any more: a matrix
        (and every view of its data) holds a reference to its buffer, so a kept buffer
        with no more references than when only this pool held it is free (CPython reference
        counts, read the same way both times); a new one when every kept buffer is in use."""
        pool = self.data
        for i in range(len(pool)):
            if _refs(pool, i) == self.free_refs:
                buf = pool[i]
                buf[:] = 0.0
                return buf
        if len(pool) >= self.DATA_BUFFERS:
            return np.zeros(n)
        pool.append(np.zeros(n))
        self.free_refs = _refs(pool, len(pool) - 1)       # only the pool refers to it now
        return pool[-1]


def _refs(pool: list, i: int) -> int:
    """References to ``pool[i]`` (one function for the free count and every check)."""
    return sys.getrefcount(pool[i])


@cache
def _kkt_class():
    import scipy.sparse as sp             # lazy: sparse models only

    class KKTMatrix(sp.csr_matrix):
        """A CSR matrix of a model's fixed KKT pattern: ``poise_column_order()`` gives its
        fill-reducing column order (made with the pattern, :meth:`Assembler.ordered`);
        None for matrices derived from it."""

        poise_column_order = None

    KKTMatrix.__module__ = __name__
    return KKTMatrix


def __getattr__(name):
    if name == "KKTMatrix":               # the class is made on first use (scipy is lazy)
        return _kkt_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _consumed(blocks):
    """The items of ``blocks``; a list's items are released (set to None) as they are read, so
    the pattern of a large model is not held twice (a generator holds one at a time anyway)."""
    if isinstance(blocks, list):
        for k in range(len(blocks)):
            item, blocks[k] = blocks[k], None
            yield item
    else:
        yield from blocks


def _sorted_union(keys: list) -> np.ndarray:
    """The sorted unique values of all arrays in ``keys``, merged one array at a time (the
    temporaries are those of one block, not of all entries at once). The registered keys come
    in long ascending runs (element blocks in instance order) and the union so far is one run:
    the stable sort (timsort) merges them in near-linear time where introsort pays ``n log n``."""
    uniq = np.zeros(0, np.int64)
    for key in keys:
        u = np.sort(key, kind="stable")
        if uniq.size:
            u = np.concatenate([uniq, _distinct(u)])
            u.sort(kind="stable")
        uniq = _distinct(u)
        del u
    return uniq


_CHUNK = 1 << 20


def _positions(uniq: np.ndarray, key: np.ndarray) -> np.ndarray:
    """``np.searchsorted(uniq, key)``, in chunks whose keys are sorted first (binary searches
    for ascending keys share their bounds: twice as fast as on the keys' runs as they come)."""
    out = np.empty(key.size, np.intp)
    for i in range(0, key.size, _CHUNK):
        c = key[i:i + _CHUNK]
        p = np.argsort(c, kind="stable")
        out[i:i + _CHUNK][p] = np.searchsorted(uniq, c[p])
    return out


def _distinct(u: np.ndarray) -> np.ndarray:
    """The distinct values of the sorted array ``u``."""
    if u.size < 2:
        return u
    new = np.empty(u.size, bool)
    new[0] = True
    np.not_equal(u[1:], u[:-1], out=new[1:])
    return u[new]


class Scatter:
    """``vals`` added at fixed indices ``idx`` of a length-``n`` vector (negative indices
    ignored), repeated (a family's residual rows at every evaluation): the negative indices go
    to an extra bin once, and above ``POOL_ABOVE`` entries the sums are made in one reused
    buffer (``add(out, vals)`` adds them to ``out``; the same sums in the same order as
    ``out += np.bincount(idx[idx >= 0], vals[idx >= 0], minlength=n)``)."""

    __slots__ = ("n", "idx", "buf")

    def __init__(self, n: int, idx):
        idx = np.asarray(idx).ravel()
        self.n = n
        self.idx = np.where(idx >= 0, idx, n).astype(np.intp)
        self.buf = np.zeros(n + 1) if idx.size >= POOL_ABOVE else None

    def add(self, out: np.ndarray, vals) -> None:
        vals = np.asarray(vals, float).ravel()
        if self.buf is None:
            out += np.bincount(self.idx, weights=vals, minlength=self.n + 1)[:self.n]
            return
        buf = self.buf
        buf[:] = 0.0
        np.add.at(buf, self.idx, vals)
        out += buf[:self.n]

    def add_parts(self, out: np.ndarray, parts) -> None:
        """:meth:`add` of values that come as consecutive pieces (an iterable of arrays, a big
        family's chunks): the same sums in the same order, no array of all the values."""
        if self.buf is None:
            self.add(out, np.concatenate([np.asarray(v, float).ravel() for v in parts]))
            return
        buf = self.buf
        buf[:] = 0.0
        at = 0
        for v in parts:
            v = np.asarray(v, float).ravel()
            np.add.at(buf, self.idx[at:at + v.size], v)
            at += v.size
        if at != self.idx.size:
            raise ValueError(f"Scatter.add_parts: {at} values for {self.idx.size} entries")
        out += buf[:self.n]
