"""Stability classification of a converged equilibrium.

The tangent stiffness ``K`` (coordinate block of the Newton Jacobian, with the converged
multipliers, *without* the ``stability`` regularisation) is reduced to the constraint manifold:
``K_red = N^T K_s N`` where the columns of ``N`` span the null space of the active constraint
Jacobian. Coordinates are first scaled to lengths (rotations by each body's length scale) so
that the eigenvalues have units of force/length and the zero threshold is relative to the
stiffest direction. ``K_s`` is the symmetric part of the scaled K (for conservative models K is
symmetric at equilibrium; for non-conservative loads the symmetric part gives the energy
criterion — documented limitation).

The inertia of ``K_red`` (counts of negative, zero and positive eigenvalues) classifies the frame:
any negative eigenvalue -> ``unstable``; else any zero eigenvalue -> ``neutral``; else ``stable``.
Modes of negative and zero eigenvalues are described by the body with the largest participation.

Dense eigen-decomposition is used up to ``DENSE_LIMIT`` coordinates; larger models report
``unknown`` (documented in docs/results-format.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

DENSE_LIMIT = 3000
ZERO_REL = 1e-8


@dataclass
class StabilityInfo:
    klass: str                 # stable | neutral | unstable | unknown
    n_negative: int
    n_zero: int
    modes: str                 # human-readable description of negative and zero modes
    min_eigenvalue: float      # smallest eigenvalue of the reduced stiffness [force/length]


def classify(model, state, J=None) -> StabilityInfo:
    """Classify the equilibrium ``state`` of ``model`` (uses ``model.row_active``).

    ``J`` may be a KKT Jacobian already evaluated at ``state`` without regularisation (any
    state of ``row_active``: inactive rows are dropped here).
    """
    nq = model.nq
    if nq == 0:
        return StabilityInfo("stable", 0, 0, "", np.nan)
    if nq > DENSE_LIMIT:
        return StabilityInfo("unknown", -1, -1, f"not classified: {nq} coordinates > {DENSE_LIMIT}",
                             np.nan)
    if J is None:
        J = model.evaluate(state, need_jac=True, eps_mass=0.0).J
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    K = J[:nq, :nq]
    act = model.row_active
    Pq = J[nq:, :nq][act]
    d = model.q_scale                       # length per coordinate unit
    Ku = K / d[:, None] / d[None, :]
    Ku = 0.5 * (Ku + Ku.T)
    if Pq.shape[0]:
        Pu = Pq / d[None, :]
        N = sla.null_space(Pu, rcond=1e-10)
    else:
        N = np.eye(nq)
    if N.shape[1] == 0:
        return StabilityInfo("stable", 0, 0, "no degrees of freedom", np.inf)
    Kr = N.T @ Ku @ N
    w, V = np.linalg.eigh(0.5 * (Kr + Kr.T))
    scale = max(float(np.max(np.abs(w))), float(np.max(np.abs(np.diag(Ku)))), 1e-300)
    tol = ZERO_REL * scale
    neg = w < -tol
    zero = np.abs(w) <= tol
    modes = []
    for label, mask in (("unstable", neg), ("neutral", zero)):
        for k in np.nonzero(mask)[0][:6]:
            q = (N @ V[:, k]) / d
            modes.append(f"{label}: {_describe(model, q)}")
        extra = int(mask.sum()) - 6
        if extra > 0:
            modes.append(f"{label}: ... {extra} more")
    klass = "unstable" if neg.any() else "neutral" if zero.any() else "stable"
    return StabilityInfo(klass, int(neg.sum()), int(zero.sum()), "; ".join(modes), float(w.min()))


def _describe(model, q):
    """Body with the largest participation in mode ``q`` and its dominant motion."""
    part = []
    for b in range(model.nb):
        o = model.body_off[b]
        t = q[o:o + 3]
        r = q[o + 3:o + 6] * model.body_scale[b] if model.body_kind[b] == 0 else np.zeros(3)
        part.append(np.linalg.norm(t) ** 2 + np.linalg.norm(r) ** 2)
    b = int(np.argmax(part))
    o = model.body_off[b]
    t = q[o:o + 3]
    r = q[o + 3:o + 6] * model.body_scale[b] if model.body_kind[b] == 0 else np.zeros(3)
    bid = int(model.body_id[b])
    if np.linalg.norm(r) >= np.linalg.norm(t):
        a = r / np.linalg.norm(r)
        return f"body {bid} rotation about ({a[0]:.2f},{a[1]:.2f},{a[2]:.2f})"
    a = t / np.linalg.norm(t)
    return f"body {bid} translation along ({a[0]:.2f},{a[1]:.2f},{a[2]:.2f})"


def stability_datasets(infos: list[StabilityInfo]) -> dict:
    """Per-frame datasets ``frames/stability``, ``frames/n_negative``, ``frames/n_zero``,
    ``frames/stability_modes``, ``frames/min_stiffness_eigenvalue``."""
    return {
        "frames/stability": np.array([i.klass for i in infos], dtype=str),
        "frames/n_negative": np.array([i.n_negative for i in infos], dtype=np.int64),
        "frames/n_zero": np.array([i.n_zero for i in infos], dtype=np.int64),
        "frames/stability_modes": np.array([i.modes for i in infos], dtype=str),
        "frames/min_stiffness_eigenvalue": np.array([i.min_eigenvalue for i in infos]),
    }
