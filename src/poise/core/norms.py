"""Euclidean norms of small arrays: ``np.linalg.norm``'s own arithmetic (its results, bit for
bit, for real arrays), without its argument handling, which costs more than the sum itself on
the few-element vectors of small models' solves."""
from __future__ import annotations

import numpy as np


def norm(x) -> np.floating:
    """``np.linalg.norm(x)`` of a real array (every entry: the Frobenius norm of a matrix)."""
    x = np.ravel(x)
    return np.sqrt(x.dot(x))


def row_norms(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """``np.linalg.norm(x, axis=axis)`` of a real array."""
    return np.sqrt(np.add.reduce(x * x, axis=axis))
