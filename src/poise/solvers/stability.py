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

from dataclasses import replace

import numpy as np

from poise.core import lean, memory
from poise.core.lean import einsum, row_norms
from poise.solvers.equilibrate import equilibrate_dense, prune_noise_dense, prune_rows_dense
from poise.solvers.stability_modes import (  # noqa: F401 - re-exported: the public names
    AUG_RHO,
    DENSE_LIMIT,
    DIAG_FLOOR,
    N_MODES,
    SIGN_TIE,
    ZERO_REL,
    Mode,
    StabilityInfo,
    canonical_basis,
    classified_info,
    describe_mode,
    not_classified,
    sign_normalised,
    unknown_info,
)
from poise.solvers.stability_scalars import eliminate_dense, eliminate_sparse
from poise.solvers.stability_sparse import (  # noqa: F401 - re-exported
    SparsePencil,
    SymmetricLDL,
    classify_pencil,
    classify_sparse,
)


def classify(model, state, J=None, active=None, kkt_columns=None) -> StabilityInfo:
    """Classify the equilibrium ``state`` of ``model``; ``active``: the solve's active
    constraint rows (None: all); ``kkt_columns``: the solve's column order of the KKT matrix
    if it has one (a large model's elimination order then ranks the bodies as it does).

    ``J`` may be a KKT Jacobian already evaluated at ``state`` without regularisation (with
    any active rows: inactive rows are dropped here), or handed over
    (:func:`poise.core.memory.hand_over`): then a large model's goes once it is read.
    """
    nq = model.nq
    if nq == 0:
        return StabilityInfo("stable", 0, 0, "", np.nan)
    if J is None:
        J = memory.hand_over(model.evaluate(state, need_jac=True, eps_mass=0.0, active=active).J)
    if active is None:
        active = np.ones(model.nc, bool)
    if nq > DENSE_LIMIT:
        if model.n_extra:
            J = memory.taken(J)
            red = eliminate_sparse(model, J)
            if red is not None:
                view, Jr, lift = red
                return _lifted(classify_sparse(view, Jr, active), lift)
            J = memory.hand_over(J)
        return classify_sparse(model, J, active, kkt_columns)
    J = memory.taken(J)
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    return classify_dense_frames(model, J[None], active)[0]


def _lifted(info, lift):
    """``info`` of the mechanism with its mode vectors completed by the scalar unknowns."""
    return replace(info, vectors=tuple(lift(v) for v in info.vectors))


def classify_dense_frames(model, J, active, ok=None) -> list[StabilityInfo]:
    """Dense classification of ``F`` frames from their KKT Jacobians ``J`` (F, N, N) (dense);
    scalar unknowns are eliminated first where their equations determine them
    (:mod:`poise.solvers.stability_scalars`), frame by frame."""
    ok = np.ones(J.shape[0], bool) if ok is None else np.asarray(ok, bool)
    red = eliminate_dense(model, J) if model.n_extra else None
    if red is None:
        return _dense_frames(model, J, active, ok)
    view, Jr, good, lift = red
    out = _dense_frames(view, Jr, active, ok & good)
    rest = _dense_frames(model, J, active, ok & ~good) if (ok & ~good).any() else out
    return [_lifted(out[f], lambda x, f=f: lift(f, x)) if ok[f] and good[f] else rest[f]
            for f in range(J.shape[0])]


def _dense_frames(model, J, active, ok) -> list[StabilityInfo]:
    """Dense classification of ``F`` frames from their KKT Jacobians ``J`` (F, N, N) (dense).

    Per frame, the sparse path's metric (docs/stability.md): the length-scaled symmetric
    stiffness ``K_s`` and the ``active`` constraint rows ``G`` (numerically empty rows
    dropped), equilibrated together (:func:`~poise.solvers.equilibrate.equilibrate_dense`:
    ``Kt``, ``Gt``), ``Kt`` reduced to the SVD null space of ``Gt``, ``eigh``, and ``|w| <=
    ZERO_REL max(rho(Kt), 1)`` is zero. The equilibration never scales a coordinate past its
    round-off-aware cap, so an exactly zero direction is zero whatever the sign of its rounding
    errors. Frames are processed with stacked decompositions; frames of equal constraint rank
    share one call. Frames with ``ok[k]`` False are ``unknown``.
    """
    F = J.shape[0]
    nq = model.nq
    unknown = StabilityInfo("unknown", -1, -1, "", np.nan)
    if nq == 0:
        return [StabilityInfo("stable", 0, 0, "", np.nan) if k else unknown for k in ok]
    if F == 1 and ok[0]:
        return [_dense_one(model, J[0], active)]
    out = [unknown] * F
    sel = np.nonzero(ok)[0]
    if not len(sel):
        return out
    d = model.q_scale                       # length per coordinate unit
    Ku = J[sel, :nq, :nq] / d[:, None] / d[None, :]
    Ku = 0.5 * (Ku + np.swapaxes(Ku, 1, 2))
    G = J[sel, nq:, :nq][:, active] / d[None, None, :]
    if G.shape[1]:        # a numerically empty row constrains nothing (as on the sparse path)
        rn = np.linalg.norm(G, axis=2)
        G = np.where((rn > 1e-10 * rn.max(axis=1, keepdims=True))[:, :, None], G, 0.0)
        G = prune_rows_dense(G)     # entries at round-off of their row (as the sparse path)
    Ks = prune_noise_dense(Ku)
    Dq, Dl = equilibrate_dense(Ks, G)
    Kt = Ks * Dq[:, :, None] * Dq[:, None, :]
    Fo = len(sel)
    if G.shape[1]:
        _, s, vh = np.linalg.svd(G * Dl[:, :, None] * Dq[:, None, :], full_matrices=True)
        tol = 1e-10 * (s.max(axis=1) if s.shape[1] else np.zeros(Fo))
        rank = np.sum(s > tol[:, None], axis=1)
    else:
        vh = np.broadcast_to(np.eye(nq), (Fo, nq, nq))
        rank = np.zeros(Fo, int)
    # zero threshold: ZERO_REL of the spectral radius of Kt (as the sparse path), at least
    # ZERO_REL (Kt's rows have unit-size entries after equilibration)
    eps = ZERO_REL * np.maximum(np.abs(np.linalg.eigvalsh(Kt)).max(axis=1), 1.0)
    for rk in sorted(set(rank.tolist())):        # (np.unique imports numpy.ma: ~15 ms)
        grp = np.nonzero(rank == rk)[0]
        Z = np.swapaxes(vh[grp, rk:, :], 1, 2)                       # (g, nq, k) null spaces
        if Z.shape[2] == 0:
            for i in grp:
                out[sel[i]] = StabilityInfo("stable", 0, 0, "no degrees of freedom", np.inf)
            continue
        Kg = Ku[grp]
        Kr = np.matmul(np.swapaxes(Z, 1, 2), np.matmul(Kt[grp], Z))
        w, V = np.linalg.eigh(0.5 * (Kr + np.swapaxes(Kr, 1, 2)))
        ztol = eps[grp]
        neg = w < -ztol[:, None]
        zero = np.abs(w) <= ztol[:, None]
        X = Dq[grp][:, :, None] * np.matmul(Z, V)    # eigenvectors in (length) coordinates
        X /= np.maximum(np.linalg.norm(X, axis=1), 1e-300)[:, None, :]
        kmin = np.argmin(w, axis=1)
        xk = X[np.arange(len(grp)), :, kmin]
        wmin = einsum("gi,gij,gj->g", xk, Kg, xk)                 # Rayleigh [force/length]
        for j, i in enumerate(grp):
            found = described_modes(X[j], Kg[j], neg[j], zero[j], d)
            klass = "unstable" if neg[j].any() else "neutral" if zero[j].any() else "stable"
            out[sel[i]] = classified_info(model, klass, int(neg[j].sum()), int(zero[j].sum()),
                                found[0], found[1], wmin[j])
    return out


