"""Kernel outputs of big families, made in chunks of instances.

Every kernel of :mod:`poise.elements.kernel` works instance by instance (no sum across
instances), so a family's local residual, compact tangent and constraint Jacobian can be made
for a range of instances at a time with the same operations on the same values: bit for bit
the whole family's. Above ``2 * CHUNK`` instances (a family with no kept
:class:`~poise.elements.slot_index.SlotIndex`) the temporaries of a chunk stay in the cache and
below malloc's mmap threshold, instead of being fresh pages the kernel zeroes at every
evaluation (at 10^5 chain links ~2 GB per solve). Chunks are balanced (at least ``CHUNK / 2``
instances), so a chunk takes the same code paths as its whole family (the small-array
branches of the kernels are for fewer entries).
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError
from poise.core.lean import all_finite
from poise.elements.kernel import (PairBlocks, SlotKinematics, constraint_jacobian_local,
                                   local_residual, tangent_compact)
from poise.elements.major import MAJOR_MIN, constraint_jacobian_major

CHUNK = 1 << 14


def spans(kin: SlotKinematics) -> list | None:
    """``(first, end)`` instance ranges of a big family's kinematics, or None (one piece)."""
    n = kin.pt.shape[0]
    if kin.index is not None or n <= 2 * CHUNK:
        return None
    k = -(-n // CHUNK)
    cuts = [n * i // k for i in range(k + 1)]
    return list(zip(cuts[:-1], cuts[1:]))


def rows(kin: SlotKinematics, a: int, b: int) -> SlotKinematics:
    """Instances ``a:b`` of ``kin`` (views; the family's slot masks, not the chunk's)."""
    return SlotKinematics(Y=kin.Y[a:b], V=kin.V[a:b], pt=kin.pt[a:b], slot_ml=kin.slot_ml,
                          K=kin.K, masks=kin.masks)


def g_rows(G, a: int, b: int):
    """Instances ``a:b`` of a constraint Hessian / force tangent ``G`` (dense, compact or None)."""
    if G is None:
        return None
    if isinstance(G, PairBlocks):
        return PairBlocks(b - a, G.S, {st: c[a:b] for st, c in G.coef.items()})
    return G[a:b]


def local_residuals(kin: SlotKinematics, rho: np.ndarray, K: int, parts: list, message):
    """``B^T rho`` of each chunk ``parts`` (from :func:`spans`), in instance order; a chunk
    with a non-finite value raises ``EvaluationError(message(its values, its first
    instance))``."""
    for a, b in parts:
        rl = local_residual(rows(kin, a, b), rho[a:b], K)
        if not all_finite(rl):
            raise EvaluationError(message(rl, a))
        yield rl


def tangent_values(kin: SlotKinematics, rho, G, K: int, pat, parts: list) -> np.ndarray:
    """:func:`~poise.elements.kernel.tangent_compact` of the whole family, chunk by chunk."""
    out = np.empty((9 * pat.nblocks, kin.pt.shape[0]))
    for a, b in parts:
        tangent_compact(rows(kin, a, b), rho[a:b], g_rows(G, a, b), K, pat, out=out[:, a:b])
    return out


def constraint_values(kin: SlotKinematics, phy, K: int, act, pidx, parts: list | None
                      ) -> np.ndarray:
    """The constraint Jacobian's registered values (n, P) of a family with no scalar columns
    (instance-major, as the model registers them: a scatter of neighbouring entries), made
    entry-major (:func:`~poise.elements.major.constraint_jacobian_major`) chunk by chunk
    (``parts`` from :func:`spans`, None: in one piece) and transposed: ``phi_y B``, rows
    multiplied by the active mask ``act`` (n, m) when a row is removed (``x * 1.0`` is ``x``:
    only then), entries ``pidx`` (None: all)."""
    n = kin.pt.shape[0]
    m = phy.shape[1]
    if np.logical_and.reduce(act, axis=None):
        act = None
    else:                                     # each entry's row of the instance
        rows_ = np.arange(m * 6 * K) // (6 * K)
        act = np.ascontiguousarray(act.T).take(rows_ if pidx is None else rows_[pidx], 0)
    out = None
    for a, b in [(0, n)] if parts is None else parts:
        Pq = _entry_major(rows(kin, a, b), phy[a:b], K, pidx)
        if act is not None:
            Pq = Pq * act[:, a:b]
        if out is None:
            out = np.empty((n, Pq.shape[0]))
        out[a:b] = Pq.T
    return out


def _entry_major(kin: SlotKinematics, phy, K: int, pidx) -> np.ndarray:
    """The entries ``pidx`` of ``phi_y B`` entry-major (P, n): component by component for many
    instances, else the instance-major kernel's values transposed (the same bits)."""
    n = kin.pt.shape[0]
    if kin.index is None and n >= MAJOR_MIN:
        return constraint_jacobian_major(kin, phy, K, pidx)
    Pq = constraint_jacobian_local(kin, phy, K).reshape(n, -1)
    return (Pq if pidx is None else Pq[:, pidx]).T
