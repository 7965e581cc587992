"""Line-search trials of the stable descent (:mod:`poise.solvers.stable`) projected onto the
constraints, and the energy test that sees through their remaining violation.

A trial ``x = retract(state, alpha dq)`` leaves the constraints by ``O(alpha^2)``:
:class:`Projector` brings it back to a relative violation ``trial_tol`` (looser than the
assembly's; the end point is Newton-polished), first with the descent step's own factorised
KKT matrix (:class:`Chord`), else a Gauss-Newton one. :class:`LagrangeTest` certifies the
trial's energy change up to its violation (``violation_work``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.linalg import SingularMatrix
from poise.solvers.limits import LIMITS
from poise.solvers.reach import coord_weights, weighted_kkt
from poise.solvers.status import Status

PROJECT_TOL = 1e-8        # relative constraint violation of a line-search trial, at most ...
PROJECT_TOL_MAX = 1e-5    # ... and at least: the trial's energy error bound within
ENERGY_MARGIN = 0.01      # this fraction of the step's predicted decrease
STEP_CHORD_RATE = 0.6     # the projection refactorises when its error falls slower than this


class Chord:
    """A descent step's factorised KKT matrix used as the projection's (chord) Jacobian:
    ``correction(phi)`` is the ``dq`` of smallest ``K_s + sigma D`` norm with ``G dq = -phi``
    (``G`` at the step's start point). A positive definite metric on the constraint
    tangent space, so the system is the step's own (no new factorisation per trial)."""

    def __init__(self, P, F, rho):
        self.P, self.F, self.rho = P, F, rho

    def correction(self, phi):
        P = self.P
        g = -P.dl * phi[P.rows]
        sol = self.F.solve(np.concatenate([self.rho * (P.Gt.T @ g), g]))
        return sol[:P.nq] * P.dq / P.d


def violation_work(model, ev, state):
    """``W``: a trial whose relative constraint violation is ``e`` has a potential energy
    within about ``e W`` of its exact projection's (the correction moves each coordinate by
    about ``e`` x its length, against the residual ``r``, and each constraint by ``e`` x its
    scale, against its multiplier)."""
    ql = np.where(model.q_kind == 1, 1.0, model.L)
    rs = np.where(model.row_kind == 1, 1.0, model.L)
    r = np.abs(np.asarray(ev.r, float)[:model.nq])
    return float(np.sum(r * ql) + np.sum(np.abs(state.lam) * rs))


class LagrangeTest:
    """The energy test of a trial that sees through its constraint violation.

    A trial ``x`` violating the constraints by ``phi(x)`` has, at its exact projection ``x*``,
    the energy ``V(x*) = V(x) + lam . phi(x) + r . (x* - x) + O(|x* - x|^2)`` (``r`` the
    residual, ``lam`` the multipliers: ``grad V = r - G^T lam``). The plain test bounds the
    whole violation term by ``e W`` (:func:`violation_work`), which near the rest position of
    a heavy mechanism (``W`` ~ multipliers x L) exceeds the energy the remaining steps gain:
    the descent then stalls short of the tolerances. Here ``lam . phi`` is added to the energy
    change (at both ends of the step) and only the residual part is bounded, which vanishes
    at an equilibrium. ``decrease(dv, proj, lam)`` -> the certified energy change."""

    def __init__(self, model, ev, state, cnt):
        self.model, self.cnt = model, cnt
        ql = np.where(model.q_kind == 1, 1.0, model.L)
        self.work_r = float(np.sum(np.abs(np.asarray(ev.r, float)[:model.nq]) * ql))
        self.phi_s = np.asarray(cnt.evaluate(model, state, "phi"), float)
        scale = np.where(model.row_kind == 1, 1.0, model.L)
        self.err_s = float(np.max(np.abs(self.phi_s) / scale, initial=0.0))

    def decrease(self, dv, proj, lam):
        phi_x = getattr(proj, "phi", None)
        if phi_x is None:
            return np.inf
        dvc = dv + float(np.asarray(lam, float) @ (phi_x - self.phi_s))
        return dvc + (proj.err + self.err_s) * self.work_r


def trial_tol(alpha, slope, work):
    """Projection tolerance of a trial at ``alpha``: its energy error bound within
    ``ENERGY_MARGIN`` of the predicted decrease, between ``PROJECT_TOL`` and
    ``PROJECT_TOL_MAX`` (near the equilibrium the decrease is small and the trials exact)."""
    if not np.isfinite(work) or work <= 0.0:
        return PROJECT_TOL
    return min(max(ENERGY_MARGIN * alpha * abs(slope) / work, PROJECT_TOL), PROJECT_TOL_MAX)


class Projector:
    """Projection of a descent step's line-search trials onto the constraints, to
    ``PROJECT_TOL`` (relative: looser than the assembly's; the end point is polished by Newton
    to the deck's tolerances). Corrections ``dq`` with ``G dq = -phi`` come from one
    factorised operator, first the descent step's own (``chord``, :class:`Chord`: no new
    factorisation per trial); when the constraint error falls slower than
    ``STEP_CHORD_RATE`` per iteration, a Gauss-Newton KKT factorisation at the current point
    replaces it and serves the step's later trials too (they lie along the same direction).
    ``proj(x) -> (state, ok)`` (a :class:`Projection` run); ``err``: the last trial's
    relative violation, ``phi``: its constraint values when it met the tolerance."""

    def __init__(self, model, cnt, chord=None):
        self.model, self.cnt = model, cnt
        self.op = chord.correction if chord is not None else None
        self.scale = np.where(model.row_kind == 1, 1.0, model.L)

    def __call__(self, x, tol=PROJECT_TOL):
        m = self.model
        self.err = 0.0
        self.phi = np.zeros(m.nc) if m.nc == 0 else None
        if m.nc == 0:
            return x, True
        end = iterate(Projection(self, tol), LIMITS.trial_project_max_iter, (), x)
        self.op, self.err = end.op, end.err
        if end.phi is not None:
            self.phi = end.phi
        return end.x, end.done is Status.CONVERGED

    def refresh(self, x):
        """A Gauss-Newton operator at ``x`` (coordinate metric ``q_scale^2``), or None."""
        m = self.model
        ev = self.cnt.evaluate(m, x, "jacobian")
        try:
            F = self.cnt.factor(weighted_kkt(m, ev, coord_weights(m)))
        except SingularMatrix:
            return None
        nq = m.nq
        return lambda phi: F.solve(np.concatenate([np.zeros(nq), -phi]))[:nq]


@dataclass(frozen=True)
class Projecting:
    """Where a :class:`Projection` stands: the trial ``x``, the correction operator,
    factorisations made, the previous error, whether the operator is fresh, the last point
    (and its constraint values) before the correction; ``err`` the last relative violation,
    ``phi`` the constraint values once met; ``done``: converged, or failed (diverging, no
    operator)."""

    x: Any
    op: Any
    refreshed: int = 0
    prev: float = np.inf
    fresh: bool = False
    last: Any = None
    last_phi: Any = None
    err: float = 0.0
    phi: Any = None
    done: Status | None = None


class Projection(Solver):
    """One trial's projection (:class:`Projector`): corrections by the held operator,
    refreshed at most ``LIMITS.trial_max_refresh`` times. Budget: correction iterations.
    Result: the last :class:`Projecting`."""

    def __init__(self, proj, tol):
        self.proj, self.tol = proj, tol

    def init(self, x):
        return Projecting(x, self.proj.op)

    def terminate(self, s):
        return s.done is not None, s.done

    def step(self, s, left):
        p = self.proj
        m = p.model
        x = s.x
        phi = p.cnt.evaluate(m, x, "phi")
        err = float(np.max(np.abs(phi) / p.scale))
        s = replace(s, err=err)
        if err <= self.tol:
            return Next(replace(s, phi=np.asarray(phi, float), done=Status.CONVERGED))
        if err > s.prev and s.fresh:
            return Next(replace(s, done=Status.DIVERGED))   # diverging after a fresh factor
        op, refreshed, fresh = s.op, s.refreshed, False
        if op is None or err > STEP_CHORD_RATE * s.prev:
            if refreshed == LIMITS.trial_max_refresh:
                return Next(replace(s, done=Status.MAX_ITERATIONS))
            if err > s.prev:             # back to the better point
                x, phi, err = s.last, s.last_phi, s.prev
            op = p.refresh(x)
            if op is None:
                return Next(replace(s, x=x, done=Status.SINGULAR_JACOBIAN))
            refreshed, fresh = refreshed + 1, True
        return Next(replace(s, x=m.retract(x, op(phi)), op=op, refreshed=refreshed,
                            fresh=fresh, last=x, last_phi=phi, prev=err))

    def postprocess(self, s, status, used):
        return s


def project(model, x, cnt, chord=None):
    """Project one trial (:class:`Projector`)."""
    return Projector(model, cnt, chord)(x)
