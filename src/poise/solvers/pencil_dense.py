"""The descent's shifted-stiffness pencil for small models, dense.

:class:`poise.solvers.stability_sparse.SparsePencil` (equilibration, elimination order,
sparse ``L D L^T``) costs a few milliseconds of Python per step whatever the size; below
``DENSE_PENCIL`` unknowns the same matrices are built dense and "factorised" by a symmetric
eigendecomposition, whose eigenvalue signs are the inertia exactly (no pivoting question) and
whose eigenvectors solve. Same interface as the sparse pencil for
:mod:`poise.solvers.stable`: ``nq, m, d, dq, dl, rows, Gt, eps, reused, ldl(s, rho)``.
"""
from __future__ import annotations

import numpy as np

from poise.solvers.stability_modes import ZERO_REL
from poise.solvers.equilibrate import equilibrate as _equilibrate
from poise.solvers.equilibrate import prune_noise as _prune_noise

DENSE_PENCIL = 150        # nq + constraint rows at or below: the dense pencil (eigh ~ ms)


class EigenLDL:
    """Inertia and solves of a small symmetric matrix from its eigendecomposition (the
    attributes :class:`~poise.solvers.symmetric_ldl.SymmetricLDL` offers the descent)."""

    def __init__(self, A):
        A = 0.5 * (A + A.T)
        self.ok = bool(np.all(np.isfinite(A)))
        self.reason = "" if self.ok else "the matrix is not finite"
        if not self.ok:
            self.n_negative = -1
            return
        self.w, self.V = np.linalg.eigh(A)
        self.pivots = self.w
        self.n_negative = int(np.count_nonzero(self.w < 0))
        self.backward_error = 32 * np.finfo(float).eps * float(np.max(np.abs(self.w),
                                                                       initial=0.0))

    def solve(self, b):
        return self.V @ ((self.V.T @ np.asarray(b, float)) / self.w)


class DensePencil:
    """Length-scaled symmetric stiffness ``Kt`` and active constraint Jacobian ``Gt`` after a
    symmetric (Ruiz) equilibration of the KKT matrix, dense; ``like``: a previous pencil of
    the same rows whose scaling starts the equilibration."""

    def __init__(self, model, J, active=None, like=None):
        import scipy.sparse as sp         # lazy: a plain solve of a small deck imports no scipy
        nq = model.nq
        J = J.toarray() if hasattr(J, "toarray") else np.asarray(J, float)
        d = np.asarray(model.q_scale, float)
        Ku = J[:nq, :nq] / d[:, None] / d[None, :]
        Ks = _prune_noise(sp.csr_matrix(0.5 * (Ku + Ku.T))).toarray()
        rows = np.arange(model.nc) if active is None else np.nonzero(active)[0]
        G = J[nq:, :nq][rows] / d[None, :]
        if len(rows):
            rn = np.linalg.norm(G, axis=1)
            keep = rn > 1e-10 * rn.max()
            G, rows = G[keep], rows[keep]
        self.rows = rows
        self.reused = like is not None and like.nq == nq and np.array_equal(like.rows, rows)
        dq, dl = _equilibrate(sp.csr_matrix(Ks), sp.csr_matrix(G),
                              start=(like.dq, like.dl) if self.reused else None)
        self.Kt = dq[:, None] * Ks * dq[None, :]
        self.Gt = dl[:, None] * G * dq[None, :]
        self.Ks, self.d, self.dq, self.dl = Ks, d, dq, dl
        self.nq, self.m = nq, len(rows)
        self.order = None
        radius = float(np.max(np.abs(np.linalg.eigvalsh(self.Kt)), initial=0.0)) if nq else 0.0
        self.eps = ZERO_REL * max(radius, 1.0)

    def kkt(self, s, rho):
        """``[[Kt - s I + rho Gt^T Gt, Gt^T], [Gt, 0]]``."""
        A = self.Kt + rho * (self.Gt.T @ self.Gt) - s * np.eye(self.nq)
        if not self.m:
            return A
        return np.block([[A, self.Gt.T], [self.Gt, np.zeros((self.m, self.m))]])

    def ldl(self, s, rho):
        return EigenLDL(self.kkt(s, rho))
