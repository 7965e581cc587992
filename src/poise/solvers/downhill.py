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
RUNAWAY = 2 * np.pi       # a body turned a full turn: no equilibrium within reach
WORK_TURN = 0.5           # rad: largest turn of a step whose drop is measured by the work


def downhill_step(model, state, ev, dq, cnt, limit, measure, mass_times, eps):
    """A trial below ``state``'s potential energy, ``(trial, evaluation, merit, alpha, step,
    drop)`` (``drop``: how much lower), or None (no descent found). ``ev``: the evaluation at
    ``state`` (its Jacobian assembled), ``dq``: Newton's step, ``limit(state, dq) -> (factor,
    trial or None)``: the step limits, ``measure(trial) -> (trial, evaluation, merit)``: a trial
    projected onto the constraints (None beyond their reach), ``mass_times(state, v)``: ``M v``,
    ``eps``: the mass multiple in ``ev``'s Jacobian. A model without a potential (a constant
    torque, expression forces) measures the drop by the work of its loads along the step
    (trapezoidal rule: exact for a quadratic potential)."""
    if model.nq == 0:
        return None
    v0 = potential_energy(model, state)
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
    if not np.isfinite(v0) and len(model.rot_idx):
        # no potential: the drop is the work along the step by the trapezoidal rule, which
        # holds only while the loads change little along it (a turn of at most WORK_TURN)
        big = float(np.max(np.linalg.norm(d[model.rot_idx].reshape(-1, 3), axis=1)))
        if big > WORK_TURN:
            d = d * (WORK_TURN / big)
            slope = float(r @ d)
    alpha, first = limit(state, d)
    for _ in range(BACKTRACK + 1):
        trial = first if first is not None else model.retract(state, alpha * d)
        first = None
        try:
            trial, evt, m1 = measure(trial)
            drop = np.nan if trial is None else _drop(model, r, v0, trial, evt, alpha * d)
        except EvaluationError:
            trial, drop = None, np.nan
        # lower, and still going down at the trial: a step never jumps over a minimum along
        # its line (a basin passed over would look like a runaway)
        if trial is not None and drop >= -ARMIJO * alpha * slope and float(evt.r @ d) < 0:
            return trial, evt, m1, alpha, d, drop
        alpha *= 0.5
    return None


def _drop(model, r0, v0, trial, ev1, dq) -> float:
    """How much lower the potential is at ``trial`` (reached by the step ``dq``, projected)
    than at the start (residual ``r0``, potential ``v0``): exact when the model has one
    (``v0`` finite), else the work of the loads along the step (trapezoidal)."""
    if np.isfinite(v0):
        return v0 - potential_energy(model, trial)
    return -0.5 * float((r0 + ev1.r) @ dq)


def _mu_scale(model, state, ev):
    """A shift of the order of the largest stiffness-to-mass ratio of the coordinates."""
    J = ev.J
    kd = np.abs(np.asarray(J.diagonal()).ravel()[:model.nq])
    md = model.mass_diagonal(state)
    has = (md > 0) & np.isfinite(kd)
    mu = float(np.max(kd[has] / md[has])) * 1e-3 if has.any() else 1.0
    return mu if np.isfinite(mu) and mu > 0 else 1.0


class Runaway:
    """Steps down the potential that never bring the merit below where it stalled, and the
    angle each body has turned along them (continuous rotation vectors: full turns within a
    step counted). ``add`` returns why there is no equilibrium in reach once a body has
    turned a full turn: the model came back to where it was with the load never balanced on
    the way, and the potential lower; else "". A translation has no such natural measure (the
    model size says nothing about where a load's law balances): budgets bound it."""

    def __init__(self, model):
        self.model = model
        self.turn = np.zeros(model.nb)
        self.drop = 0.0

    def add(self, a, b, drop) -> str:
        """A step from state ``a`` to ``b`` and the potential ``drop`` along it."""
        m = self.model
        if m.nb == 0 or a.rotvec is None or b.rotvec is None:
            return ""
        self.turn += np.linalg.norm(b.rotvec - a.rotvec, axis=1)
        self.drop += float(drop)
        k = int(np.argmax(self.turn))
        if not self.turn[k] >= RUNAWAY:
            return ""
        where = m.coord_info[int(m.body_off[k])].rsplit(" ", 1)[0]
        energy = f"{unit_name(m, 'force')}*{unit_name(m, 'length')}"
        return (f"no equilibrium within reach: {where} turned "
                f"{self.turn[k] / (2 * np.pi):.3g} turns down the potential energy (it fell by "
                f"{self.drop:.6g} {energy}) and the imbalance never came closer to zero than "
                "where Newton's line search stalled: a load the model cannot hold anywhere along "
                "a full turn (more than its springs or gravity can balance)")


_ABBREV = {"NEWTON": "N", "KNEWTON": "kN", "MILLINEWTON": "mN", "POUND_FORCE": "lbf",
           "METER": "m", "MILLIMETER": "mm", "CENTIMETER": "cm", "KILOMETER": "km",
           "INCH": "in", "FOOT": "ft"}


def unit_name(model, kind) -> str:
    """The deck's unit name of ``kind`` (``force``, ``length``) for messages."""
    names = dict(p.split("=", 1) for p in str(model.units or "").split() if "=" in p)
    name = names.get(kind, "NEWTON" if kind == "force" else "METER").upper()
    return _ABBREV.get(name, name.lower())
