"""Stability of large models (``nq > DENSE_LIMIT``): inertia by spectrum slicing.

``K_red`` is never formed: the inertia is counted from sparse ``L D L^T`` factorisations of the
equilibrated, augmented KKT matrix (:class:`SymmetricLDL`, :class:`SparsePencil`), and the
unstable/neutral modes come from operators applied with those factorisations. Why and how
(the equilibration, the augmentation, the trust tests, the mode iterations): docs/stability.md.
"""
from __future__ import annotations

import numpy as np

from poise.core import memory
from poise.core.permutation import inverse
from poise.solvers.equilibrate import equilibrate as _equilibrate
from poise.solvers.equilibrate import kkt_rows
from poise.solvers.equilibrate import prune_noise as _prune_noise
from poise.solvers.equilibrate import prune_rows as _prune_rows
from poise.solvers.redundancy import redundant_rows
from poise.solvers.stability_iterations import lowest_mode, negative_modes, zero_modes
from poise.solvers.stability_modes import (
    AUG_RHO,
    BERR_MAX,
    TINY_PIVOT,
    WEAK_DIAG,
    ZERO_REL,
    StabilityInfo,
    classified_info,
    not_classified,
)
from poise.solvers.symmetric_ldl import (  # noqa: F401 - re-exported
    SymmetricLDL,
    symmetric_permutation,
)


def classify_sparse(model, J, active=None, kkt_columns=None) -> StabilityInfo:
    """Inertia by spectrum slicing with sparse LDL^T factorisations of the equilibrated KKT
    matrix (module docstring, "Large models"). Active constraint rows that have become
    dependent at this configuration (a tiny pivot at a constraint row) are found by the
    redundancy test of the static driver and dropped (the null space is unchanged), once.
    ``J`` may be a zero-argument callable returning the matrix (:class:`SparsePencil`);
    ``kkt_columns``: the solve's column order of the KKT matrix, if it has one
    (:meth:`~poise.model.assembly.Assembler.ordered`): it ranks the bodies (no ordering of
    its own; if it gives no trustworthy count, the pencil's own order is tried)."""
    try:
        # lean: a stable model needs Gt^T Gt for one matrix only
        P = SparsePencil(model, J, active=active, lean=True, kkt_columns=kkt_columns)
        J = None
        info = classify_pencil(model, P)
        if info.klass == "unknown" and kkt_columns is not None:
            # no trustworthy count in the solve's order: the pencil's own (minimum degree)
            P = SparsePencil(model, P, active=active, lean=True)
            info = classify_pencil(model, P)
        if info.klass == "unknown" and P.singular:
            red = redundant_rows(P.G_active, np.ones(model.nq))
            if len(red):
                P = SparsePencil(model, P, drop=red, active=active, lean=True,
                                 kkt_columns=kkt_columns)
                info = classify_pencil(model, P)
        return info
    except (RuntimeError, ValueError, ArithmeticError, MemoryError,
            np.linalg.LinAlgError) as e:
        return not_classified(f"sparse classification failed ({type(e).__name__}: {e})")


def classify_pencil(model, P) -> StabilityInfo:
    m, eps = P.m, P.eps
    up, why = P.factor(+eps)
    if up is None:
        return not_classified(why)
    below = up.n_negative - m                       # eigenvalues < +eps
    if below < 0:
        return not_classified("KKT inertia has fewer negative pivots than active constraint rows "
                        "(dependent constraint rows?)")
    if below == 0:
        if P.nq == m:                    # valid factorisation: Gt square and non-singular
            return StabilityInfo("stable", 0, 0, "no degrees of freedom", np.inf)
        low = lowest_mode(P, up, +eps)
        return StabilityInfo("stable", 0, 0, "", low[0][1] if low else np.nan)
    del up                       # its factors (and SuperLU's copies of L and U) go first
    dn, why = P.factor(-eps)
    if dn is None:
        return not_classified(why)
    n_neg = dn.n_negative - m                       # eigenvalues < -eps
    if not 0 <= n_neg <= below:
        return not_classified(f"inconsistent inertia at the two shifts ({below} eigenvalues below "
                        f"+{eps:.1e}, {n_neg} below -{eps:.1e})")
    n_zero = below - n_neg
    unstable = negative_modes(P, dn, -eps, n_neg) if n_neg else []
    neutral = zero_modes(P, dn, -eps, n_zero) if n_zero else []
    ws = [w for _, w in unstable + neutral]
    klass = "unstable" if n_neg else "neutral"
    return classified_info(model, klass, n_neg, n_zero, unstable, neutral, min(ws) if ws else np.nan)


