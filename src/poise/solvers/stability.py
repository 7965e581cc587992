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
``K_red`` is Jacobi-equilibrated before the eigen-decomposition (a congruence, so the inertia is
unchanged): the zero threshold is then relative to each direction's own stiffness, and a stiff/soft
mix (1e9 next to 1 N/m) is not mistaken for a neutral system.

Dense eigen-decomposition is used up to ``DENSE_LIMIT`` coordinates; larger models report
``unknown`` (documented in docs/results-format.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DENSE_LIMIT = 3000
ZERO_REL = 1e-8
DIAG_FLOOR = 1e-24     # relative floor of the diagonal in the Jacobi equilibration


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
        N = _null_space(Pu, rcond=1e-10)
    else:
        N = np.eye(nq)
    if N.shape[1] == 0:
        return StabilityInfo("stable", 0, 0, "no degrees of freedom", np.inf)
    Kr = N.T @ Ku @ N
    Kr = 0.5 * (Kr + Kr.T)
    # Jacobi equilibration (a congruence: the inertia is unchanged, Sylvester): a stiff/soft mix
    # (a 1e9 N/m spring next to a 1 N/m one) is judged per direction, not against the stiffest
    dg = np.abs(np.diag(Kr))
    ref = max(float(dg.max()), float(np.max(np.abs(np.diag(Ku)))))
    fl = DIAG_FLOOR * ref if ref > 1e-280 else 1.0        # all-zero stiffness: no scaling
    sj = 1.0 / np.sqrt(np.maximum(dg, fl))
    w, V = np.linalg.eigh(Kr * sj[:, None] * sj[None, :])
    tol = ZERO_REL * max(float(np.max(np.abs(w))), 1.0)
    neg = w < -tol
    zero = np.abs(w) <= tol
    X = N @ (sj[:, None] * V)                 # eigenvectors in (length) coordinates
    X /= np.maximum(np.linalg.norm(X, axis=0), 1e-300)
    kmin = int(np.argmin(w))
    wmin = float(X[:, kmin] @ Ku @ X[:, kmin])   # Rayleigh quotient [force/length]
    modes = []
    for label, mask in (("unstable", neg), ("neutral", zero)):
        for k in np.nonzero(mask)[0][:6]:
            q = X[:, k] / d
            modes.append(f"{label}: {_describe(model, q)}")
        extra = int(mask.sum()) - 6
        if extra > 0:
            modes.append(f"{label}: ... {extra} more")
    klass = "unstable" if neg.any() else "neutral" if zero.any() else "stable"
    return StabilityInfo(klass, int(neg.sum()), int(zero.sum()), "; ".join(modes), wmin)


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


def _null_space(A, rcond=1e-10):
    """Orthonormal basis of the null space of ``A`` by SVD (as scipy.linalg.null_space)."""
    u, s, vh = np.linalg.svd(A, full_matrices=True)
    tol = rcond * (s.max() if s.size else 0.0)
    rank = int(np.sum(s > tol))
    return vh[rank:].T.conj()