def described_modes(X, K, neg, zero, d) -> list[list]:
    """``[unstable, neutral]``: up to N_MODES ``(q, w)`` each (``q`` in model coordinates, ``w``
    the Rayleigh quotient of ``K`` [force/length]) from the unit eigenvectors ``X`` (length
    coordinates) selected by the masks ``neg`` / ``zero``; ``d`` the length per coordinate unit.
    The zero eigenvalues are one eigenvalue: their modes come from the eigenbasis-independent
    :func:`~poise.solvers.stability_modes.canonical_basis` of their space."""
    found = []
    for mask, neutral in ((neg, False), (zero, True)):
        xs = X[:, np.nonzero(mask)[0]]                               # unit, length coordinates
        if neutral and xs.shape[1] > 1:
            xs = canonical_basis(xs)
        xs = xs[:, :N_MODES]
        wk = einsum("ik,ij,jk->k", xs, K, xs)                    # Rayleigh [force/length]
        found.append([(xs[:, c] / d, float(wk[c])) for c in range(xs.shape[1])])
    return found


def _dense_one(model, J, active) -> StabilityInfo:
    """:func:`_dense_frames` of one frame (a static solve's): the same operations on the
    frame's 2-d arrays, without the stacking (the same numbers)."""
    nq = model.nq
    d = model.q_scale
    Ku = J[:nq, :nq] / d[:, None] / d[None, :]
    Ku = 0.5 * (Ku + Ku.T)
    G = J[nq:, :nq][active] / d[None, :]
    if G.shape[0]:
        rn = row_norms(G)
        G = np.where((rn > 1e-10 * np.maximum.reduce(rn))[:, None], G, 0.0)
        G = prune_rows_dense(G[None])[0]
    Ks = prune_noise_dense(Ku[None])
    Dq, Dl = equilibrate_dense(Ks, G[None])
    Ks, Dq, Dl = Ks[0], Dq[0], Dl[0]
    Kt = Ks * Dq[:, None] * Dq[None, :]
    if G.shape[0]:
        _, s, vh = lean.svd(G * Dl[:, None] * Dq[None, :])
        tol = 1e-10 * (np.maximum.reduce(s) if s.size else 0.0)
        rank = int(np.add.reduce(s > tol))
    else:
        vh = np.eye(nq)
        rank = 0
    eps = ZERO_REL * max(float(np.maximum.reduce(np.abs(lean.eigvalsh(Kt)))), 1.0)
    Z = vh[rank:, :].T                                               # (nq, k) null space
    if Z.shape[1] == 0:
        return StabilityInfo("stable", 0, 0, "no degrees of freedom", np.inf)
    Kr = Z.T @ (Kt @ Z)
    w, V = lean.eigh(0.5 * (Kr + Kr.T))
    neg = w < -eps
    zero = np.abs(w) <= eps
    X = Dq[:, None] * (Z @ V)                   # eigenvectors in (length) coordinates
    X /= np.maximum(row_norms(X, axis=0), 1e-300)[None, :]
    xk = X[:, int(np.argmin(w))].copy()
    wmin = float(einsum("gi,gij,gj->g", xk[None], Ku[None], xk[None])[0])   # [force/length]
    n_neg, n_zero = int(np.add.reduce(neg)), int(np.add.reduce(zero))
    # (a stable frame has no mode to describe)
    found = described_modes(X, Ku, neg, zero, d) if n_neg or n_zero else [[], []]
    klass = "unstable" if n_neg else "neutral" if n_zero else "stable"
    return classified_info(model, klass, n_neg, n_zero, found[0], found[1], wmin)
