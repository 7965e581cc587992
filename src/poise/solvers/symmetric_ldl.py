"""Sparse ``L D L^T`` with 1x1 diagonal pivots in a given symmetric order, and its inertia.

SuperLU in symmetric mode without pivoting (``diag_pivot_thresh=0``): the signs of the pivots
are the inertia (Sylvester) when no off-diagonal pivot was taken, and a backward-error estimate
says whether that count can be trusted. Used by the sparse stability pencil and the descent's
(:mod:`poise.solvers.stability_sparse`); method: docs/stability.md.
"""
from __future__ import annotations

import numpy as np

from poise.core import memory
from poise.core.permutation import inverse
from poise.solvers.superlu import splu


class SymmetricLDL:
    """Sparse ``L D L^T`` of a symmetric matrix with 1x1 diagonal pivots only, and its inertia.

    SuperLU in symmetric mode with ``diag_pivot_thresh=0`` takes every diagonal pivot that is
    not exactly zero; when no off-diagonal pivot was taken (``perm_r == perm_c``) the factors
    of ``P^T A P`` satisfy ``U = D L^T`` and, by Sylvester's law of inertia, the signs of the
    pivots ``diag(U)`` are the signs of A's eigenvalues. ``order`` is a symmetric elimination
    order (``A[order][:, order]`` is factorised as given); None lets SuperLU choose (minimum
    degree on A + A^T).

    ``ok`` is False (with ``reason``) when a pivot was zero, non-finite or off the diagonal.
    Without pivoting the factorisation is not backward stable in general, so
    ``backward_error = 32 u ||(|L| |U|) 1||_inf`` estimates ``||L D L^T - A||``: the counted
    inertia is A's when this is below A's smallest |eigenvalue| (Weyl).

    ``lu`` is SciPy's SuperLU object. Its first read of ``lu.U`` (the pivots, here) makes and
    caches CSC copies of both factors; :attr:`backward_error` reads them and then empties
    both (the solves use SuperLU's own factors): after it, ``lu.L`` and ``lu.U`` are empty
    matrices of their shapes.
    """

    def __init__(self, A, order=None, permuted: bool = False):
        """``permuted``: ``A`` is ``A[order][:, order]`` already (:func:`symmetric_permutation`).
        ``A`` may be a zero-argument callable returning the matrix: then only this call holds
        it, and it goes as soon as SuperLU has its copy (before the factors are read)."""
        self.order = None if order is None else np.asarray(order)
        self._permuted = permuted
        self._pos = None
        self._b = None                    # solve_head's right-hand side (:meth:`_rhs`)
        A = self._matrix(memory.taken(A))
        self.n = n = A.shape[0]
        self.ok = False
        self.reason = ""
        self._berr = np.inf
        self.n_negative = self.n_positive = -1
        try:
            lu = self._splu(A)
        except RuntimeError as e:
            self.reason = f"the LDL^T factorisation failed ({e})"
            return
        del A                             # SuperLU holds its own copy
        if not np.array_equal(lu.perm_r, lu.perm_c):
            self.reason = "the LDL^T factorisation needed an off-diagonal pivot"
            return
        d = lu.U.diagonal()               # (SciPy makes and keeps CSC copies of U and L)
        if not np.all(np.isfinite(d)) or np.any(d == 0.0):
            self.reason = "the LDL^T factorisation has a zero or non-finite pivot"
            return
        self._berr = None                 # computed on first use (the descent never asks)
        self.pivots = d
        # original index of each pivot (pivot k eliminates column perm_c^-1[k] of A[order])
        self.index = np.empty(n, np.int64)
        self.index[lu.perm_c] = np.arange(n) if self.order is None else self.order
        self.n_negative = int(np.count_nonzero(d < 0))
        self.n_positive = n - self.n_negative
        self.lu = lu
        self.ok = True

    def _matrix(self, A):
        import scipy.sparse as sp
        A = sp.csc_matrix(A)
        if self.order is not None and not self._permuted:
            A = symmetric_permutation(A, self.order)
        return A

    def _splu(self, A):
        """SuperLU column by column at any size (``panel_size=1``): the KKT matrices' supernodes
        are narrow, so panels buy nothing (``poise.solvers.superlu``; 4.4 -> 3.1 ms at 11 000
        unknowns); the pivots, hence the inertia, are the same."""
        return splu(A, permc_spec="MMD_AT_PLUS_A" if self.order is None else "NATURAL",
                    diag_pivot_thresh=0.0, options=dict(SymmetricMode=True), panel_size=1)

    @property
    def backward_error(self) -> float:
        """``32 u ||(|L| |U|) 1||_inf`` (inf when the factorisation is not valid). Empties
        ``lu.L`` and ``lu.U`` (SciPy's cached copies of the factors) once it has read them."""
        if self._berr is None:
            # two compiled sparse products over SciPy's CSC copies of the factors (both made at
            # the first read of lu.U), each made absolute in place, read, and emptied (the
            # solves use SuperLU's own factors): neither copy is held after this
            U = self.lu.U
            g = _abs_matvec(U, np.ones(self.n))
            _empty(U)
            L = self.lu.L
            g = _abs_matvec(L, g)
            _empty(L)
            self._berr = 32 * np.finfo(float).eps * float(np.max(g, initial=0.0))
        return self._berr

    @property
    def inertia(self) -> tuple[int, int, int]:
        """(negative, zero, positive) pivot counts (no zero pivot in a valid factorisation)."""
        return self.n_negative, 0, self.n_positive

    def solve(self, b, overwrite_b: bool = False):
        """``A^-1 b``; ``overwrite_b``: the solution is written into ``b`` (one array of the
        system's size fewer at a time)."""
        b = np.asarray(b, float)
        if self.order is None:
            return self.lu.solve(b)
        y = self.lu.solve(np.ascontiguousarray(b[self.order]))
        x = b if overwrite_b else np.empty_like(y)
        x[self.order] = y
        return x

    #: right-hand sides solved together by :meth:`solve_head` (SuperLU solves every column
    #: alone, so the grouping changes no bit; it bounds the temporaries of a wide block)
    HEAD_COLUMNS = 4

    def solve_head(self, v, k: int):
        """``(A^-1 [v; 0])[:k]`` for ``v`` with ``k`` rows (a vector or a block of columns),
        bit for bit :meth:`solve`'s, without its full-size reordered copies: the right-hand
        side is made in the factorisation's order, and only the head of the solution is
        gathered back."""
        v = np.asarray(v, float)
        if self._pos is None:
            self._pos = np.arange(self.n) if self.order is None else inverse(self.order)
        at = self._pos[:k]
        if v.ndim == 1:
            b = np.zeros(self.n)
            b[at] = v
            return self.lu.solve(b)[at]
        out = np.empty(v.shape)
        w = self.HEAD_COLUMNS
        for c in range(0, v.shape[1], w):
            b = self._rhs(min(w, v.shape[1] - c))
            b[at] = v[:, c:c + w]
            out[:, c:c + w] = self.lu.solve(b)[at]      # (SuperLU solves a copy of b)
        return out

    def _rhs(self, w: int):
        """A zero right-hand side of ``w`` columns in Fortran order, kept for the next block of
        that width: :meth:`solve_head` writes the same head rows every time, the tail stays
        zero (no fresh, page-faulted array per block of a subspace iteration)."""
        b = self._b
        if b is None or b.shape[1] != w:
            b = self._b = np.zeros((self.n, w), order="F")
        return b


def _abs_matvec(M, x):
    """``|M| x`` for a CSC factor copy ``M`` (SuperLU's ``L`` / ``U``), whose values are made
    absolute in place."""
    np.abs(M.data, out=M.data)
    return M @ x


def _empty(M):
    """Free the arrays of SuperLU's cached CSC copy ``M`` of a factor: the SuperLU object keeps
    the copy it made on the first read of ``lu.L`` / ``lu.U`` for later reads, which never come
    (the solves use its own factors); ``M`` becomes the empty matrix of its shape."""
    M.data = np.zeros(0)
    M.indices = np.zeros(0, np.int32)
    M.indptr = np.zeros(M.shape[1] + 1, np.int32)


def symmetric_permutation(A, order):
    """``A[order][:, order]`` in CSC (a fresh matrix: the caller's ``A`` can go before the
    factorisation, which then holds one copy of the matrix, not two)."""
    return A[order][:, order].tocsc()
