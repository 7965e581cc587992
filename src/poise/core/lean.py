"""numpy's own arithmetic on small arrays without the Python argument handling of its
convenience functions, which costs more than the work itself on the few-element arrays of a
small model's solve: Euclidean norms (``np.linalg.norm``'s results, bit for bit, for real
arrays), the all-finite test, a gather along the last axis, ``einsum``, ``where`` and
``concatenate``: numpy's C functions that ``np.einsum`` (without ``optimize``), ``np.where`` and
``np.concatenate`` call after Python wrappers costing more than their work on 3x3 blocks; and
the LAPACK routines of ``np.linalg`` (``svd``, ``eigh``, ``eigvalsh``, ``cholesky``, ``solve``) of
one real matrix, its gufuncs called as it calls them (same routines, same results, same
errors) without its argument checks and conversions."""
from __future__ import annotations

import numpy as np

try:
    from numpy._core.multiarray import c_einsum as einsum
except ImportError:  # numpy < 2 (its C function elsewhere): the public one
    einsum = np.einsum

try:
    from numpy.linalg import _umath_linalg
    if not all(hasattr(_umath_linalg, f) for f in ("svd_f", "eigh_lo", "eigvalsh_lo", "solve",
                                                   "solve1", "cholesky_lo")):
        _umath_linalg = None
except ImportError:  # (numpy's layout changed: the public functions below)
    _umath_linalg = None

#: ``np.where(cond, x, y)``: numpy's C function without its ``__array_function__`` dispatch
#: (a Python call that costs as much as the selection of a few dozen entries)
where = getattr(np.where, "_implementation", np.where)
#: ``np.concatenate``: the same (a small model's evaluation joins a few dozen small arrays)
concatenate = getattr(np.concatenate, "_implementation", np.concatenate)


def norm(x) -> np.floating:
    """``np.linalg.norm(x)`` of a real array (every entry: the Frobenius norm of a matrix)."""
    x = x.ravel() if type(x) is np.ndarray else np.ravel(x)
    return np.sqrt(x.dot(x))


def row_norms(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """``np.linalg.norm(x, axis=axis)`` of a real array."""
    return np.sqrt(np.add.reduce(x * x, axis=axis))


def all_finite(x) -> bool:
    """``np.all(np.isfinite(x))`` (for a real array)."""
    return bool(np.logical_and.reduce(np.isfinite(x), axis=None))


def take_along_last(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``np.take_along_axis(a, idx, -1)`` (``a[..., idx[..., j]]`` per leading index)."""
    m, j = a.shape[-1], idx.shape[-1]
    flat = a.reshape(-1, m)
    rows = np.arange(flat.shape[0])[:, None]
    return flat[rows, idx.reshape(-1, j)].reshape(idx.shape)


def _no_eigenvalues(err, flag):
    raise np.linalg.LinAlgError("Eigenvalues did not converge")


def _no_svd(err, flag):
    raise np.linalg.LinAlgError("SVD did not converge")


def _singular(err, flag):
    raise np.linalg.LinAlgError("Singular matrix")


def _not_positive_definite(err, flag):
    raise np.linalg.LinAlgError("Matrix is not positive definite")


def _lapack(a) -> bool:
    """Whether ``a`` goes to the gufuncs directly: a real float64 matrix."""
    return _umath_linalg is not None and type(a) is np.ndarray and a.dtype == np.float64 \
        and a.ndim == 2


def svd(a):
    """``np.linalg.svd(a, full_matrices=True)`` of a real matrix: ``(u, s, vh)``."""
    if not _lapack(a):
        return np.linalg.svd(a, full_matrices=True)
    with np.errstate(call=_no_svd, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        return _umath_linalg.svd_f(a, signature="d->ddd")


def eigh(a):
    """``np.linalg.eigh(a)`` of a real symmetric matrix (its lower triangle): ``(w, v)``."""
    if not _lapack(a):
        return tuple(np.linalg.eigh(a))
    with np.errstate(call=_no_eigenvalues, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        return _umath_linalg.eigh_lo(a, signature="d->dd")


def eigvalsh(a):
    """``np.linalg.eigvalsh(a)`` of a real symmetric matrix (its lower triangle)."""
    if not _lapack(a):
        return np.linalg.eigvalsh(a)
    with np.errstate(call=_no_eigenvalues, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        return _umath_linalg.eigvalsh_lo(a, signature="d->d")


def solve(a, b):
    """``np.linalg.solve(a, b)`` of a real matrix and a real vector (or matrix of columns)."""
    if not (_lapack(a) and type(b) is np.ndarray and b.dtype == np.float64 and b.ndim <= 2):
        return np.linalg.solve(a, b)
    with np.errstate(call=_singular, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        if b.ndim == 1:
            return _umath_linalg.solve1(a, b, signature="dd->d")
        return _umath_linalg.solve(a, b, signature="dd->d")


def cholesky(a):
    """``np.linalg.cholesky(a)`` (lower) of a real symmetric matrix."""
    if not _lapack(a):
        return np.linalg.cholesky(a)
    with np.errstate(call=_not_positive_definite, invalid="call", over="ignore",
                     divide="ignore", under="ignore"):
        return _umath_linalg.cholesky_lo(a, signature="d->d")
