"""The inverse of a permutation by one scatter (``argsort`` would sort): the rank of every
index in a fill-reducing or renumbering order, as the factorisations, the assembler's column
layout and the equilibration read it."""
from __future__ import annotations

import numpy as np


def inverse(order, dtype=np.intp) -> np.ndarray:
    """``inv`` with ``inv[order[k]] = k`` (``order`` a permutation of ``0..n-1``)."""
    out = np.empty(len(order), dtype)
    out[order] = np.arange(len(order), dtype=dtype)
    return out
