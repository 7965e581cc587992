"""Scalar unknowns (``Control_Diff`` states, implicit ``Reference_Variable`` s) in the stability
classification: eliminated through their own equations before the inertia is counted.

A scalar unknown has no potential energy: its residual row is an equation ``e(q, s) = 0`` whose
sign is a convention (an explicit ``Control_Diff`` ``y' = c - y`` has ``de/dy = -1``: a stable
state, yet a "negative stiffness" if the row were read as a force). In a static analysis the
states are slaved to the mechanism (``y' = 0`` always holds), so the verdict is the mechanism's
with ``s = s(q)``: the Schur complement ``J_oo - J_os J_ss^-1 J_so`` over the other unknowns
(coordinates, the states kept and the multipliers), in which any scaling of the eliminated
rows cancels. A state whose equation does not determine it (an integrator reading only the
mechanism: ``y' = target - x``, ``de/dy = 0``) is kept, and the coupled matrix is classified
as it is (documented limitation, docs/stability.md).
"""
from __future__ import annotations

import numpy as np

#: a state is eliminated when its own derivative is above this fraction of its block's largest
#: and the block of those eliminated has a reciprocal condition above it too
RCOND_MIN = 1e-12


class MechanicalView:
    """The model seen with the eliminated scalar unknowns removed (``keep``: the coordinates
    kept, in order; body coordinates come first, so their offsets are unchanged): what the
    classification reads (``nq``, ``n_extra``, ``q_scale``, ``coord_info``); everything else is
    the model's."""

    def __init__(self, model, keep):
        self._model = model
        self.nq = len(keep)
        self.n_extra = model.n_extra - (model.nq - len(keep))
        self.q_scale = np.asarray(model.q_scale)[keep]
        self.coord_info = [model.coord_info[k] for k in keep]

    def __getattr__(self, name):
        return getattr(self._model, name)


def _split(model, Jss):
    """Indices (into the scalar block) of the states to eliminate: an own derivative above
    RCOND_MIN of the block's largest entry in every frame of ``Jss`` (F, ns, ns)."""
    big = np.abs(Jss).max(axis=(1, 2))
    d = np.abs(np.diagonal(Jss, axis1=1, axis2=2))
    return np.nonzero(np.all(d > RCOND_MIN * np.maximum(big, 1e-300)[:, None], axis=0))[0]


def _parts(model, N, el):
    nq, ns = model.nq, model.n_extra
    s = nq - ns + el                                   # eliminated unknowns (KKT indices)
    o = np.setdiff1d(np.arange(N), s)                  # kept: coordinates, states, multipliers
    keep = o[o < nq]
    return s, o, keep


def eliminate_dense(model, J):
    """``J`` (F, N, N) -> ``(view, J_red, ok (F,), lift)`` or None (nothing to eliminate).
    ``ok[f]``: frame f's eliminated block is invertible (its reduced matrix is valid);
    ``lift(f, x)``: a coordinate vector of the view completed with the eliminated ``ds``."""
    ns = model.n_extra
    if not ns:
        return None
    first = model.nq - ns
    el = _split(model, J[:, first:model.nq, first:model.nq])
    if not len(el):
        return None
    s, o, keep = _parts(model, J.shape[1], el)
    Jss = J[:, s][:, :, s]
    sv = np.linalg.svd(Jss, compute_uv=False)
    ok = sv[:, -1] > RCOND_MIN * np.maximum(sv[:, 0], 1e-300)
    Jos, Jso = J[:, o][:, :, s], J[:, s][:, :, o]
    X = np.zeros_like(Jso)
    if ok.any():
        X[ok] = np.linalg.solve(Jss[ok], Jso[ok])                 # J_ss^-1 J_so
    Jr = J[:, o][:, :, o] - np.matmul(Jos, X)
    nk = len(keep)

    def lift(f, x):
        full = np.zeros(model.nq)
        full[keep] = x
        full[s] = -X[f][:, :nk] @ np.asarray(x, float)
        return full
    return MechanicalView(model, keep), Jr, ok, lift


def eliminate_sparse(model, J):
    """The sparse one-frame counterpart: ``(view, J_red, lift)`` or None (nothing to eliminate,
    or a singular block)."""
    import scipy.sparse as sp                          # lazy: the sparse path has it loaded
    ns = model.n_extra
    if not ns:
        return None
    J = sp.csr_matrix(J)
    first = model.nq - ns
    el = _split(model, J[first:model.nq][:, first:model.nq].toarray()[None])
    if not len(el):
        return None
    s, o, keep = _parts(model, J.shape[0], el)
    Jss = J[s][:, s].toarray()
    sv = np.linalg.svd(Jss, compute_uv=False)
    if not sv[-1] > RCOND_MIN * max(sv[0], 1e-300):
        return None
    X = np.linalg.solve(Jss, J[s][:, o].toarray())                 # (ne, N - ne), small
    Jr = (J[o][:, o] - sp.csr_matrix(J[o][:, s] @ X)).tocsr()
    nk = len(keep)

    def lift(x):
        full = np.zeros(model.nq)
        full[keep] = x
        full[s] = -X[:, :nk] @ np.asarray(x, float)
        return full
    return MechanicalView(model, keep), Jr, lift
