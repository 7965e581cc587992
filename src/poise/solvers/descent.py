"""The inertia-controlled Newton descent: down the potential energy to an equilibrium.

:class:`Descent` (a :class:`~poise.solvers.iterate.Solver`; :func:`descend` runs it and the
final polish) shifts the tangent stiffness by the smallest ``sigma`` whose ``L D L^T`` inertia
says the reduced matrix is positive definite, so every step is a descent direction; steps are
limited and backtracked (Armijo) on the potential energy of trials projected onto the
constraints (:mod:`poise.solvers.trials`). The energy never increases; the end point is
Newton-polished. Without a potential energy the trapezoidal work of the applied forces is the
energy change. Used by ``--require-stable`` (:mod:`poise.solvers.stable`) and as MKEAM's
fast continuation (``Relaxation._handover``). Details: docs/mkeam.md.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from poise.core.errors import EvaluationError
from poise.core.wording import plural
from poise.solvers.energy import potential_energy
from poise.solvers.history import Row
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.limits import LIMITS
from poise.solvers.newton import Scales, measures, newton
from poise.solvers.pencil_dense import DENSE_PENCIL, DensePencil
from poise.solvers.stability import AUG_RHO, SparsePencil
from poise.solvers.status import Status
from poise.solvers.steps import step_size
from poise.solvers.trials import Chord, LagrangeTest, Projector, trial_tol, violation_work

STEP_TRANS = 0.4          # x L: largest translation of one descent step
STEP_ROT = 1.0            # rad: largest rotation of one descent step
EXTEND = 2.0              # a shifted full step accepted at once is tried this much longer
SKIP_ZERO_SHIFT = 0.05    # x spectral radius: above, the next step does not try sigma = 0
#: how a descent ends: polished (Newton certified it), at an equilibrium (to be polished), or
#: stalled (no step lowers the energy); out of budget: max_iterations (then polished too)
ENDS = {"polished": Status.CONVERGED, "equilibrium": Status.CONVERGED,
        "stalled": Status.STEP_TOO_SMALL}


def energy_drop(model, a, b, cnt, pa=None):
    """``V(b) - V(a)`` (potential energy, or minus the trapezoidal work of the applied forces
    along the tangent difference when the model has no potential). Returns (dV, V(b))."""
    pb = potential_energy(model, b)
    if pa is None:
        pa = potential_energy(model, a)
    if np.isfinite(pa) and np.isfinite(pb):
        return pb - pa, pb
    dq = model.local_difference(a, b)
    # residual r = -Q + G^T lam: its projection on a constraint-respecting step is -Q . dq
    ra = np.asarray(cnt.evaluate(model, a, "residual", every_row=True).r).ravel()[:model.nq]
    rb = np.asarray(cnt.evaluate(model, b, "residual", every_row=True).r).ravel()[:model.nq]
    return 0.5 * float((ra + rb) @ dq), np.nan


def _ic_step(model, state, cnt, sigma, like=None):
    """One inertia-controlled Newton direction at ``state``: ``(K_s + sigma D) dq + G^T y = -r``,
    ``G dq = -phi`` in the equilibrated length coordinates of the pencil (sparse, or
    :class:`~poise.solvers.pencil_dense.DensePencil` for small models; ``D`` its diagonal
    metric), with the
    smallest ``sigma`` (0, else from a quarter of the last step's, grown by 8; 0 is not tried
    after a shift above ``SKIP_ZERO_SHIFT``) whose KKT inertia is ``(nq, m, 0)``: the reduced
    matrix is positive definite and ``dq`` a descent direction of the potential energy.
    ``like``: the previous step's pencil (its elimination order and scaling are reused; when
    no valid factorisation is found with them, a fresh pencil is tried).
    Returns ``(dq, sigma, ev, dlam, chord)``: ``dq`` None when no valid factorisation was
    found; ``chord``: the factorised step (:class:`~poise.solvers.trials.Chord`) the
    line-search projections reuse."""
    ev = cnt.evaluate(model, state, "jacobian")
    pencil = DensePencil if model.nq + model.nc <= DENSE_PENCIL else SparsePencil
    P = pencil(model, ev.J, active=cnt.active, like=like)
    out = _ic_solve(model, P, ev, cnt, sigma)
    if out[0] is None and P.reused:
        out = _ic_solve(model, pencil(model, ev.J, active=cnt.active), ev, cnt, sigma)
    return out


def _ic_solve(model, P, ev, cnt, sigma):
    nq, m = P.nq, P.m
    r = np.asarray(ev.r, float)[:nq]
    f = -(P.dq / P.d) * r
    g = -P.dl * np.asarray(ev.phi, float)[P.rows] if m else np.zeros(0)
    scale = P.eps / 1e-8                      # spectral radius estimate of Kt
    # plain Newton (sigma = 0) whenever the inertia allows; after a step that needed a large
    # shift, start from a quarter of it (the zero-shift factorisation would almost surely fail)
    k0 = 1 if sigma > SKIP_ZERO_SHIFT * scale else 0
    sig = max(sigma / 4.0, 1e-6 * scale) if k0 else 0.0
    for k in range(k0, LIMITS.shift_tries):
        for rho in AUG_RHO:
            F = cnt.factor((-sig, rho), lambda at: P.ldl(*at))      # the pencil at (shift, rho)
            if F.ok and np.all(np.abs(F.pivots) > 1e-14 * scale):
                break
        if F.ok and F.n_negative == m and np.all(np.abs(F.pivots) > 1e-14 * scale):
            b = np.concatenate([f + rho * (P.Gt.T @ g), g]) if m else f
            sol = F.solve(b)
            if np.all(np.isfinite(sol)):
                dlam = np.zeros(model.nc)
                dlam[P.rows] = P.dl * sol[nq:]
                return sol[:nq] * P.dq / P.d, sig, ev, dlam, Chord(P, F, rho)
        sig = max(sigma / 4.0, 1e-6 * scale) if k == 0 else 8.0 * sig
    return None, sig, ev, None, None


@dataclass(frozen=True)
class Descending:
    """Where a :class:`Descent` stands: the point, its potential energy, the shift
    ``sigma``, steps taken (descent steps and polish iterations), polishes failed, the first
    trial's length, the last step's pencil, line searches failed in a row, the last
    imbalance; ``stop``: ``"equilibrium"`` (polish it), ``"stalled"`` (``why`` says why) or
    ``"polished"`` (``outcome``: the polish's)."""

    state: Any
    pe: float
    sigma: float = 0.0
    steps: int = 0
    polish_fail: int = 0
    alpha0: float = 1.0
    like: Any = None
    failed: int = 0
    imb: float = np.nan
    stop: str = ""
    why: tuple = ()
    outcome: Any = None


class Descent(Solver):
    """The inertia-controlled Newton descent (:func:`descend`): one step per
    :func:`_ic_step` direction, its line search and row, and the Newton polish once a full
    unshifted step was taken. Budget: steps (polish iterations count). Result: the last
    :class:`Descending`."""

    def __init__(self, model, settings, frame, cnt):
        self.model, self.settings, self.frame, self.cnt = model, settings, frame, cnt
        self.sc = Scales(model, settings)

    def init(self, state, pe):
        return Descending(state, potential_energy(self.model, state) if pe is None else pe)

    def terminate(self, s):
        return bool(s.stop), ENDS.get(s.stop)

    def step(self, s, left):
        model, cnt, frame = self.model, self.cnt, self.frame
        state, pe = s.state, s.pe
        try:
            dq, sigma, ev, dlam, chord = _ic_step(model, state, cnt, s.sigma, s.like)
        except EvaluationError as e:
            return Next(replace(s, stop="stalled", why=(
                f"an element could not be evaluated during the descent ({e})",)), 0)
        steps = s.steps + 1
        imb, cerr, zinf, worst = measures(model, ev, self.sc)
        if dq is None:
            row = Row(frame, steps, imb, cerr, np.nan, np.nan, worst,
                      "stable-descent: no valid factorisation", pos=state.pos, rot=state.rot)
            return Next(replace(s, steps=steps, sigma=sigma, imb=imb, stop="stalled",
                                why=(_stalled(imb, sigma, s.failed),)), 1, (row,))
        s = replace(s, steps=steps, sigma=sigma, imb=imb, like=chord.P)
        # step limits (a trust region on the linearisation of the constraints)
        rot = model.q_kind == 1
        big = max(float(np.max(np.abs(dq[rot]), initial=0.0)) / STEP_ROT,
                  float(np.max(np.abs(dq[~rot]), initial=0.0)) / (STEP_TRANS * model.L), 1.0)
        dq = dq / big
        slope = float(np.asarray(ev.r, float)[:model.nq] @ dq)
        proj = Projector(model, cnt, chord)
        work = violation_work(model, ev, state)
        lagrange = LagrangeTest(model, ev, state, cnt) if np.isfinite(pe) else None
        alpha = s.alpha0
        accepted = None
        for _ in range(self.settings.limits.descent_backtrack):
            try:
                x = model.retract(state, alpha * dq)
                x, ok = proj(x, trial_tol(alpha, slope, work))   # not projected: shorter
                if ok:
                    dv, pe_x = energy_drop(model, state, x, cnt, pe)
                    tol = 1e-13 * max(abs(pe) if np.isfinite(pe) else 0.0, 1.0)
                    goal = 1e-4 * alpha * min(slope, 0.0) + tol
                    if dv + proj.err * work <= goal or (
                            lagrange is not None and
                            lagrange.decrease(dv, proj, state.lam + min(alpha, 1.0) * dlam)
                            <= goal):
                        accepted = (x, pe_x if np.isfinite(pe_x) else pe + dv)
                        break
            except EvaluationError:
                pass
            alpha *= 0.5
        if accepted is not None and alpha == 1.0 and sigma > 0.0 and big == 1.0:
            alpha, accepted = _extend(model, state, dq, proj, cnt, pe, slope, accepted, work)
        row = Row(frame, steps, imb, cerr, step_size(alpha * dq, self.sc),
                  alpha if accepted else np.nan, worst, f"stable-descent sigma={sigma:.3g}",
                  pos=state.pos, rot=state.rot)
        if zinf <= 1.0 and (accepted is None or
                            not accepted[1] < pe - 1e-13 * max(abs(pe), 1.0)):
            # at an equilibrium already (no step lowers the energy either): the polish
            # certifies it, the caller classifies
            return Next(replace(s, stop="equilibrium"), 1, (row,))
        if accepted is None:
            failed = s.failed + 1
            sigma = max(8.0 * sigma, 1.0) if sigma > 0 else 0.0
            if sigma == 0.0:
                return Next(replace(s, sigma=sigma, failed=failed, stop="stalled",
                                    why=(_stalled(imb, sigma, failed),)), 1, (row,))
            return Next(replace(s, sigma=sigma, failed=failed), 1, (row,))
        state, pe = accepted
        state.lam = state.lam + min(alpha, 1.0) * dlam     # the KKT step's multiplier update
        s = replace(s, state=state, pe=pe, failed=0, alpha0=min(1.0, 2.0 * alpha))
        if not (sigma == 0.0 and alpha == 1.0 and big == 1.0
                and s.polish_fail < self.settings.limits.polish_fails):
            return Next(s, 1, (row,))
        rows = [row]
        st, o = self.polish(state, rows)
        s = replace(s, steps=s.steps + o.iterations)
        if o.ok:
            dv, _ = energy_drop(model, state, st, cnt, pe)
            if dv <= 1e-9 * max(abs(pe) if np.isfinite(pe) else 0.0, 1.0):
                return Next(replace(s, state=st, pe=pe + dv, stop="polished", outcome=o),
                            1 + o.iterations, tuple(rows))
        return Next(replace(s, polish_fail=s.polish_fail + 1), 1 + o.iterations, tuple(rows))

    def polish(self, state, history):
        """Newton (no fallback chain) from ``state``, its rows to ``history``."""
        s = self.settings
        return newton(self.model, state, replace(s, fallback=False), history, self.frame,
                      self.cnt, max_iter=min(s.max_num_iter, s.limits.polish_max_iter),
                      event="stable-polish")

    def postprocess(self, s, status, used):
        return s


def descend(model, state, settings, history, frame, cnt, budget, pe=None, why=None):
    """Inertia-controlled Newton from ``state`` down to an equilibrium (:class:`Descent`:
    :func:`_ic_step` directions limited to ``STEP_ROT`` rad / ``STEP_TRANS`` x L, an Armijo
    backtracking on the potential energy of the trial projected onto the constraints by
    :func:`project`, starting at twice the last accepted step; the Newton polish once a full
    step with ``sigma = 0`` was taken, its point kept only if its energy is not higher), then,
    unless it stalled or was polished, the Newton polish of where it stopped. The potential
    energy never increases. Returns ``(state, outcome or None, pe, steps)``; on None, the
    reason is appended to the list ``why`` when one is given (:func:`_stalled`)."""
    why = [] if why is None else why
    solver = Descent(model, settings, frame, cnt)
    d = iterate(solver, budget, history, state, pe)
    why.extend(d.why)
    if d.stop == "polished":
        return d.state, d.outcome, d.pe, d.steps
    if d.stop == "stalled":
        return d.state, None, d.pe, d.steps
    st, o = solver.polish(d.state, history)
    steps = d.steps + o.iterations
    if o.ok:
        return st, o, d.pe, steps
    why.append(f"not at an equilibrium after {plural(steps, 'descent step')} (imbalance "
               f"{d.imb:.3g}; budget {budget}), and Newton's polish from there failed "
               f"({o.message})" if steps >= budget else
               f"the descent stopped at imbalance {d.imb:.3g} and Newton's polish from there "
               f"failed ({o.message})")
    return d.state, None, d.pe, steps


def _stalled(imb, sigma, failed):
    """Why the descent stopped without a step (not the budget: it was not used up)."""
    if failed:
        return (f"the descent stalled at imbalance {imb:.3g}: no trial along "
                f"{plural(failed, 'successively shifted direction')} (shift up to {sigma:.3g}) "
                "lowered the potential energy measurably")
    return (f"the descent stalled at imbalance {imb:.3g}: no shift of the stiffness (up to "
            f"{sigma:.3g}) gave a positive definite reduced matrix with a reliable "
            "factorisation")


def _extend(model, state, dq, proj, cnt, pe, slope, accepted, work):
    """A full shifted step that was accepted at once and stays inside the step limits: the
    shift made the quadratic model conservative, so try ``EXTEND`` x longer steps along it (up
    to the limits) while each lowers the energy more. Returns ``(alpha, (state, pe))``."""
    rot = model.q_kind == 1
    room = 1.0 / max(float(np.max(np.abs(dq[rot]), initial=0.0)) / STEP_ROT,
                     float(np.max(np.abs(dq[~rot]), initial=0.0)) / (STEP_TRANS * model.L),
                     1e-300)
    alpha, best = 1.0, accepted
    for _ in range(LIMITS.max_extend):
        a = min(EXTEND * alpha, room)
        if a <= alpha * 1.01:
            break
        try:
            x, ok = proj(model.retract(state, a * dq), trial_tol(a, slope, work))
            if not ok:
                break
            dv, pe_x = energy_drop(model, state, x, cnt, pe)
        except EvaluationError:
            break
        pe_new = pe_x if np.isfinite(pe_x) else pe + dv
        if not (pe_new + proj.err * work < best[1]
                and dv + proj.err * work <= 1e-4 * a * min(slope, 0.0)):
            break
        alpha, best = a, (x, pe_new)
    return alpha, best
