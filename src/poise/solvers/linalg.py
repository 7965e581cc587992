"""Linear algebra chosen once per model: dense LU for small systems, SuperLU for large ones."""
from __future__ import annotations

import warnings

import numpy as np

from poise.core import phases
from poise.core.lean import all_finite, norm
from poise.core.permutation import inverse
from poise.solvers.superlu import splu

# Dense systems up to this size are solved with numpy's LAPACK (the inverse of the regularity
# bound, else gesv) and checked with an SVD where that bound does not decide: no scipy import on
# the small-deck path (scipy.linalg/sparse cost ~0.25 s of process start).
NUMPY_DENSE_MAX = 120


try:
    from numpy.linalg import _umath_linalg
except ImportError:  # (numpy's layout changed: the public function)
    _umath_linalg = None


def _inverse(J):
    """``np.linalg.inv(J)`` of a real square matrix (the same LAPACK call and result)."""
    if _umath_linalg is None or J.dtype != np.float64:
        return np.linalg.inv(J)
    return _umath_linalg.inv(J, signature="d->d")


def kept_entries(M, keep):
    """The CSR or CSC ``M`` without its stored entries where ``keep`` (one flag per entry) is
    False: ``M`` itself when all stay, else a new matrix of the kept entries in ``M``'s order
    (``M``'s arrays, which may be shared, are left as they are)."""
    if keep.all():
        return M
    at = np.empty(keep.size + 1, M.indptr.dtype)    # kept entries before each one
    at[0] = 0
    np.cumsum(keep, out=at[1:])
    return type(M)((M.data[keep], M.indices[keep], at[M.indptr]), shape=M.shape)


def stored_nonzeros(A):
    """The CSC ``A`` without its stored exact zeros (:func:`kept_entries`). SuperLU takes every
    stored entry for a nonzero, and the model's pattern stores every entry a family's block may
    fill, also where the block is zero for this model at every configuration (the out-of-plane
    multipliers and components of a planar model): the factors would carry that fill and
    every solve its work. The same matrix, the same pivots; only the factors' round-off may
    differ."""
    return kept_entries(A, A.data != 0.0)


def _layout_nonzeros(lay, J):
    """``stored_nonzeros(lay.matrix(J))`` (the column-ordered CSC ``J`` without its stored
    exact zeros, ``lay`` its :class:`~poise.model.assembly.CSCLayout`) through the layout of
    ``J``'s nonzero entries (:meth:`~poise.model.assembly.CSCLayout.part`), kept while ``J``'s
    zeros are where they were (Newton's matrices of a model: the same entries are zero at every
    iteration): then a gather of the nonzero values alone, instead of a gather of every entry
    and its compaction (a running count, copies of the kept values and row indices: fresh
    arrays) at every factorisation. The same matrix, bit for bit."""
    nz = J.data != 0.0
    if lay.kept is not None and np.array_equal(nz, lay.kept[0]):
        return lay.kept[1].matrix(J)
    import scipy.sparse as sp  # lazy: sparse systems only
    at = kept_entries(sp.csc_matrix((lay.take, lay.indices, lay.indptr), shape=J.shape),
                      nz[lay.take])                     # CSR positions of the kept entries
    return lay.part(at.data, at.indices, at.indptr, nz).matrix(J)


class SingularMatrix(Exception):
    """Raised when a factorisation is (numerically) singular; ``row`` is the worst row if known."""

    def __init__(self, message, row=None):
        super().__init__(message)
        self.row = row


def _pow2(x):
    """Nearest powers of two of ``1 / x`` (1 where x is 0 or not finite): exact scalings."""
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where((x > 0) & np.isfinite(x), -np.round(np.log2(np.where(x > 0, x, 1.0))), 0.0)
    return np.exp2(e)


def equilibration(J):
    """Row and column scalings ``(r, c)`` (powers of two) with ``diag(r) J diag(c)`` of unit
    largest entry per row, then per column: the singularity test then sees the matrix's rank,
    not its units (a 1e-9 N/mm spring next to a 1e12 one is a regular system)."""
    if hasattr(J, "tocsr"):
        A = abs(J.tocsr())
        r = _pow2(np.asarray(A.max(axis=1).todense()).ravel())
        c = _pow2(np.asarray((A.multiply(r[:, None])).max(axis=0).todense()).ravel())
    else:
        A = np.abs(np.asarray(J))
        r = _pow2(A.max(axis=1))
        c = _pow2((A * r[:, None]).max(axis=0))
    return r, c


