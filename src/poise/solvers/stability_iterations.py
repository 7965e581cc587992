"""The modes of a large model's stability classification: iterations with the operator
``v -> x`` of a factorised shifted KKT matrix (:meth:`SparsePencil.op
<poise.solvers.stability_sparse.SparsePencil.op>`), whose dominant eigenvalues are the reduced
stiffness' eigenvalues nearest the shift. A stable frame's lowest mode (Krylov iteration with
an a-posteriori residual stop), the unstable modes (Lanczos, or block iteration after a shift
below the spectrum) and the neutral modes (block iteration; a whole zero eigenspace described
from its canonical basis). docs/stability.md, step 4.
"""
from __future__ import annotations

import numpy as np

from poise.solvers.stability_modes import (
    LOW_ANGLE,
    LOW_BLOCK,
    LOW_MAX,
    N_MODES,
    SMALL_OP,
    canonical_basis,
)


def _eig_extreme(op, n, k, which, tol, maxiter=20):
    """``k`` eigenpairs of the symmetric operator ``op`` at the end ``which`` ('LA' or 'SA'):
    dense for small operators, else implicitly restarted Lanczos (ARPACK; on non-convergence
    the pairs that did converge)."""
    if n <= SMALL_OP:
        A = op.matmat(np.eye(n))
        w, V = np.linalg.eigh(0.5 * (A + A.T))
        idx = np.argsort(w if which == "SA" else -w)[:k]
        return w[idx], V[:, idx]
    from scipy.sparse.linalg import ArpackError, ArpackNoConvergence, eigsh
    v0 = op.matvec(np.random.default_rng(7).standard_normal(n))     # in the range of op
    try:
        return eigsh(op, k=k, which=which, tol=tol, v0=v0, maxiter=maxiter)
    except ArpackNoConvergence as e:
        return e.eigenvalues, e.eigenvectors
    except ArpackError:
        return np.zeros(0), np.zeros((n, 0))


def _subspace(P, op, b, iters, seed, X=None):
    """Block subspace iteration on ``op`` (block size ``b``, one multi-right-hand-side solve per
    step) followed by a Rayleigh-Ritz step on Kt: the Ritz pairs ``(mu, X)`` (mu ascending) of
    the dominant invariant subspace of ``op``. Ritz values are Rayleigh quotients, so a Ritz
    vector of a tight cluster is a valid mode with that value even before it has converged."""
    b = max(1, min(b, P.nq))
    if X is None:
        X = np.random.default_rng(seed).standard_normal((P.nq, b))
    X = op.matmat(X)
    for it in range(iters + 1):
        U = _orthonormalize(_orthonormalize(X))
        if it < iters:
            X = op.matmat(U)
    H = U.T @ (P.Kt @ U)
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    return w, U @ V


def _orthonormalize(X, rtol=1e-7):
    """Orthonormal basis of the columns of tall X from its Gram matrix (one pass loses the
    directions below ``rtol`` of the largest: harmless here, they are the ones the iteration
    discards; call twice for orthogonality to round-off). Cheaper than QR for n x 10. One
    column is scaled to unit length (none if it is zero)."""
    if X.shape[1] == 1:
        nx = float(np.linalg.norm(X))
        return X / nx if nx > 0.0 else X[:, :0]
    Gm = X.T @ X
    w, V = np.linalg.eigh(0.5 * (Gm + Gm.T))
    keep = w > (rtol ** 2) * max(float(w[-1]), 0.0) if w.size else w > 0
    keep &= w > 0
    Y = X @ V[:, keep]
    Y /= np.sqrt(w[keep])                 # (in place: one tall temporary fewer)
    return Y


def lowest_mode(P, F, s):
    """Stable model (``kkt(s)`` has no reduced eigenvalue below ``s``): the smallest ones are
    the dominant eigenvalues ``theta = 1/(mu - s) > 0`` of ``op(F)``, found by Krylov
    iteration (``LOW_BLOCK`` vectors a step, fully reorthogonalised) with Rayleigh-Ritz on
    ``op`` over the whole basis: one solve per step, until the dominant Ritz vector ``x`` is
    within ``LOW_ANGLE`` of the eigenvector by the a-posteriori bound ``||op(x) - theta x|| /
    (theta - theta_2)`` (``theta_2``: the next Ritz value; ``LOW_MAX`` steps at most). The
    mode is ``op(x)``, one power step past ``x`` and on the manifold, made of the solves done:
    its Rayleigh quotient is within ``LOW_ANGLE^2 theta_2 / theta`` of ``mu - s`` (relative).
    So the stop is on the value reported (a narrow gap asks for a smaller residual, a wide one
    for a larger), not on the residual alone. An exactly degenerate lowest eigenvalue is one
    eigenvalue to a Krylov iteration; in a tight cluster a Ritz vector is a valid mode of its
    value."""
    op = P.op(F)
    nq = P.nq
    b = min(LOW_BLOCK, nq)
    Q = _orthonormalize(_orthonormalize(_low_start(nq, b)))
    # the basis Qa and its images Wa = op(Qa), filled in place (pages touched only as filled),
    # and their small products H = Qa^T Wa, M = Wa^T Wa, a block of columns (and rows) a step
    m = LOW_MAX * b
    Qa = np.empty((nq, m), order="F")
    Wa = np.empty_like(Qa)
    H, M = np.zeros((m, m)), np.zeros((m, m))
    n = 0
    for _ in range(LOW_MAX):
        k = Q.shape[1]
        Qa[:, n:n + k] = Q
        W = Wa[:, n:n + k]
        W[...] = op.matmat(Q)
        n += k
        C = Qa[:, :n].T @ W
        H[:n, n - k:n], H[n - k:n, :n] = C, C.T
        D = Wa[:, :n].T @ W
        M[:n, n - k:n], M[n - k:n, :n] = D, D.T
        th, Y = np.linalg.eigh(0.5 * (H[:n, :n] + H[:n, :n].T))
        y, t = Y[:, -1], float(th[-1])
        # ||op(x) - t x||^2 = y^T M y - t^2 for x = Qa y (Qa orthonormal, y^T H y = t)
        gap = t - float(th[-2]) if n > 1 else 0.0
        if not t > 0.0 or n + b > m or \
                float(y @ M[:n, :n] @ y) - t * t <= (LOW_ANGLE * gap) ** 2:
            break
        R = W - Qa[:, :n] @ C                         # the next block: W's new directions
        R -= Qa[:, :n] @ (Qa[:, :n].T @ R)            # (twice: orthogonal to round-off)
        Q = _orthonormalize(R if k == 1 else _orthonormalize(R))   # (one column: scaled)
        if not Q.shape[1]:                            # (an invariant subspace: nothing new)
            break
    x = Wa[:, :n] @ y                                 # op(Qa y)
    found = sorted(P.modes(x), key=lambda mo: mo[2])
    return [mo[:2] for mo in found[:1]]


