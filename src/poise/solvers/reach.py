"""Least-change projection onto the constraints, and the reach of an assembly.

The weighted KKT system ``[[W, G^T], [G, 0]]`` (``W`` the squared coordinate scales) gives the
smallest move (lengths, rotations weighted by the body's size) that corrects the constraint
values to first order; iterated, it is Gauss-Newton on ``Phi(q) = 0``. It assembles an input
onto its constraints (:class:`Assembly`) and keeps Newton's trial points
where the loop can close (:func:`project`): a trial Newton's linearised constraints put far off
the constraints (a slider-crank's slider pushed past ``r + l``) is brought back onto them, and
one whose Gauss-Newton stops converging lies beyond the assembly's reach, so Newton shortens
its step instead of iterating from an unassemblable point. Details: docs/solvers.md.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from poise.core import per_object
from poise.core.errors import EvaluationError
from poise.solvers.history import Row
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.limits import LIMITS, Limits
from poise.solvers.linalg import SingularMatrix
from poise.solvers.status import Status

PROJECT_ABOVE = 1e-3     # a Newton trial violating its constraints by more (x L, rad) is projected
PROJECT_TOL = 1e-10      # projection accuracy (x L, rad), that of the input's assembly
PROJECT_RATE = 0.5       # Gauss-Newton must at least halve the violation per iteration
ASSEMBLY_TOL = 1e-10     # relative constraint violation after assembly


def weighted_kkt(model, ev, W):
    """KKT matrix with ``diag(W)`` in the coordinate block and the constraint Jacobian."""
    nq = model.nq
    J = ev.J
    if hasattr(J, "tocsc"):
        K = _weighted_sparse(J.tocsr(), nq, np.asarray(W, float))
        # its pattern is within the KKT pattern: the assembler's column order serves it too
        K.poise_column_order = getattr(J, "poise_column_order", None)
        return K
    K = np.array(J, copy=True)
    K[:nq, :nq] = np.diag(W)
    return K


def _weighted_sparse(J, nq, W):
    """``[[diag(W), B], [C, D]]`` from the CSR KKT matrix ``J = [[*, B], [C, D]]`` in one pass
    over its index arrays (the coordinate rows keep their entries in multiplier columns behind
    the diagonal ``W``, the constraint rows are copied): the CSC matrix ``scipy.sparse.bmat``
    of the four blocks gives (same entries, stored zeros and sorted rows), without its four
    intermediate matrices."""
    import scipy.sparse as sp  # lazy: sparse systems only
    J.sort_indices()
    p = J.indptr[nq]
    keep = J.indices[:p] >= nq                         # B's entries in the coordinate rows
    kept = np.concatenate([[0], np.cumsum(keep)])[J.indptr[:nq + 1]]
    ptr = np.concatenate([kept + np.arange(nq + 1), J.indptr[nq + 1:] - p + kept[-1] + nq])
    top = ptr[:nq]                                     # each coordinate row: W first
    n = int(ptr[-1])
    idx = np.empty(n, J.indices.dtype)
    val = np.empty(n)
    idx[top], val[top] = np.arange(nq), W
    rest = np.ones(n, bool)
    rest[top] = False
    nb = int(kept[-1])
    pos = np.nonzero(rest)[0]
    idx[pos[:nb]], val[pos[:nb]] = J.indices[:p][keep], J.data[:p][keep]
    idx[pos[nb:]], val[pos[nb:]] = J.indices[p:], J.data[p:]
    return sp.csr_matrix((val, idx, ptr), shape=J.shape).tocsc()


def coord_weights(model):
    """Squared length per unit of each coordinate (rotations weighted by the body's size)."""
    return model.q_scale ** 2


def violation(model, phi) -> float:
    """Largest constraint violation, translations relative to L, rotations in radians."""
    if not phi.size:
        return 0.0
    return float(np.maximum.reduce(np.abs(phi) / _row_lengths(model)))


_ROW_LENGTHS = per_object.table()


def _row_lengths(model) -> np.ndarray:
    """Per constraint row 1 (rotational) or L (translational): :func:`violation`'s divisor,
    made once per model (read-only)."""
    def make():
        got = np.where(model.row_kind == 1, 1.0, model.L)
        got.setflags(write=False)
        return got
    return per_object.once_per(_ROW_LENGTHS, model, make)


def project(model, state, cnt, ev=None, limits: Limits = LIMITS):
    """``state`` moved onto its active constraints by least-change Gauss-Newton, or None when
    that does not converge at ``PROJECT_RATE`` (the constraints cannot be met near it: beyond
    the assembly's reach, or a singular configuration). ``ev``: an evaluation at ``state``
    (saves one); at most ``limits.project_max_iter`` steps (:class:`OntoConstraints` run by
    the one loop). Evaluations and factorisations are counted in ``cnt``."""
    return iterate(OntoConstraints(model, cnt), limits.project_max_iter + 1, [], state, ev)


@dataclass(frozen=True)
class _Projecting:
    """:class:`OntoConstraints`' state: the configuration, its evaluation (None: not yet), the
    violation before and the verdict once known (True: on the constraints)."""

    state: object
    ev: object = None
    prev: float = np.inf
    on: bool | None = None


class OntoConstraints(Solver[_Projecting]):
    """:func:`project` as a :class:`~poise.solvers.iterate.Solver`: one step evaluates the
    configuration (when not yet), decides (within ``PROJECT_TOL``: on; not converging at
    ``PROJECT_RATE``: beyond reach) or takes one weighted least-change Gauss-Newton step. A
    spent budget, a singular system or an element that cannot be evaluated: beyond reach."""

    out_of_budget = Status.ASSEMBLY_FAILED

    def __init__(self, model, cnt):
        self.model, self.cnt = model, cnt
        self.W = coord_weights(model)

    def init(self, state, ev=None):
        return _Projecting(state, ev)

    def terminate(self, s):
        if s.on is None:
            return False, None
        return True, Status.CONVERGED if s.on else Status.ASSEMBLY_FAILED

    def step(self, s, left):
        model, cnt = self.model, self.cnt
        try:
            ev = s.ev if s.ev is not None else cnt.evaluate(model, s.state, "defer")
            v = violation(model, ev.phi)
            if v <= PROJECT_TOL:
                return Next(replace(s, ev=ev, on=True))
            if not v <= PROJECT_RATE * s.prev:
                return Next(replace(s, on=False))
            cnt.jacobian(model, ev)
            x = cnt.factor(weighted_kkt(model, ev, self.W)).solve(
                np.concatenate([np.zeros(model.nq), -ev.phi]))
            if not np.all(np.isfinite(x)):
                return Next(replace(s, on=False))
            return Next(_Projecting(model.retract(s.state, x[:model.nq]), None, v))
        except (SingularMatrix, EvaluationError):
            return Next(replace(s, on=False))

    def postprocess(self, s, status, used):
        return s.state if s.on else None


def assemble(model, state, settings, history, frame: int, cnt, ev=None):
    """Least-change projection onto the constraints (Gauss-Newton on the KKT system,
    :class:`Assembly` run by :func:`~poise.solvers.iterate.iterate` within
    ``Limits.assembly_max_iter`` steps). ``ev``: an evaluation at ``state`` with the solve's
    active rows (the prologue's; saves the first evaluation).

    Returns ``(state, assembled: bool, status)``; ``assembled`` says whether anything moved.
    """
    if model.nc == 0:
        return state, False, Status.CONVERGED
    return iterate(Assembly(model, settings, frame, cnt), settings.limits.assembly_max_iter,
                   history, state, ev)


@dataclass(frozen=True)
class _Assembling:
    """:class:`Assembly`'s state: the configuration, its evaluation and violation ``v``."""

    state: object
    ev: object
    v: float
    it: int = 0
    moved: bool = False
    status: Status | None = None


class Assembly(Solver[_Assembling]):
    """:func:`assemble` as a :class:`~poise.solvers.iterate.Solver`: ``step`` is one weighted
    least-change Gauss-Newton step and its ``assembly`` history row; each configuration is
    evaluated (and its violation measured) where it is made, so ``terminate`` only reads."""

    out_of_budget = Status.ASSEMBLY_FAILED

    def __init__(self, model, settings, frame, cnt):
        self.model, self.frame, self.cnt = model, frame, cnt
        self.q_len = np.where(model.q_kind == 0, model.L, 1.0)   # trans / L, rad, scalars
        self.W = coord_weights(model)

    def _at(self, state, it, moved, ev=None):
        model = self.model
        if ev is None:
            ev = self.cnt.evaluate(model, state, "defer")   # Jacobian only if violated
        v = float((np.abs(ev.phi) / np.where(model.row_kind == 1, 1.0, model.L)).max())
        return _Assembling(state, ev, v, it, moved, Status.CONVERGED if v <= ASSEMBLY_TOL else None)

    def init(self, state, ev=None):
        return self._at(state, 0, False, ev)

    def terminate(self, s):
        return s.status is not None, s.status

    def postprocess(self, s, status, used):
        return s.state, s.moved, status

    def step(self, s, left):
        model, ev = self.model, s.ev
        self.cnt.jacobian(model, ev)
        K = weighted_kkt(model, ev, self.W)
        try:
            x = self.cnt.factor(K).solve(np.concatenate([np.zeros(model.nq), -ev.phi]))
        except SingularMatrix:
            return Next(replace(s, status=Status.ASSEMBLY_FAILED), 0)
        dq = x[:model.nq]
        prev = s.state                    # the row's pose: the configuration it measured
        sn = float(np.max(np.abs(dq) / self.q_len))
        row = Row(self.frame, s.it, float(np.max(np.abs(ev.r))) if ev.r.size else 0.0, s.v, sn,
                  1.0, "", "assembly", pos=prev.pos, rot=prev.rot)
        return Next(self._at(model.retract(prev, dq), s.it + 1, True), 1, (row,))