def _columns_ordered(J, order):
    """``J[:, order]`` in CSC. From CSR in one conversion (its columns renamed to their rank in
    ``order``: the same matrix, rows ascending in every column) instead of a CSC copy and a
    column selection (two fresh copies of the matrix: at 10^5 links 0.2 GB of new pages)."""
    if getattr(J, "format", "") != "csr":
        return J.tocsc()[:, order]
    import scipy.sparse as sp  # lazy: sparse systems only
    rank = inverse(order, J.indices.dtype)
    return sp.csr_matrix((J.data, rank[J.indices], J.indptr), shape=J.shape).tocsc()


def _clearly_regular(J):
    """The inverse of a small dense ``J`` when ``J`` is certainly far from the singularity
    threshold (``sigma_min / sigma_max > 1e-15``), else None: ``||J||_F ||J^-1||_F`` bounds the
    2-norm condition number from above, so a bound below 1e13 (100x margin over the inverse's
    own round-off) decides like the SVD would, at a fraction of its cost; otherwise the SVD
    decides. The inverse then serves the solves (a product each, refined against ``J``)."""
    with np.errstate(all="ignore"):
        try:
            # numpy's LAPACK inverse itself (np.linalg.inv's work without its wrapper, which
            # costs about a sixth of a 38x38 inverse): an exactly zero pivot gives NaNs here
            # (errors ignored), a LinAlgError through np.linalg.inv; None either way
            Ji = _inverse(J)
        except np.linalg.LinAlgError:
            return None
        k = norm(J) * norm(Ji)
    return Ji if k < 1e13 else None          # None for NaN/Inf (overflowing inverse)


