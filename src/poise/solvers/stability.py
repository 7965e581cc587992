"""Stability classification of a converged equilibrium (stable, neutral, unstable).

The tangent stiffness (coordinate block of the Newton Jacobian, without the ``stability``
regularisation), length-scaled, symmetrised and reduced to the constraint manifold, is
classified by its inertia: any negative eigenvalue -> ``unstable``, else any zero -> ``neutral``,
else ``stable``. Dense eigen-decomposition up to ``DENSE_LIMIT`` coordinates (here), spectrum
slicing with sparse factorisations beyond (:mod:`poise.solvers.stability_sparse`); the result
types and mode descriptions live in :mod:`poise.solvers.stability_modes`. Method and
limitations: docs/stability.md.
"""
from __future__ import annotations

import numpy as np

from poise.solvers.stability_modes import (  # noqa: F401 - re-exported: the public names
    AUG_RHO,
    DENSE_LIMIT,
    DIAG_FLOOR,
    N_MODES,
    SIGN_TIE,
    ZERO_REL,
    Mode,
    StabilityInfo,
    _describe,
    _info,
    _unknown,
    sign_normalised,
    stability_datasets,
    unknown_info,
)
from poise.solvers.stability_sparse import (  # noqa: F401 - re-exported
    SymmetricLDL,
    _classify_pencil,
    _classify_sparse,
    _SparsePencil,
)


def classify(model, state, J=None, active=None) -> StabilityInfo:
    """Classify the equilibrium ``state`` of ``model``; ``active``: the solve's active
    constraint rows (None: all).

    ``J`` may be a KKT Jacobian already evaluated at ``state`` without regularisation (with
    any active rows: inactive rows are dropped here).
    """
    nq = model.nq
    if nq == 0:
        return StabilityInfo("stable", 0, 0, "", np.nan)
    if J is None:
        J = model.evaluate(state, need_jac=True, eps_mass=0.0, active=active).J
    if active is None:
        active = np.ones(model.nc, bool)
    if nq > DENSE_LIMIT:
        return _classify_sparse(model, J, active)
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    return classify_dense_frames(model, J[None], active)[0]


def classify_dense_frames(model, J, active, ok=None) -> list[StabilityInfo]:
    """Dense classification of ``F`` frames from their KKT Jacobians ``J`` (F, N, N) (dense).

    Per frame: the length-scaled symmetric stiffness reduced to the SVD null space of the
    ``active`` constraint rows, Jacobi-equilibrated, ``eigh`` with the ``ZERO_REL`` threshold
    (module docstring). Frames are processed with stacked SVDs and eigen-decompositions; frames
    of equal constraint rank share one call. Frames with ``ok[k]`` False are ``unknown``.
    """
    F = J.shape[0]
    nq = model.nq
    unknown = StabilityInfo("unknown", -1, -1, "", np.nan)
    ok = np.ones(F, bool) if ok is None else np.asarray(ok, bool)
    if nq == 0:
        return [StabilityInfo("stable", 0, 0, "", np.nan) if k else unknown for k in ok]
    out = [unknown] * F
    sel = np.nonzero(ok)[0]
    if not len(sel):
        return out
    d = model.q_scale                       # length per coordinate unit
    Ku = J[sel, :nq, :nq] / d[:, None] / d[None, :]
    Ku = 0.5 * (Ku + np.swapaxes(Ku, 1, 2))
    Pq = J[sel, nq:, :nq][:, active]
    Fo = len(sel)
    if Pq.shape[1]:
        _, s, vh = np.linalg.svd(Pq / d[None, None, :], full_matrices=True)
        tol = 1e-10 * (s.max(axis=1) if s.shape[1] else np.zeros(Fo))
        rank = np.sum(s > tol[:, None], axis=1)
    else:
        vh = np.broadcast_to(np.eye(nq), (Fo, nq, nq))
        rank = np.zeros(Fo, int)
    for rk in sorted(set(rank.tolist())):        # (np.unique imports numpy.ma: ~15 ms)
        grp = np.nonzero(rank == rk)[0]
        Nb = np.swapaxes(vh[grp, rk:, :], 1, 2)                      # (g, nq, k) null spaces
        if Nb.shape[2] == 0:
            for i in grp:
                out[sel[i]] = StabilityInfo("stable", 0, 0, "no degrees of freedom", np.inf)
            continue
        Kg = Ku[grp]
        Kr = np.matmul(np.swapaxes(Nb, 1, 2), np.matmul(Kg, Nb))
        Kr = 0.5 * (Kr + np.swapaxes(Kr, 1, 2))
        # Jacobi equilibration (a congruence: the inertia is unchanged, Sylvester): a stiff/soft
        # mix (a 1e9 N/m spring next to a 1 N/m one) is judged per direction, not against the
        # stiffest
        dg = np.abs(np.diagonal(Kr, axis1=1, axis2=2))
        ref = np.maximum(dg.max(axis=1), np.abs(np.diagonal(Kg, axis1=1, axis2=2)).max(axis=1))
        fl = np.where(ref > 1e-280, DIAG_FLOOR * ref, 1.0)          # all-zero: no scaling
        sj = 1.0 / np.sqrt(np.maximum(dg, fl[:, None]))
        w, V = np.linalg.eigh(Kr * sj[:, :, None] * sj[:, None, :])
        ztol = ZERO_REL * np.maximum(np.abs(w).max(axis=1), 1.0)
        neg = w < -ztol[:, None]
        zero = np.abs(w) <= ztol[:, None]
        X = np.matmul(Nb, sj[:, :, None] * V)        # eigenvectors in (length) coordinates
        X /= np.maximum(np.linalg.norm(X, axis=1), 1e-300)[:, None, :]
        kmin = np.argmin(w, axis=1)
        xk = X[np.arange(len(grp)), :, kmin]
        wmin = np.einsum("gi,gij,gj->g", xk, Kg, xk)                 # Rayleigh [force/length]
        for j, i in enumerate(grp):
            found = []
            for mask in (neg[j], zero[j]):
                ks = np.nonzero(mask)[0][:N_MODES]
                xs = X[j][:, ks]                                     # unit, length coordinates
                wk = np.einsum("ik,ij,jk->k", xs, Kg[j], xs)        # Rayleigh [force/length]
                found.append([(xs[:, c] / d, float(wk[c])) for c in range(len(ks))])
            klass = "unstable" if neg[j].any() else "neutral" if zero[j].any() else "stable"
            out[sel[i]] = _info(model, klass, int(neg[j].sum()), int(zero[j].sum()),
                                found[0], found[1], wmin[j])
    return out

