"""SuperLU options by system size: large systems are factorised column by column.

SuperLU factorises in *panels* of ``panel_size`` columns (scipy's default comes from SuperLU's
``sp_ienv``) and keeps work arrays of ``m x panel_size`` entries for them: at 1.1 M unknowns
(a 10⁵-link chain's KKT matrix) about 0.3 GB touched per factorisation. The KKT matrices of
poise's models have narrow supernodes, where panels buy nothing: with ``panel_size=1`` the
factors are the same size and the factorisation is faster (0.79 -> 0.52 s at 10⁵ links,
0.071 -> 0.032 s at 10⁴) with a third of the transient memory. The pivots and fill are the
same, but the updates are summed in another order (round-off differs), so small systems keep
SuperLU's default and their results stay bitwise those of before. :func:`splu` is the one
call of SuperLU's factorisation for the solvers' systems (Newton's, the stability LDL^T's):
with these options, and in a large solve's kept heap on fresh mapped storage.
"""
from __future__ import annotations

from poise.core import memory

#: Systems with at least this many unknowns are factorised column by column.
COLUMNWISE_MIN = 50_000


def lean(n: int) -> dict:
    """Keyword arguments for ``scipy.sparse.linalg.splu`` of an ``n x n`` system."""
    return {"panel_size": 1} if n >= COLUMNWISE_MIN else {}


def splu(A, **options):
    """``scipy.sparse.linalg.splu(A, **options)`` of the CSC ``A``, with :func:`lean`'s options
    for its size unless ``options`` name them, inside :func:`poise.core.memory.mapped` (in a
    large solve the factors get fresh storage, not the kept heap's)."""
    import scipy.sparse.linalg as spla  # lazy: sparse systems only
    with memory.mapped(A.shape[0]):
        return spla.splu(A, **{**lean(A.shape[0]), **options})
