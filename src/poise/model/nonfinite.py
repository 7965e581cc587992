"""Messages for a non-finite evaluation: they name the deck element whose kernel produced the
NaN/Inf, or the equation / coordinate that is not finite."""
from __future__ import annotations

import numpy as np

from poise.elements.context import row_where


def family_nonfinite(fam, rl, first: int = 0) -> str:
    """Message naming the deck element whose kernel produced NaN/Inf (``rl``: the local
    residuals of the instances from ``first`` on)."""
    k = first + int(np.nonzero(~np.isfinite(rl).all(axis=1))[0][0])
    locs = fam.element_locs
    if locs:
        return f"{locs[k].prefix()} produced a non-finite force (NaN/Inf)"
    return f"element family {fam.name} (instance {k}) produced a non-finite value (NaN/Inf)"


def nonfinite_message(model, r, phi):
    bad = np.nonzero(~np.isfinite(phi))[0]
    if len(bad):
        ri = model.row_info[bad[0]]
        return f"{row_where(ri)}: equation {ri['equation']} is not finite (NaN/Inf)"
    bad = np.nonzero(~np.isfinite(r))[0]
    ci = model.coord_info[bad[0]]
    return f"non-finite force on {ci} (NaN/Inf produced by an element acting on it)"
