"""numpy's own arithmetic on small arrays without the Python argument handling of its
convenience functions, which costs more than the work itself on the few-element arrays of a
small model's solve: Euclidean norms (``np.linalg.norm``'s results, bit for bit, for real
arrays) and the all-finite test."""
from __future__ import annotations

import numpy as np


def norm(x) -> np.floating:
    """``np.linalg.norm(x)`` of a real array (every entry: the Frobenius norm of a matrix)."""
    x = np.ravel(x)
    return np.sqrt(x.dot(x))


def row_norms(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """``np.linalg.norm(x, axis=axis)`` of a real array."""
    return np.sqrt(np.add.reduce(x * x, axis=axis))


def all_finite(x) -> bool:
    """``np.all(np.isfinite(x))`` (for a real array)."""
    return bool(np.logical_and.reduce(np.isfinite(x), axis=None))
