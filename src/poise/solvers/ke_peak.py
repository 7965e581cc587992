"""One MKEAM iteration: RATTLE integration from rest up to the first kinetic-energy peak.

:class:`KeIteration` integrates the conservative constrained dynamics from rest
(:func:`~poise.solvers.rattle.rattle_step`) with a step from the stiffness (``STEPS_PER_PERIOD``
per fastest period), the motion (``MAX_TRANS_STEP`` x L, ``MAX_ROT_STEP`` rad per step) and
the energy error (``ENERGY_TOL``, halving); once the power of the forces turns negative the
peak is bracketed and located by :class:`PeakSearch`. Both are :class:`~poise.solvers.iterate.
Solver` runs whose budget is integrator steps. The method: docs/mkeam.md.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.limits import LIMITS
from poise.solvers.rattle import CONSTRAINT_TOL, RattlePoint, rattle_step
from poise.solvers.status import Status

STEPS_PER_PERIOD = 20.0
MAX_TRANS_STEP = 0.1         # x L per integration step
MAX_ROT_STEP = 0.1           # rad per integration step
ENERGY_TOL = 1e-3            # relative energy error per step
NOISE_FACTOR = 10.0          # energy resolution: x work over the constraint tolerance
MAX_TRAVEL = 1e4             # x L: an iterate farther than this from the start is divergence
PEAK_TOL = 1e-3              # bracket of the peak relative to the step


@dataclass(frozen=True)
class Flight:
    """Where a :class:`KeIteration` stands: the last accepted point ``a``, the step ``h``,
    integrator steps taken, the energy scale and resolution seen so far, ``retry`` (the last
    step was rejected: the next one is half as long), and once it ended the point it ends at
    and why (``message``, empty on a peak or at rest)."""

    a: RattlePoint
    h: float
    steps: int = 0
    escale: float = 0.0
    noise: float = 0.0
    retry: bool = False
    end: Any = None
    message: str = ""
    done: Status | None = None


@dataclass(frozen=True)
class Landing:
    """The result of a KE iteration: its end ``point``, integrator ``steps``, the step size
    ``h`` reached, ``message`` (non-empty: why it failed, or that no force acts) and
    ``status`` (``converged``: a peak, at rest, or no force; ``max_iterations``: still
    accelerating when its budget ran out; else a failure: ``nonfinite``, ``diverged``,
    ``step_too_small``)."""

    point: RattlePoint
    steps: int
    h: float
    message: str
    status: Status

    @property
    def failed(self) -> bool:
        return self.status in (Status.NONFINITE, Status.DIVERGED, Status.STEP_TOO_SMALL)


class KeIteration(Solver):
    """Integrate from rest at a state until the first kinetic-energy peak (or at rest, or
    out of budget: then the iteration restarts where it stands, still descending: a mode so
    soft that its peak is out of reach is left to the Newton polish). ``origin``: the
    positions the run started from (a body farther than ``MAX_TRAVEL`` x L is divergence).
    Budget: integrator steps (rejected ones too). Result: :class:`Landing`."""

    def __init__(self, dyn, origin):
        self.dyn, self.model, self.origin = dyn, dyn.m, origin

    def init(self, state, h0):
        a = RattlePoint(self.dyn, state, np.zeros(self.model.nq), 0.0)
        h = min(h0, self.h_limit(a)) if np.isfinite(h0) else self.h_limit(a)
        if not np.isfinite(h):
            return Flight(a, h, end=a, message="no force acts (already at rest in equilibrium)",
                          done=Status.CONVERGED)
        return Flight(a, h, noise=self.energy_noise(a))

    def terminate(self, s):
        return s.done is not None, s.done

    def step(self, s, left):
        a, h = s.a, s.h
        if not s.retry:
            hl = self.h_limit(a)
            h = min(2.0 * h, hl) if np.isfinite(hl) else 2.0 * h
        b = rattle_step(self.dyn, a, h)
        s = replace(s, steps=s.steps + 1)
        if b is not None:
            work = 0.5 * h * (a.power + b.power)
            err = abs(b.ke - a.ke - work)
            s = replace(s, escale=max(s.escale, a.ke, b.ke, abs(work)),
                        noise=max(s.noise, self.energy_noise(b)))
            if err <= max(ENERGY_TOL * s.escale, s.noise) or h < 1e-14 * max(1.0, a.t):
                return self._accepted(replace(s, h=h, retry=False), b, left - 1)
        h *= 0.5
        if h < 1e-300:
            return Next(replace(s, h=h, end=a, message="integration step became too small",
                                done=Status.STEP_TOO_SMALL))
        return Next(replace(s, h=h, retry=True))

    def _accepted(self, s, b, left):
        """After the accepted step to ``b`` (``left`` steps of budget remain)."""
        a = s.a
        bad, status = self.absurd(b)
        if bad:
            return Next(replace(s, end=b, message=bad, done=status))
        if s.steps >= LIMITS.rest_steps and s.escale <= s.noise:
            return Next(replace(s, end=b, done=Status.CONVERGED))   # at rest (resolution)
        if b.power <= 0.0:
            if a.power <= 0.0:                 # never accelerated: at rest already
                return Next(replace(s, end=a if a.ke >= b.ke else b, done=Status.CONVERGED))
            peak, n = iterate(PeakSearch(self.dyn, a, b, s.h),
                              min(LIMITS.peak_search_steps, left), (), b)
            return Next(replace(s, steps=s.steps + n, end=peak, done=Status.CONVERGED), 1 + n)
        return Next(replace(s, a=b))

    def postprocess(self, s, status, used):
        end = s.a if s.end is None else s.end
        return Landing(end, used, s.h, s.message, status)

    def h_limit(self, a: RattlePoint):
        """Largest step at ``a``: ``STEPS_PER_PERIOD`` per period of the fastest mode (a
        Gershgorin bound of the largest eigenvalue of ``M^-1/2 K M^-1/2``), and the motion
        limits per step for the present velocity and acceleration."""
        m, dyn = self.model, self.dyn
        md = m.mass_diagonal(a.state)
        if len(dyn.x_idx):
            md[dyn.x_idx] = dyn.extra_mass(a.state)
        d = np.where(md > 0, 1.0 / np.sqrt(np.where(md > 0, md, 1.0)), 0.0)   # scalars: no mass
        K = a.K
        if sp.issparse(K):
            rs = np.asarray(abs(K) @ d).ravel() * d
        else:
            rs = (np.abs(K) @ d) * d
        w2 = float(np.max(rs)) if m.nq else 0.0
        h = np.inf
        if w2 > 0:
            h = 2 * np.pi / np.sqrt(w2) / STEPS_PER_PERIOD
        acc = a.Minv @ a.Q
        lim = np.where(m.q_kind == 1, MAX_ROT_STEP, MAX_TRANS_STEP * m.L)
        vel = np.abs(a.v)
        with np.errstate(divide="ignore", invalid="ignore"):
            hv = np.where(vel > 0, lim / vel, np.inf)
            ha = np.where(np.abs(acc) > 0, np.sqrt(2 * lim / np.abs(acc)), np.inf)
        return float(min(h, hv.min(initial=np.inf), ha.min(initial=np.inf)))

    def energy_noise(self, a):
        """Energy the integrator cannot resolve at ``a``: the work of the applied forces over
        the position-constraint tolerance of a step (``CONSTRAINT_TOL`` x L per translation,
        x 1 rad per rotation), times ``NOISE_FACTOR``. Energy errors below it are accepted
        (halving the step does not reduce them), and an iteration whose energies all stay
        below it is at rest as far as the integration can tell."""
        m = self.model
        ql = np.where(m.q_kind == 0, m.L, 1.0)
        return NOISE_FACTOR * CONSTRAINT_TOL * float(np.sum(np.abs(a.Q) * ql))

    def absurd(self, b):
        """Why the integrated point ``b`` cannot be a step towards an equilibrium, and the
        status that says so (``("", None)`` if it can): non-finite energy or pose, or a body
        farther than ``MAX_TRAVEL * L`` from the start."""
        m = self.model
        if not (np.isfinite(b.ke) and np.all(np.isfinite(b.state.pos))
                and np.all(np.isfinite(b.state.rot))):
            return "the integration produced a non-finite state (NaN/Inf)", Status.NONFINITE
        if m.nb and float(np.max(np.abs(b.state.pos - self.origin))) > MAX_TRAVEL * m.L:
            return (f"a body moved more than {MAX_TRAVEL:g} L = {MAX_TRAVEL * m.L:.3g} from the "
                    "input configuration (nothing holds it: no equilibrium within reach)",
                    Status.DIVERGED)
        return "", None


@dataclass(frozen=True)
class Bracket:
    """Where a :class:`PeakSearch` stands: the bracket ``[lo, hi]`` of step sizes from ``a``
    with the power at both ends, the best point so far, the side the last trial fell on."""

    lo: float
    hi: float
    plo: float
    phi: float
    best: RattlePoint
    side: int = 0
    stop: bool = False


class PeakSearch(Solver):
    """The kinetic-energy peak between the accepted point ``a`` (power > 0) and the step
    ``h`` later ``b`` (power <= 0): regula falsi (Illinois) on the power over the step size,
    each trial a RATTLE step from ``a``, until the bracket is ``PEAK_TOL`` x h, the power
    vanishes or a trial fails. Budget: RATTLE steps. Result: ``(best point, steps)``."""

    def __init__(self, dyn, a, b, h):
        self.dyn, self.a, self.b, self.h = dyn, a, b, h

    def init(self, best):
        return Bracket(0.0, self.h, self.a.power, self.b.power, best)

    def terminate(self, s):
        done = s.stop or not (s.hi - s.lo > PEAK_TOL * self.h)
        return done, Status.CONVERGED if done else None

    def step(self, s, left):
        lo, hi, plo, phi_ = s.lo, s.hi, s.plo, s.phi
        tau = (lo * phi_ - hi * plo) / (phi_ - plo)
        if not (lo < tau < hi):
            tau = 0.5 * (lo + hi)
        c = rattle_step(self.dyn, self.a, tau)
        if c is None:
            return Next(replace(s, stop=True))
        best = c if c.ke >= s.best.ke or c.power > 0 else s.best
        side = s.side
        if c.power > 0:
            lo, plo = tau, c.power
            if side == 1:
                phi_ *= 0.5
            side = 1
        else:
            hi, phi_ = tau, c.power
            if side == -1:
                plo *= 0.5
            side = -1
        if abs(c.power) <= 1e-12 * max(abs(self.a.power), abs(self.b.power)):
            return Next(replace(s, best=c, stop=True))
        return Next(Bracket(lo, hi, plo, phi_, best, side))

    def postprocess(self, s, status, used):
        return s.best, used
