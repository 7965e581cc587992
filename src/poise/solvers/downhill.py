"""Newton's way out of a stall of its merit: a step down the potential energy.

Newton's line search minimises the tolerance-scaled residual norm, whose local minima are not
all equilibria: on a slider-crank whose crank must turn through the toggle, the residual norm
has a valley short of the toggle (the generalised force shrinks and grows again) where every
Newton direction goes uphill in the merit and the line search stalls. The potential energy has
no such spurious minima (its critical points are the equilibria). When the merit stalls and
the model is conservative, :func:`downhill_step` takes a step that lowers the potential:
Newton's own direction if it descends, else the direction of ``K + mu M`` with ``mu`` raised
until it does (a pseudo-time step), backtracked on the energy and projected onto the
constraints like every trial. Newton then resumes from the lower point. Details:
docs/solvers.md, "Newton on mechanisms".
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError
from poise.solvers.energy import potential_energy
from poise.solvers.linalg import SingularMatrix

ARMIJO = 1e-4
BACKTRACK = 8             # energy line-search halvings
MU_TRIES = 6              # shifts tried, each x 10
MU_FIRST = 2.0            # first shift: this x the negative curvature along Newton's step


def downhill_step(model, state, ev, dq, cnt, limit, measure, mass_times, eps):
    """A trial below ``state``'s potential energy, ``(trial, evaluation, merit, alpha, step)``,
    or None (no potential, no descent found). ``ev``: the evaluation at ``state`` (its
    Jacobian assembled), ``dq``: Newton's step, ``limit(state, dq) -> (factor, trial or
    None)``: the step limits, ``measure(trial) -> (trial, evaluation, merit)``: a trial
    projected onto the constraints (None beyond their reach), ``mass_times(state, v)``: ``M v``,
    ``eps``: the mass multiple in ``ev``'s Jacobian."""
    v0 = potential_energy(model, state)
    if not np.isfinite(v0) or model.nq == 0:
        return None
    nq = model.nq
    r = ev.r
    d = dq
    slope = float(r @ d)                 # dV along d (the constraints' reactions do no work)
    if not slope < 0:
        # Newton heads uphill (negative curvature along its step): shift until it descends
        # curvature of K along dq, from the KKT rows (K + eps M) dq + G^T dl = -r, G dq = 0
        mM = float(dq @ mass_times(state, dq))
        mu = MU_FIRST * (slope / mM + eps) if mM > 0 else 0.0
        d = None
        if not (np.isfinite(mu) and mu > 0):
            mu = _mu_scale(model, state, ev)
        for _ in range(MU_TRIES):
            try:
                evm = cnt.evaluate(model, state, "jacobian", eps=eps + mu)
                x = cnt.factor(evm.J).solve(-np.concatenate([evm.r, evm.phi]))
            except (EvaluationError, SingularMatrix):
                x = None
            if x is not None and np.all(np.isfinite(x)):
                s = float(r @ x[:nq])
                if s < 0:
                    d, slope = x[:nq], s
                    break
            mu *= 10.0
        if d is None:
            return None
    alpha, first = limit(state, d)
    for _ in range(BACKTRACK + 1):
        trial = first if first is not None else model.retract(state, alpha * d)
        first = None
        try:
            trial, evt, m1 = measure(trial)
            v1 = potential_energy(model, trial) if trial is not None else np.nan
        except EvaluationError:
            trial, v1 = None, np.nan
        if trial is not None and v1 <= v0 + ARMIJO * alpha * slope:
            return trial, evt, m1, alpha, d
        alpha *= 0.5
    return None


def _mu_scale(model, state, ev):
    """A shift of the order of the largest stiffness-to-mass ratio of the coordinates."""
    J = ev.J
    kd = np.abs(np.asarray(J.diagonal()).ravel()[:model.nq])
    md = model.mass_diagonal(state)
    has = (md > 0) & np.isfinite(kd)
    mu = float(np.max(kd[has] / md[has])) * 1e-3 if has.any() else 1.0
    return mu if np.isfinite(mu) and mu > 0 else 1.0
