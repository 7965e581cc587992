"""numpy's own arithmetic on small arrays without the Python argument handling of its
convenience functions, which costs more than the work itself on the few-element arrays of a
small model's solve: Euclidean norms (``np.linalg.norm``'s results, bit for bit, for real
arrays), the all-finite test, a gather along the last axis, and ``einsum`` and ``where``: numpy's
C functions that ``np.einsum`` (without ``optimize``) and ``np.where`` call after Python
wrappers costing more than their work on 3x3 blocks."""
from __future__ import annotations

import numpy as np

try:
    from numpy._core.multiarray import c_einsum as einsum
except ImportError:  # numpy < 2 (its C function elsewhere): the public one
    einsum = np.einsum

#: ``np.where(cond, x, y)``: numpy's C function without its ``__array_function__`` dispatch
#: (a Python call that costs as much as the selection of a few dozen entries)
where = getattr(np.where, "_implementation", np.where)


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
