"""Newton's way out of a stall of its merit: a step down the potential energy.

Newton's line search minimises the tolerance-scaled residual norm, whose local minima are not
all equilibria: on a slider-crank whose crank must turn through the toggle, the residual norm
has a valley short of the toggle (the generalised force shrinks and grows again) where every
Newton direction goes uphill in the merit and the line search stalls. The potential energy has
no such spurious minima (its critical points are the equilibria). When the merit stalls and
the model is conservative, :func:`downhill_step` takes a step that lowers the potential:
Newton's own direction if it descends within the step limits, else the direction of
``K + mu M`` with ``mu`` raised until it does (a pseudo-time step; when Newton's step overran
the limits, also until no body turns more than ``SHIFT_TURN``), backtracked on the energy and
projected onto the constraints like every trial. Newton then resumes from the lower point. Details:
docs/solvers.md, "Newton on mechanisms".
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError
from poise.solvers.energy import potential_energy
from poise.solvers.linalg import SingularMatrix
from poise.solvers.limits import LIMITS

ARMIJO = 1e-4
MU_FIRST = 2.0            # first shift: this x the negative curvature along Newton's step
RUNAWAY = 2 * np.pi       # a body turned a full turn: no equilibrium within reach
WORK_TURN = 0.5           # rad: largest turn of a step whose drop is measured by the work
SHIFT_TURN = 1.0          # rad: a shifted step turning a body more than this: shift more
DROP_SHARE = 0.1          # a runaway's potential drop: at least this x turn x stalled moment


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
    r = ev.r
    d = dq
    slope = float(r @ d)                 # dV along d (the constraints' reactions do no work)
    mu, cap = None, np.inf
    if not slope < 0:
        # Newton heads uphill (negative curvature along its step): shift until it descends
        # curvature of K along dq, from the KKT rows (K + eps M) dq + G^T dl = -r, G dq = 0
        mM = float(dq @ mass_times(state, dq))
        mu = MU_FIRST * (slope / mM + eps) if mM > 0 else 0.0
    elif limit(state, d)[0] < 1.0:
        # Newton's step goes beyond the step limits, mostly along a direction of (nearly) no
        # stiffness (a free spin only the regularisation bounds): cut to the limits it would
        # spin and leave the rest of the step nothing; a shifted, pseudo-time step damps that
        # direction and keeps the descent
        mu, cap = 0.0, SHIFT_TURN
    if mu is not None:
        if not (np.isfinite(mu) and mu > 0):
            mu = _mu_scale(model, state, ev)
        d, slope = _shifted(model, state, ev, cnt, eps, mu, cap)
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
    for _ in range(LIMITS.backtrack + 1):
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


def _shifted(model, state, ev, cnt, eps, mu, cap=np.inf):
    """The step of ``K + (eps + mu) M`` with the constraints, ``mu`` raised x 10 up to
    ``LIMITS.mu_tries`` times until it descends and turns no body more than ``cap`` rad (a
    pseudo-time step, not a leap along a direction only the shift bounds): ``(step, slope)``
    (the last descending one if none turns that little), or ``(None, nan)``."""
    nq = model.nq
    out = (None, np.nan)
    for _ in range(LIMITS.mu_tries):
        try:
            evm = cnt.evaluate(model, state, "jacobian", eps=eps + mu)
            x = cnt.factor(evm.J).solve(-np.concatenate([evm.r, evm.phi]))
        except (EvaluationError, SingularMatrix):
            x = None
        if x is not None and np.all(np.isfinite(x)):
            s = float(ev.r @ x[:nq])
            if s < 0:
                out = (x[:nq], s)
                turn = (float(np.max(np.linalg.norm(x[model.rot_idx].reshape(-1, 3), axis=1)))
                        if len(model.rot_idx) else 0.0)
                if turn <= cap:
                    return out
                # a large shift's step shrinks as 1 / mu: aim at the cap
                mu *= min(10.0, max(2.0, 1.2 * turn / cap))
                continue
        mu *= 10.0
    return out


def _mu_scale(model, state, ev):
    """A shift of the order of the largest stiffness-to-mass ratio of the coordinates."""
    J = ev.J
    kd = np.abs(np.asarray(J.diagonal()).ravel()[:model.nq])
    md = model.mass_diagonal(state)
    has = (md > 0) & np.isfinite(kd)
    mu = float(np.max(kd[has] / md[has])) * 1e-3 if has.any() else 1.0
    return mu if np.isfinite(mu) and mu > 0 else 1.0


class Runaway:
    """Steps down the potential that never bring the merit below where it stalled, and the net
    turn of each body along them: the sum of the rotation increments of the steps (a vector:
    turns about one axis add up, full turns within a step counted, back and forth cancels).
    ``add`` returns why there is no equilibrium in reach once a body has turned a full turn and
    the potential fell by at least ``DROP_SHARE`` x that turn x the body's unbalanced moment
    where Newton stalled: the model came back to where it was with the load never balanced on
    the way, and the load did work along it (a spin about a neutral axis, along which the load
    does next to none, is no such turn); else "". A translation has no such natural measure
    (the model size says nothing about where a load's law balances): budgets bound it."""

    def __init__(self, model, r):
        self.model = model
        self.turn = np.zeros((model.nb, 3))
        self.drop = 0.0
        # the unbalanced moment on each body where Newton stalled (its residual ``r``)
        self.moment = np.zeros(model.nb)
        if len(model.rot_body):
            self.moment[model.rot_body] = np.linalg.norm(
                np.asarray(r)[model.rot_idx].reshape(-1, 3), axis=1)

    def add(self, step, drop) -> str:
        """A step (tangent increment ``step``, (nq,)) and the potential ``drop`` along it."""
        m = self.model
        rb = m.rot_body
        if m.nb == 0 or not len(rb):
            return ""
        self.turn[rb] += np.asarray(step, float)[m.rot_idx].reshape(-1, 3)
        self.drop += float(drop)
        net = np.linalg.norm(self.turn, axis=1)
        full = (net >= RUNAWAY) & (self.drop >= DROP_SHARE * net * self.moment)
        if not full.any():
            return ""
        k = int(np.argmax(np.where(full, net, -1.0)))
        where = m.coord_info[int(m.body_off[k])].rsplit(" ", 1)[0]
        energy = f"{unit_name(m, 'force')}*{unit_name(m, 'length')}"
        return (f"no equilibrium within reach: {where} turned "
                f"{net[k] / (2 * np.pi):.3g} turns down the potential energy (it fell by "
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