def _diag_scaled(M, r, c):
    """``diags(r) @ M @ diags(c)`` for a CSR ``M``, the very arrays scipy's two sparse products
    give, without them: each entry ``(r_i m_ij) c_j``, exact zeros dropped, entries in ``M``'s
    order. ``M`` with duplicate entries (which those products would sum) takes scipy's
    products."""
    import scipy.sparse as sp
    if not M.has_canonical_format:
        return (sp.diags(r) @ M @ sp.diags(c)).tocsr()
    return _scaled_block(sp.csr_matrix((M.data.copy(), M.indices.copy(), M.indptr.copy()),
                                       shape=M.shape), r, c)


def _scaled_block(M, r, c):
    """``M`` (a CSR block of the Jacobian: a fresh copy, scaled in place) with each entry
    ``(r_i m_ij) c_j`` (``r`` None: ``m_ij c_j``), exact zeros dropped (explicit ones, and
    products that underflow), entries in ``M``'s order. The explicit zeros go before the
    scaling (the stiffness block of an assembled Jacobian is mostly stored zeros of its
    pattern): the same entries, fewer products."""
    if not M.data.all():
        M.eliminate_zeros()
    if r is not None:
        M.data *= np.repeat(r, np.diff(M.indptr))
    M.data *= c[M.indices]
    if not M.data.all():
        M.eliminate_zeros()
    return M


