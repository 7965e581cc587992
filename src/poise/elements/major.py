"""Slot kernels of many instances made component by component: the slot vectors transposed to
``(S, 3, n)``, every operation a vector over all instances (numpy's 3-wide inner loops of the
instance-major layout cost several times more per value). Used from ``MAJOR_MIN`` instances
(below, the transposes cost more than they save); the operations and their order are those of
:mod:`poise.elements.kernel` (``v x w`` component by component as ``cross3`` forms it, each
marker's slot terms added in slot order onto zeros), so the values are its bits."""
from __future__ import annotations

import numpy as np

MAJOR_MIN = 512            # instances from which a family's kernels run component-major


def constraint_jacobian_major(kin, phi_y: np.ndarray, K: int,
                              pidx=None) -> np.ndarray:
    """The entries ``pidx`` (None: all) of
    :func:`~poise.elements.kernel.constraint_jacobian_local`'s flattened ``(m, 6K)`` rows,
    entry-major ``(P, n)`` (the order the model registers them in): the same values, bit for
    bit."""
    n, S = kin.pt.shape
    m = phi_y.shape[1]
    V = np.ascontiguousarray(kin.V.transpose(1, 2, 0))                  # (S, 3, n)
    py = np.ascontiguousarray(phi_y.reshape(n, m, S, 3).transpose(1, 2, 3, 0))  # (m, S, 3, n)
    out = np.zeros((m, 2 * K, 3, n))
    p_all, p_any = kin.masks
    pt = kin.pt
    ml = kin.slot_ml
    for s in range(S):
        k = ml[s]
        v, p = V[s], py[:, s]                                         # (3, n), (m, 3, n)
        rot = out[:, 2 * k + 1]
        # (v x p) component by component, as cross3 forms it
        rot[:, 0] += v[1] * p[:, 2] - v[2] * p[:, 1]
        rot[:, 1] += v[2] * p[:, 0] - v[0] * p[:, 2]
        rot[:, 2] += v[0] * p[:, 1] - v[1] * p[:, 0]
        if p_all[s]:
            out[:, 2 * k] += p
        elif p_any[s]:
            out[:, 2 * k] += p * pt[:, s]
    out = out.reshape(m * 6 * K, n)
    return out if pidx is None else out.take(pidx, 0)


def local_residual_major(kin, rho: np.ndarray, K: int) -> np.ndarray:
    """:func:`~poise.elements.kernel.local_residual` (n, 6K) of a family without a
    :class:`~poise.elements.slot_index.SlotIndex`: ``B^T rho`` is
    :func:`constraint_jacobian_major` of one row ``rho`` (the same operations on the same
    values, so the same bits)."""
    n = kin.pt.shape[0]
    return np.ascontiguousarray(constraint_jacobian_major(kin, rho.reshape(n, 1, -1), K).T)