def _low_start(nq, b):
    """:func:`lowest_mode`'s start block: unit random columns, each plus the unit constant
    vector (the scaled coordinates all moving alike). The random part gives every eigenvector
    the weight a random start gives it (the constant only adds to it: a mode is missing only
    if the two cancel exactly, as unlikely as a random start without it), and the stopping
    test is unchanged; the constant weighs the smooth, global modes that are typically the
    softest (a chain's swing): one solve fewer on the 10^3 to 10^5 link chains."""
    X = np.random.default_rng(5).standard_normal((nq, b))
    X /= np.linalg.norm(X, axis=0)
    X += 1.0 / np.sqrt(nq)
    return X


def negative_modes(P, F, s, n_neg):
    """Up to N_MODES unstable modes, most negative first.

    ``F`` factorises ``kkt(s)``, ``s = -eps``: the negative eigenvalues ``1/(mu - s)`` of
    ``op(F)`` are exactly the n_neg unstable modes, well apart from the positive ones when the
    instability is weak. When all of them are wanted (n_neg <= N_MODES) Lanczos takes them from
    there. Otherwise (or if Lanczos does not deliver them all) a further factorisation at a
    Gershgorin lower bound ``s_lo`` of the spectrum of Kt (no reduced eigenvalue below it,
    checked by its inertia) makes the most unstable modes the dominant ones of a positive
    operator, and a block iteration gives them (Ritz pairs: inside a tight cluster, valid
    modes of that value). Its lowest Ritz value ``r`` then gives a closer shift ``1.1 r``,
    used (after the same inertia check) for a few more steps: convergence goes with
    ``(mu_1 - s) / (mu_j - s)``."""
    k = min(n_neg, N_MODES)
    found = []
    if n_neg <= N_MODES:
        th, X = _eig_extreme(P.op(F), P.nq, k, "SA", 1e-8)
        found = [mo for mo in P.modes(X[:, th < 0]) if mo[2] < -P.eps]
    if len(found) < k:
        X = None
        s_lo = -1.01 * float(abs(P.Kt).sum(axis=1).max()) - P.eps
        for _ in range(2):
            lo, _why = P.factor(s_lo)
            if lo is None or lo.n_negative != P.m:
                break
            w, X = _subspace(P, P.op(lo), k + 6, 3, seed=3, X=X)
            more = [mo for mo in P.modes(X) if mo[2] < -P.eps]
            if len(more) >= len(found):
                found = more
            if not w.size or w[0] >= -P.eps:
                break
            s_lo = 1.1 * float(w[0])
    found.sort(key=lambda mo: mo[2])
    return [mo[:2] for mo in found[:k]]


def zero_modes(P, F, s, n_zero):
    """Up to N_MODES neutral modes. With ``F`` factorising ``kkt(s)``, ``s = -eps``, the reduced
    eigenvalues in [-eps, eps] are the dominant ones of ``op(F)`` (>= 1/(2 eps)), exactly
    degenerate clusters included: a short block iteration and Rayleigh-Ritz give them. When
    they span the whole zero eigenspace, it is described from its basis that does not depend
    on the iteration's (:func:`canonical_basis`, as on the dense path)."""
    k = min(n_zero, N_MODES)
    w, X = _subspace(P, P.op(F), k + 4, 4, seed=11)
    X = X[:, np.argsort(np.abs(w), kind="stable")]
    found = [mo for mo in P.modes(X) if abs(mo[2]) <= 2 * P.eps]
    if 1 < n_zero <= len(found):          # the whole zero eigenspace: described as the dense
        C = canonical_basis(np.stack([q * P.d for q, _, _ in found[:n_zero]], axis=1))
        w = np.einsum("ij,ij->j", C, P.Ks @ C)          # (length coordinates, unit columns)
        found = [(C[:, j] / P.d, float(w[j])) for j in range(C.shape[1])]
    return [mo[:2] for mo in found[:k]]