class SparsePencil:
    """The reduced-stiffness eigenproblem of a large model, never formed: the length-scaled
    symmetric stiffness ``Kt`` and active constraint Jacobian ``Gt`` after a symmetric
    equilibration of the KKT matrix, the KKT elimination order, and factorisations at shifts."""

    def __init__(self, model, J, drop=(), active=None, like=None, lean: bool = False,
                 kkt_columns=None):
        """``J``: the KKT Jacobian, a zero-argument callable returning it (then it goes as soon
        as its blocks are read) or a pencil of the same Jacobian (its stiffness and constraint
        rows are taken, e.g. to ``drop`` rows). ``like``: a pencil of the same model at a
        nearby configuration (a descent's previous step): its elimination order is reused and
        its scaling starts the equilibration, when it has the same constraint rows (an order is
        a permutation: any one gives the inertia; a poor one shows as a failed factorisation,
        and the caller builds a fresh pencil). ``lean``: ``Gt^T Gt`` is dropped once a matrix
        is built from it (:attr:`GtG` makes it again when needed). ``kkt_columns``: a
        fill-reducing column order of the model's KKT matrix (made once per model, at its
        first use): the bodies are eliminated in its order instead of a minimum-degree order of
        their own (:func:`_kkt_order`)."""
        import scipy.sparse as sp
        nq = model.nq
        d = np.asarray(model.q_scale, float)
        rows = np.arange(model.nc) if active is None else np.nonzero(active)[0]
        if isinstance(J, SparsePencil):
            Ks, G, nnz = J.Ks, J.G_active, J.G_active.nnz
        else:
            J = sp.csr_matrix(memory.taken(J))
            nnz = J.nnz
            Di = 1.0 / d
            Ku = _scaled_block(J[:nq, :nq], Di, Di)
            Ku = Ku + Ku.T.tocsr()
            Ku.data *= 0.5
            Ks = _prune_noise(Ku)
            G = J[nq:, :nq]
            G = _scaled_block(G if len(rows) == G.shape[0] else G[rows], None, Di)
            J = Ku = None                 # (a handed-over Jacobian goes here)
        self.G_active = G                 # active rows, length-scaled (dependent-row check)
        self.rows = rows                  # constraint rows of Gt (model indices)
        if G.shape[0]:
            # a numerically empty row does not constrain anything (the dense SVD's rcond);
            # ``drop``: active rows found dependent at this configuration
            rn = _row_norms(G)
            keep = rn > 1e-10 * rn.max()
            keep[np.asarray(drop, np.int64)] = False
            if not keep.all():
                G = G[keep]
                self.rows = self.rows[keep]
            G = _prune_rows(G)          # entries at round-off of their row
        same = like is not None and like.nq == nq and np.array_equal(like.rows, self.rows)
        dq, dl = _equilibrate(Ks, G, start=(like.dq, like.dl) if same else None)
        self.Kt = _diag_scaled(Ks, dq, dq)
        self.Gt = _diag_scaled(G, dl, dq)
        self._GtG = self._Gc = None
        self.Ks, self.d, self.dq, self.dl = Ks, d, dq, dl
        self.nq, self.m = nq, self.Gt.shape[0]
        self.reused = same
        self.order = (like.order if same else
                      _kkt_order(model, self.Kt, self.Gt, self.GtG, kkt_columns))
        # zero threshold: ZERO_REL of the spectral radius of Kt (an upper bound of the reduced
        # matrix's), at least ZERO_REL (Kt has a unit-scale diagonal block after equilibration)
        self.eps = ZERO_REL * max(_spectral_radius(self.Kt), 1.0)
        self.singular = False             # a tiny pivot at a constraint row was met
        self.lean = lean                  # Gt^T Gt not kept beside a factorisation
        self._pos = None                  # the permuted position of each unknown
        memory.release_stage(nnz * 16)    # the temporaries' pages (large models)

    @property
    def GtG(self):
        """``Gt^T Gt`` in canonical CSR (kept until a :attr:`lean` pencil's factorisation drops
        it, then made again when needed: the same matrix). The product of ``Gt^T``'s rows
        (:attr:`Gc`) and ``Gt``'s is scipy's ``Gt.T @ Gt`` kernel call, with its indices sorted in
        place: entry ``(i, j)`` sums the products ``g_ki g_kj`` in ascending ``k`` as ``(j, i)``
        does, so the matrix is symmetric bit for bit and these are the arrays of its CSC copy
        converted to CSR, without that conversion."""
        if self._GtG is None:
            G = self.Gc.T @ self.Gt
            G.sort_indices()
            self._GtG = G
        return self._GtG

    @property
    def Gc(self):
        """``Gt`` in CSC (its transpose's rows: :attr:`GtG` and :meth:`permuted_kkt` read them),
        kept and dropped with :attr:`GtG`."""
        if self._Gc is None:
            self._Gc = self.Gt.tocsc()
        return self._Gc

    def kkt(self, s, rho):
        """``[[Kt - s I + rho Gt^T Gt, Gt^T], [Gt, 0]]`` (congruent to the rho = 0 matrix)."""
        import scipy.sparse as sp
        A = self.Kt + rho * self.GtG - s * sp.identity(self.nq, format="csr")
        if self.m == 0:
            return A.tocsc()
        return sp.bmat([[A, self.Gt.T], [self.Gt, None]], format="csc")

    def permuted_kkt(self, s, rho):
        """``kkt(s, rho)[order][:, order]`` in CSC, the very arrays :func:`symmetric_permutation`
        gives (each column holds its entries in the unpermuted row order, relabelled), by
        scipy's compiled kernels: the KKT matrix's columns are the rows of its transpose,
        stacked as CSR (:func:`~poise.solvers.equilibrate.kkt_rows`: the upper-left block's
        columns, ``Gt``'s columns under them, ``Gt``'s rows as the last columns, in sorted order
        as the block matrix has them), gathered in the elimination order and their row indices
        relabelled (no block matrix, no fancy-indexed copies, no scatter)."""
        import scipy.sparse as sp
        nq, n = self.nq, self.nq + self.m
        # the upper-left block by columns: the rows of its transpose, Kt^T + rho Gt^T Gt - s I
        # (Gt^T Gt is symmetric bit for bit: each entry sums the same products in the same
        # order), the very entries kkt(s, rho)'s block has, without transposing that block
        GtG = self.GtG if rho == 1.0 else rho * self.GtG
        A = self.Kt.T.tocsr() + GtG - s * sp.identity(nq, format="csr")
        GtG = None
        if self._pos is None:
            self._pos = inverse(self.order)
        Gr = self.Gt if self.Gt.has_sorted_indices else self.Gt.sorted_indices()
        T = kkt_rows(A, Gr, self.Gc)         # row j: column j of kkt(s, rho)
        A = Gr = None
        if self.lean:
            self._GtG = self._Gc = None
        T = T[self.order]                    # (scipy's compiled row gather)
        indptr, indices, data = T.indptr, T.indices, T.data
        nnz = int(indptr[-1])
        T = None
        np.take(self._pos.astype(indices.dtype), indices, out=indices)
        A = sp.csc_matrix((data, indices, indptr), shape=(n, n))
        memory.release_stage(nnz * 16)    # the temporaries' pages (large models)
        return A

    def ldl(self, s, rho):
        """The :class:`SymmetricLDL` of ``kkt(s, rho)`` in the pencil's elimination order."""
        return SymmetricLDL(lambda: self.permuted_kkt(s, rho), self.order, permuted=True)

    def factor(self, s):
        """A valid LDL^T of ``kkt(s, rho)`` for the first ``rho`` of AUG_RHO whose backward
        error is below ``BERR_MAX * eps`` and whose pivots are all above ``TINY_PIVOT * eps``
        (a pivot at round-off level has no reliable sign: the matrix is numerically singular,
        typically dependent constraint rows at this configuration); else ``(None, reason)``."""
        why = []
        F = None
        for rho in AUG_RHO:
            F = None                      # a failed attempt's factors go before the next
            F = self.ldl(s, rho)
            if not F.ok:                  # a zero pivot (exactly dependent rows?)
                self.singular = True
                why.append(F.reason)
                continue
            if F.backward_error > BERR_MAX * self.eps:
                why.append(f"LDL^T backward error {F.backward_error:.1e} above "
                           f"{BERR_MAX:g} x the zero threshold {self.eps:.1e}")
                continue
            tiny = np.abs(F.pivots) < TINY_PIVOT * self.eps
            if tiny.any():
                at_row = bool(np.any(F.index[tiny] >= self.nq))
                self.singular |= at_row
                why.append(f"pivot {np.abs(F.pivots).min():.1e} below {TINY_PIVOT:g} x the zero "
                           f"threshold: numerically singular"
                           + (" (dependent constraint rows?)" if at_row else ""))
                continue
            return F, ""
        return None, (f"sparse inertia of the {self.nq + self.m}-unknown KKT matrix at shift "
                      f"{s:+.1e} not reliable ({why[0]}; {len(why) - 1} other augmentation "
                      "weights failed too)")

    def op(self, F):
        """``v -> x`` with ``kkt(s) [x; y] = [v; 0]``: ``Z (Z^T (Kt - s I) Z)^-1 Z^T v`` for an
        orthonormal null-space basis Z of Gt (symmetric; its range satisfies Gt x = 0)."""
        from scipy.sparse.linalg import LinearOperator
        nq = self.nq

        def mv(v):
            return F.solve_head(v, nq)
        return LinearOperator((nq, nq), matvec=mv, matmat=mv, dtype=float)

    def modes(self, X):
        """Check the columns of X (scaled coordinates) and return [(q, w, mu)]: ``q`` in model
        coordinates, ``w`` the Rayleigh quotient in length coordinates [force/length] (as the
        dense path), ``mu`` the scaled Rayleigh quotient (compared with ``eps``)."""
        X = np.asarray(X, float).reshape(self.nq, -1)
        nx = np.linalg.norm(X, axis=0)
        ok = np.isfinite(nx) & (nx > 0.0)
        X = X[:, ok] / nx[ok]
        if self.m:                                    # on the manifold (Gt x = 0)?
            X = X[:, np.linalg.norm(self.Gt @ X, axis=0) <= 1e-6]
        mu = np.einsum("ij,ij->j", X, self.Kt @ X)
        XL = self.dq[:, None] * X
        XL /= np.linalg.norm(XL, axis=0)
        w = np.einsum("ij,ij->j", XL, self.Ks @ XL)
        return [(XL[:, j] / self.d, float(w[j]), float(mu[j])) for j in range(X.shape[1])]


