"""``Reference_Matrix`` data: the values of a full or sparse matrix given as element text.

MotionSolve's two inline forms (Adams ``MATRIX``): **full** ``nrow x ncol`` values in column
order (the default) or row order (``isroworder="TRUE"``, Adams ``FULL=RORDER``), and **sparse**
(``issparse="TRUE"``) ``nval`` triples ``row col value`` with 1-based indices, entries not listed
being zero. Numbers are separated by blanks and/or commas; Fortran ``D`` exponents are read.
:func:`matrix_values` checks the shape, counts and indices (every problem located) and returns
the dense array; validation runs it on every matrix of a deck, used or not.
"""
from __future__ import annotations

import re

import numpy as np

from poise.core.errors import ProblemCollector
from poise.deck.spec import Element

_SPLIT = re.compile(r"[\s,;]+")
#: largest number of entries of a dense matrix (8 MB of float64): larger data is not a deck
MAX_ENTRIES = 1_000_000


def _numbers(text, el, pc):
    toks = [t for t in _SPLIT.split((text or "").strip()) if t]
    try:
        return np.array([float(t.replace("D", "E").replace("d", "e")) for t in toks], float)
    except ValueError as e:
        pc.error(el.loc, f"Reference_Matrix text is not a list of numbers ({e})")
        return None


def matrix_values(el: Element, pc: ProblemCollector) -> np.ndarray | None:
    """The dense ``(nrow, ncol)`` values of a ``Reference_Matrix`` (None after a located problem
    added to ``pc``)."""
    a = el.attrs
    if any(a.get(k) for k in ("usrsub_dll_name", "script_name", "usrsub_fnc_name",
                              "usrsub_param_string")):
        pc.error(el.loc, "user-subroutine matrices are not supported; expected the values as "
                 "element text (full or sparse form)")
        return None
    nr, nc = a.get("nrow"), a.get("ncol")
    if not isinstance(nr, int) or not isinstance(nc, int) or nr < 1 or nc < 1:
        pc.error(el.loc, f"Reference_Matrix needs nrow >= 1 and ncol >= 1; got nrow={nr}, "
                 f"ncol={nc}")
        return None
    if nr * nc > MAX_ENTRIES:
        pc.error(el.loc, f"Reference_Matrix of {nr} x {nc} entries; expected at most "
                 f"{MAX_ENTRIES} entries")
        return None
    v = _numbers(el.text, el, pc)
    if v is None:
        return None
    if not np.isfinite(v).all():
        pc.error(el.loc, "Reference_Matrix text holds a value that is not a finite number")
        return None
    if not a.get("issparse"):
        if len(v) != nr * nc:
            pc.error(el.loc, f"Reference_Matrix text has {len(v)} values; expected nrow x ncol "
                     f"= {nr * nc}")
            return None
        return (v.reshape(nr, nc) if a.get("isroworder") else v.reshape(nc, nr).T).copy()
    nval = a.get("nval")
    if len(v) % 3:
        pc.error(el.loc, f"sparse Reference_Matrix text has {len(v)} numbers; expected "
                 "row col value triples")
        return None
    t = v.reshape(-1, 3)
    if nval is not None and nval != len(t):
        pc.error(el.loc, f"nval={nval} but the text has {len(t)} row col value triples", "nval")
        return None
    ij = t[:, :2]
    if (ij != np.trunc(ij)).any():
        pc.error(el.loc, "sparse Reference_Matrix row and column indices must be integers")
        return None
    i, j = ij[:, 0].astype(np.int64), ij[:, 1].astype(np.int64)
    bad = (i < 1) | (i > nr) | (j < 1) | (j > nc)
    if bad.any():
        k = int(np.argmax(bad))
        pc.error(el.loc, f"sparse entry {k + 1} at ({i[k]}, {j[k]}) is outside the "
                 f"{nr} x {nc} matrix (indices start at 1)")
        return None
    key = (i - 1) * nc + (j - 1)
    uniq, first = np.unique(key, return_index=True)
    if len(uniq) != len(key):
        dup = np.setdiff1d(np.arange(len(key)), first)[0]
        pc.error(el.loc, f"sparse entry {dup + 1} repeats ({i[dup]}, {j[dup]}); expected each "
                 "entry once")
        return None
    out = np.zeros((nr, nc))
    out[i - 1, j - 1] = t[:, 2]
    return out