class Factor:
    """Factorisation of a dense or CSR matrix; ``solve(b)``. Solvers factorise through
    :meth:`poise.solvers.data.SolveData.factor`, which counts.

    ``equilibrate=True`` factorises ``diag(r) J diag(c)`` (:func:`equilibration`) and maps the
    solution back: for badly scaled but regular systems (stiffnesses 1e21 apart)."""

    def __init__(self, J, equilibrate: bool = False):
        t0 = phases.now()
        self.scale = None
        try:
            if equilibrate:
                r, c = equilibration(J)
                if hasattr(J, "tocsr"):
                    import scipy.sparse as sp
                    order = getattr(J, "poise_column_order", None)
                    J = (sp.diags(r) @ J @ sp.diags(c)).tocsr()
                    if order is not None:
                        J.poise_column_order = order
                else:
                    J = np.asarray(J) * r[:, None] * c[None, :]
                self.scale = (r, c)
            self._factor(J)
        finally:
            phases.add("factorise", phases.now() - t0)

    def _factor(self, J):
        self.sparse = hasattr(J, "tocsc")
        self.order = None
        self.numpy = False
        if self.sparse:
            order = getattr(J, "poise_column_order", None)
            try:
                if order is not None:
                    # fill-reducing order computed once per pattern (model.assembly), the
                    # column-ordered CSC layout too when the matrix has the assembler's pattern
                    self.order = order()
                    lay = getattr(J, "poise_csc_layout", None)
                    lay = None if lay is None else lay()
                    A = (_layout_nonzeros(lay, J) if lay is not None and lay.fits(J)
                         else stored_nonzeros(_columns_ordered(J, self.order)))
                    self.lu = splu(A, permc_spec="NATURAL")
                    del A
                else:
                    A = stored_nonzeros(J.tocsc())
                    self.lu = splu(A, permc_spec="COLAMD")
                    del A
            except RuntimeError as e:
                raise SingularMatrix(str(e)) from None
            # SuperLU refuses an exactly zero pivot (RuntimeError above); the pivots of a finite
            # matrix are read only if a solve fails: ``lu.U`` copies both factors, kept as long
            # as the factorisation
            self._pivot_row = None
            data = J.data if getattr(J, "format", "") in ("csr", "csc", "coo") else J.tocsr().data
            if not np.all(np.isfinite(data)) and not np.all(np.isfinite(self.lu.U.diagonal())):
                raise SingularMatrix("singular matrix (zero pivot)", row=self.pivot_row)
        elif np.asarray(J).shape[0] <= NUMPY_DENSE_MAX:
            J = np.asarray(J)
            self.numpy = True
            self._pivot_row = None
            # an inverse it returns has a finite bound ||J|| ||J^-1||: J is finite then
            self.inverse = _clearly_regular(J)
            if self.inverse is None:
                if not all_finite(J):
                    raise SingularMatrix("matrix has non-finite entries")
                _u, sv, vh = np.linalg.svd(J)
                # the coordinate/equation most involved in the weakest direction: the culprit
                self._pivot_row = int(np.argmax(np.abs(vh[-1])))
                if sv[-1] <= 1e-15 * max(sv[0], 1e-300):
                    raise SingularMatrix("singular matrix (tiny singular value)",
                                         row=self._pivot_row)
        else:
            import scipy.linalg as sla
            J = np.asarray(J)
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                lu, piv = sla.lu_factor(J, check_finite=False)
            d = np.abs(np.diag(lu))
            self._pivot_row = int(np.argmin(d))
            if not np.all(np.isfinite(lu)) or d.min() <= 1e-15 * max(d.max(), 1e-300):
                raise SingularMatrix("singular matrix (tiny pivot)", row=self._pivot_row)
            self.lu = (lu, piv)
        self.J = J

    @property
    def pivot_row(self):
        """The row of the smallest pivot (the culprit a singular-matrix message names; small
        dense: the largest entry of the weakest right singular vector)."""
        if self._pivot_row is None and self.numpy:
            self._pivot_row = int(np.argmax(np.abs(np.linalg.svd(self.J)[2][-1])))
        elif self._pivot_row is None:
            u = np.abs(self.lu.U.diagonal())
            self._pivot_row = int(np.nonzero(self.lu.perm_r == int(np.argmin(u)))[0][0])
        return self._pivot_row

    def _solve(self, b):
        if self.sparse:
            y = self.lu.solve(b)
            if self.order is None:
                return y
            x = np.empty_like(y)
            x[self.order] = y
            return x
        if self.numpy:
            return self.inverse @ b if self.inverse is not None else np.linalg.solve(self.J, b)
        import scipy.linalg as sla
        return sla.lu_solve(self.lu, b, check_finite=False)

    def drop_matrix(self) -> None:
        """Forget the matrix (kept for the refinement's residuals; at 10^5 links 0.1 GB): later
        solves are plain ones, as accurate as the checked solves already made with these
        factors (their backward error is the factors', whatever the right-hand side). Not for
        numpy's small dense path, which solves with the matrix itself."""
        if not self.numpy:
            self.J = None

    @property
    def unchecked(self):
        """These factors' plain solves (``unchecked.solve(b)``, no refinement check): for a
        correction to a solution just checked with them, whose error counts relative to that
        solution, not to its own right-hand side (the neutral filter's ``S x``,
        :func:`~poise.solvers.steps.neutral_filtered`)."""
        return _Unchecked(self)

    def solve(self, b, refine: int = 2, rtol: float = 1e-8):
        """Solve with iterative refinement; raise SingularMatrix if the residual stays large
        (plain solves once :meth:`drop_matrix` was called)."""
        if self.scale is None:          # (no extra call on the common path)
            return self._solve_refined(b, refine, rtol)
        return self._scaled(self._solve_refined, b, refine, rtol)

    def _scaled(self, solve, b, *args):
        """``solve(b, *args)`` of the factorised (equilibrated) system, mapped to and from
        ``J``'s."""
        if self.scale is not None:
            r, c = self.scale
            return c * solve(r * np.asarray(b, float), *args)
        return solve(b, *args)

    def _solve_refined(self, b, refine, rtol):
        x = self._solve(b)
        if self.J is None:
            return x
        nb = norm(b)
        if nb == 0:
            return x
        for _ in range(refine + 1):
            if not all_finite(x):
                raise SingularMatrix("singular matrix (non-finite solution)", row=self.pivot_row)
            res = b - self.J @ x
            if norm(res) <= rtol * nb:
                return x
            x = x + self._solve(res)
        res = b - self.J @ x
        if not all_finite(x) or norm(res) > 1e-4 * nb:
            raise SingularMatrix("singular matrix (linear solve residual "
                                 f"{np.linalg.norm(res) / nb:.1e})", row=self.pivot_row)
        return x


class _Unchecked:
    """:attr:`Factor.unchecked`: ``solve(b)`` by the factors alone (scaled as they are)."""

    __slots__ = ("f",)

    def __init__(self, f):
        self.f = f

    def solve(self, b):
        return self.f._scaled(self.f._solve, b)