def _row_norms(M):
    """Euclidean norms of the rows of a canonical CSR ``M`` (an empty row: 0)."""
    sq = np.zeros(M.shape[0])
    nz = np.diff(M.indptr) > 0
    if nz.any():
        sq[nz] = np.add.reduceat(M.data * M.data, M.indptr[:-1][nz])
    return np.sqrt(sq)


def _coordinate_groups(model) -> np.ndarray:
    """Group of each coordinate: one per body, one per scalar unknown."""
    nq, nb = model.nq, model.nb
    grp = np.full(nq, -1, np.int64)
    if nb:
        size = np.where(np.asarray(model.body_kind) == 0, 6, 3)
        within = np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
        grp[np.repeat(np.asarray(model.body_off), size) + within] = np.repeat(np.arange(nb), size)
    free = grp < 0
    grp[free] = nb + np.arange(int(free.sum()))
    return grp


def _kkt_order(model, K, G, GtG, kkt_columns=None) -> np.ndarray:
    """Symmetric elimination order of the KKT matrix for 1x1 pivots. Bodies (and scalar
    unknowns) are ordered as in ``kkt_columns`` (a fill-reducing column order of the KKT
    matrix, the solve's LU order) or else by minimum degree on the quotient graph (one node
    per body) of ``|K| + |G|^T |G|``; every constraint row comes right after the last of the
    bodies it acts on (its pivot is then ``-g A^-1 g^T``, not its zero diagonal), and so does
    every *weak* coordinate (augmented diagonal ``|K_ii + (G^T G)_ii|`` below ``WEAK_DIAG``,
    e.g. a scalar unknown with no stiffness of its own): eliminated first, its near-zero pivot
    would blow up the rest of the factor."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    nq = model.nq
    grp = _coordinate_groups(model)
    ng = int(grp.max()) + 1
    K, GtG = K.tocsr(), GtG.tocsr()
    Gp = G.tocsr() if G.shape[0] else None        # (its pattern: the bodies of each row)
    if kkt_columns is not None and ng > 1:
        # a group's rank: the position of its first coordinate among the KKT columns (ranks
        # need not be consecutive: only their order counts)
        at = inverse(kkt_columns, np.int64)
        rank = np.full(ng, len(kkt_columns), np.int64)
        np.minimum.at(rank, grp, at[:nq])
    elif ng > 1:
        # the pattern of E^T (|K| + |G|^T |G|) E, from K and from the bodies each constraint
        # row acts on (|G| E: a few entries a row), not from the larger G^T G
        E = sp.csr_matrix((np.ones(nq), (np.arange(nq), grp)), shape=(nq, ng))
        Q = E.T @ abs(K) @ E
        if Gp is not None:
            GE = abs(Gp) @ E
            Q = Q + GE.T @ GE
        Q = Q.tocsc()
        Q.data[:] = 1.0
        Q = (Q + sp.identity(ng, format="csc") * (ng + 1.0)).tocsc()   # diagonally dominant
        rank = spla.splu(Q, permc_spec="MMD_AT_PLUS_A").perm_c       # position of each group
    else:
        rank = np.zeros(1, np.int64)
    key = 3 * rank[grp]
    nzr = (np.diff(K.indptr) > 0) | (np.diff(GtG.indptr) > 0)       # rows of |K| + |GtG|
    weak = (np.abs(K.diagonal() + GtG.diagonal()) < WEAK_DIAG) & nzr   # (K + GtG)'s
    if weak.any():
        S = (abs(K) + abs(GtG)).tocsr()
        S.sum_duplicates()
        last = np.zeros(nq, np.int64)
        last[nzr] = np.maximum.reduceat(rank[grp[S.indices]], S.indptr[:-1][nzr])
        key[weak] = 3 * last[weak] + 2
    keys = [key]
    if Gp is not None:
        last = np.maximum.reduceat(rank[grp[Gp.indices]], Gp.indptr[:-1])
        keys.append(3 * last + 1)
    return np.argsort(np.concatenate(keys), kind="stable")


def _spectral_radius(A, iters=20) -> float:
    """Power-iteration estimate (a lower bound) of the spectral radius of symmetric CSR A:
    ``x <- A @ (x / |x|)``, ``iters`` times."""
    n = A.shape[0]
    x = np.random.default_rng(20240611).standard_normal(n)
    r = 0.0
    nx = np.linalg.norm(x)
    for _ in range(iters):
        if nx == 0.0:
            break
        x = A @ (x / nx)
        nx = np.linalg.norm(x)          # (the next step's divisor too)
        r = float(nx)
    return r
