"""FIM_S per frame (static: one frame; quasi-static: every output time) and the output times.

* Output times: planned from the ``Simulate`` element (:mod:`poise.app.times`).
* FIM_S (:class:`NewtonFrames`): frame 0 = the prologue (redundancy detection, assembly,
  least-squares multipliers) + Newton with the fallback chain; every later frame starts from a predictor
  extrapolated in the tangent space of the previous frame (``Model.local_difference`` /
  ``Model.retract``; linear from 2 frames, quadratic from 3) and runs Newton. A failed step is
  retried with sub-steps (interval halved, down to ``Limits.min_substep_fraction`` of the output
  interval), each sub-step solved from its own predictor; failures are recorded in
  ``iterations/event``.
* Nothing in the scene depends on time (``Model.depends_on_time()``): one solve, the frame is
  replicated and the result says so (attribute ``time_independent``).
* MKEAM requested for a quasi-static run: FIM_S with a warning in the message (deck_format 1.7).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from poise.core.errors import EvaluationError
from poise.solvers import path, singular
from poise.solvers.context import Strategy, prologue, replicate
from poise.solvers.fallback import NO_RECOVERY, recover, solve_frame
from poise.solvers.linalg import SingularMatrix
from poise.solvers.newton import FrameOutcome, branch_newton
from poise.solvers.status import Status
from poise.solvers.stability import classify
from poise.solvers.stable import acceptable, seek_stable

PREDICT_SPACING = 1e-2    # extrapolation nodes closer than this fraction of the step: dropped
MAX_PATH_STEP = 0.25      # predicted motion per step at most (translations / L, rotations in rad)
JUMP_RATIO = 1.0          # correction / predicted step above this: a suspected jump (sub-step)
JUMP_RATIO_SUB = 3.0      # ... on sub-steps <= JUMP_SUB of the interval (a kink in a drive)
JUMP_SUB = 1.0 / 8.0
JUMP_FLOOR = 10.0         # x max_error: a correction this small is never a jump
JUMP_SHRINK = 0.6         # ... nor one that shrank this much when the sub-step was halved
LOCATE_REL = 1e-7         # bisection width, relative to max(1, |t|) (then the fold law)


# ---------------------------------------------------------------------- helpers
def predictor(model, frames, t):
    """State extrapolated to ``t`` from the last (up to 3) ``frames`` (quadratic in the tangent
    space of the last frame; multipliers by the same Lagrange weights). Nodes closer than
    ``PREDICT_SPACING`` of the step to the last one are dropped (the last state alone: no
    extrapolation)."""
    last = frames[-1]
    if len(frames) == 1:
        st = last.copy()
        st.t = t
        return st
    tau = t - last.t
    # previous frames, most recent first; nodes much closer to the last one than the step
    # would amplify their difference without bound (weights ~ tau^2 / spacing^2)
    pts = [p for p in frames[-3:-1][::-1] if abs(p.t - last.t) > PREDICT_SPACING * abs(tau)]
    if not pts:
        st = last.copy()
        st.t = t
        return st
    taus = [p.t - last.t for p in pts]
    if len(pts) == 2 and abs(taus[0] - taus[1]) > PREDICT_SPACING * abs(tau):
        t1, t2 = taus
        w1 = tau * (tau - t2) / (t1 * (t1 - t2))
        w2 = tau * (tau - t1) / (t2 * (t2 - t1))
        ws = [w1, w2]
    else:
        ws = [tau / taus[0]]
        pts = pts[:1]
    dq = sum(w * model.local_difference(last, p) for w, p in zip(ws, pts))
    dl = sum(w * (p.lam - last.lam) for w, p in zip(ws, pts))
    st = model.retract(last, dq, dl)
    st.t = t
    return st


def first_frame(ctx, state):
    """Frame 0 of every Newton-started analysis: the prologue (redundancy, assembly,
    multipliers), then Newton with the fallback chain. Returns ``(state, outcome)``."""
    state, out = prologue(ctx, state)
    if out is not None:
        return state, out
    ctx.start = state.copy()
    state, out = solve_frame(ctx.model, state, ctx.settings, ctx.history, 0, ctx.data)
    if out.strategy != "plain" and ctx.kind == "quasistatic":
        ctx.notes.append(f"frame 0: plain Newton failed; converged with the fallback strategy "
                         f"'{out.strategy}'")
    return state, out


def distance(model, a, b) -> float:
    """Largest body motion from ``a`` to ``b``: CG translations / L, rotation angles [rad]
    (the scale of ``max_error``)."""
    if not model.nb:
        return 0.0
    d = float(np.max(np.linalg.norm(b.pos - a.pos, axis=1))) / model.L
    rb = model.rot_body
    if len(rb):
        f = np.linalg.norm((b.rot[rb] - a.rot[rb]).reshape(len(rb), 9), axis=1)
        d = max(d, float(np.max(2.0 * np.arcsin(np.minimum(f / np.sqrt(8.0), 1.0)))))
    return d


def tangent(model, state, settings, data):
    """The path's direction at ``state``: ``(dq/dt, dlam/dt) = -F_y^{-1} F_t`` (``F_t`` by
    central differences at fixed configuration; ``F_y`` regularised as Newton's), or None."""
    h = 1e-6 * max(1.0, abs(state.t))
    try:
        f = data.factor(data.evaluate(model, state, "jacobian",
                                      eps=float(np.sqrt(settings.stability))).J)
        F = []
        for dt in (h, -h):
            st = state.copy()
            st.t = state.t + dt
            ev = data.evaluate(model, st, "residual")
            F.append(np.concatenate([ev.r, ev.phi]))
        y = f.solve((F[1] - F[0]) / (2.0 * h))
    except (SingularMatrix, EvaluationError, np.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(y)):
        return None
    return y[:model.nq], y[model.nq:]


class BranchPath:
    """The branch being followed in one :func:`fims_step`: the last (up to 3) accepted states,
    predictions from them (a tangent from the first when it is alone) and the continuity test
    of a corrected point against its prediction."""

    def __init__(self, model, frames, settings, data, interval, orient=None, history=None,
                 frame=0):
        self.model, self.settings, self.data = model, settings, data
        self.history, self.frame = history, frame
        self.hist = list(frames[-3:])
        self.interval = interval
        self.floor = JUMP_FLOOR * settings.max_error
        self._tangent = (None, None)     # (state, its tangent or None)
        self.first_order = False         # after a jump: tangent predictions only
        self._flagged = None             # (from time, step, correction) of the last jump
        self._refs = None                # singularity measures of the frames before
        self.probe_iterations = 0
        self.located_from = None         # the last state reached before the bisection
        if orient is None:              # a new branch record: the measures of the states so far
            orient = singular.Orientation(model, data)
            for st in self.hist:
                orient.reference(st)
        self.orient = orient
        self._tested = None              # (state, its orientation matrix): the last tested

    def predict(self, t):
        """``(predicted state at t, known)``: extrapolated from the last accepted states
        (:func:`predictor`), or along the path's tangent at the last one when it is alone or
        after a jump (a kink in a driven motion inside the extrapolation's history
        misleads it at any step size); ``known`` False: no direction was available (the
        prediction is the last state, no distance test)."""
        hist, model = self.hist, self.model
        last = hist[-1]
        if len(hist) > 1 and not self.first_order:
            return predictor(model, hist, t), True
        if self._tangent[0] is not last:
            self._tangent = (last, tangent(model, last, self.settings, self.data))
        v = self._tangent[1]
        st = last.copy() if v is None else model.retract(last, (t - last.t) * v[0],
                                                          (t - last.t) * v[1])
        st.t = t
        return st, v is not None

    def jump(self, pred, st, known, probe=False) -> str:
        """Why ``st`` (corrected from ``pred``) is not on the branch, or ``""``.

        * Its assembly orientation (:class:`~poise.solvers.singular.Orientation`) must be the
          last accepted state's: a prediction that overshot a toggle converges on the mirrored
          branch, however small the correction.
        * The correction may not exceed the predicted step (``JUMP_RATIO``); on sub-steps of
          at most ``JUMP_SUB`` of the interval, ``JUMP_RATIO_SUB`` times the larger of the
          predicted step and the path's speed times the step (a kink in a driven motion
          passes), or it must have shrunk to ``JUMP_SHRINK`` of the correction of the same
          step twice as long (a path from rest: the correction falls as the step squared,
          a jump's stays); never less than ``JUMP_FLOOR`` x ``max_error``. A bisection
          ``probe`` next to the end of a branch, where the path has a square-root shape that
          no extrapolation follows, may also move as far as it went from the last state (and
          gets no return test: it is next to a singular point by construction).
        """
        model, last = self.model, self.hist[-1]
        same, A = self.orient.same(last, st)
        self._tested = (st, A)
        if not same:
            return ("the assembly changed branch (the orientation of its constraints flipped: "
                    "a singular configuration lies between)")
        if not known:
            return "" if probe else self.returns(st)
        corr = distance(model, pred, st)
        step = distance(model, last, pred)
        dt = pred.t - last.t
        prev, self._flagged = self._flagged, (last.t, dt, corr)
        if probe or dt <= JUMP_SUB * self.interval:
            rate = 0.0
            if len(self.hist) > 1 and last.t > self.hist[-2].t:
                rate = distance(model, self.hist[-2], last) / (last.t - self.hist[-2].t)
            allowed = self.floor + JUMP_RATIO_SUB * max(step, rate * dt,
                                                        distance(model, last, st) if probe else 0)
            if prev is not None and prev[0] == last.t and abs(prev[1] - 2.0 * dt) <= 1e-9 * dt:
                allowed = max(allowed, JUMP_SHRINK * prev[2])
        else:
            allowed = self.floor + JUMP_RATIO * step
        if corr <= allowed:
            return "" if probe else self.returns(st)
        self.first_order = True
        return (f"the corrector landed {corr:.3g} from the predicted point, more than the step "
                f"allows ({allowed:.3g}; translations / L, rotations in rad): a jump off the "
                "branch")

    def returns(self, st) -> str:
        """Next to a singular configuration (:meth:`~poise.solvers.singular.Orientation.near`)
        branches meet, and neither the distance nor the orientation tells them apart: the step
        must come back. Newton at the last state's time from ``st`` (at most
        ``Limits.return_max_iter`` iterations) must land on the last state (within ``JUMP_FLOOR`` x
        ``max_error``) when it converges; from the mirrored branch it lands on its mirror."""
        if self.history is None or not self.orient.near():
            return ""
        last = self.hist[-1]
        back = st.copy()
        back.t = last.t
        b, out = branch_newton(self.model, back, self.settings, self.history, self.frame,
                               self.data, min(self.settings.max_num_iter,
                                              self.settings.limits.return_max_iter), "return")
        if not out.ok:          # inconclusive (Newton is slow next to a fold): no verdict
            return ""
        d = distance(self.model, b, last)
        if d <= self.floor:
            return ""
        self.first_order = True
        return (f"stepping back to t={last.t:.9g} from it leads {d:.3g} away from the state "
                "there (next to a singular configuration): another branch")

    def refs(self, frames):
        """Measures of the output frames before the last state reached (regular points of the
        path the singularity measures are compared with), computed once."""
        if self._refs is None:
            near = self.hist[-1]
            self._refs = [singular.measure(self.model, self.data, f)
                          for f in frames[-3:] if f.t < near.t]
        return self._refs

    def near_singular(self, frames) -> bool:
        """Does the last state reached approach a singular configuration (``NEAR``)?"""
        refs = self.refs(frames)
        hist = self.hist
        return bool(refs) and singular.diagnose(
            self.model, self.data, hist[-1], None, refs, hist[-1].t, singular.NEAR) is not None

    def accept(self, st):
        self.hist = (self.hist + [st])[-3:]
        if self._tested is not None and self._tested[0] is st and self._tested[1] is not None:
            self.orient.reference(st, self._tested[1])

    def locate(self, history, frame, t_hi):
        """Bisection of ``(last accepted time, t_hi]`` for where the branch ends, to
        ``LOCATE_REL``. A probe is Newton (at most ``Limits.probe_max_iter`` iterations, continuity
        tested) from the prediction, and when that stops at once or lands off the branch, from
        the last state reached (next to a fold the extrapolation lands where the Jacobian is
        singular, or past a turning point of the drive on the other branch). After the first probe that goes on, one probe at
        ``t_hi`` itself: a branch that merely turned back near a singular point goes on (then
        ``t_lo == t_hi``). Returns ``(t_lo, t_hi, iterations)``; the accepted probes extend the
        branch."""
        self.located_from = self.hist[-1]
        t_lo = self.hist[-1].t
        tol = LOCATE_REL * max(1.0, abs(t_hi))
        its = 0
        t_end, tried_end = t_hi, False
        while t_hi - t_lo > tol:
            t = 0.5 * (t_lo + t_hi)
            if t_lo > self.located_from.t and not tried_end:
                t, tried_end = t_end, True   # once on the way: does the branch go on after all?
            pred, known = self.predict(t)
            last = self.hist[-1].copy()
            last.t = t
            ok = False
            for start in (pred, last):
                st, out = branch_newton(self.model, start, self.settings, history, frame,
                                        self.data, self.settings.limits.probe_max_iter, "locate")
                its += out.iterations
                ok = out.ok and not self.jump(start, st, known and start is pred, probe=True)
                if ok or (not out.ok and out.iterations > 2):   # no second start when Newton
                    break                                       # worked and found nothing
            if not ok:
                t_hi = min(t_hi, t)
                continue
            self.accept(st)
            t_lo = t
        return t_lo, t_hi, its


def fims_step(model, frames, t_target, settings, history, counters, frame, min_dt,
              orient=None):
    """FIM_S from ``frames[-1]`` to ``t_target`` on the same branch, with automatic
    sub-stepping.

    A step whose prediction moves a body more than ``MAX_PATH_STEP`` (a path sampled too
    coarsely may pass a singular configuration and come back on the other branch within one
    output interval), whose Newton fails, or whose corrected point jumped off the branch
    (:meth:`BranchPath.jump`), is halved; after a success the step doubles again (up to what is
    left). When halving reaches ``min_dt``: if the last point reached approaches a singular
    configuration (:func:`~poise.solvers.singular.diagnose`), the end of the branch is located
    by bisection and the frame is ``singular_configuration`` at that time (the state written
    is the last one on the branch); else a persistent jump fails the frame
    (``step_too_small``) and a Newton failure goes to the fallback chain of a static solve
    (:func:`~poise.solvers.fallback.recover`) from the frame's predictor (its result must be on
    the branch too).

    ``orient``: the :class:`~poise.solvers.singular.Orientation` kept across the frames of a
    run (its reference is the last accepted state). Returns ``(state, outcome, n_substeps)``;
    ``frames`` is not modified. The outcome's iterations count every sub-step, probe and
    strategy.
    """
    branch = BranchPath(model, frames, settings, counters, t_target - frames[-1].t, orient,
                   history, frame)
    t_prev = frames[-1].t
    dt = t_target - t_prev
    n_sub = total_it = 0
    max_iter = min(settings.max_num_iter, settings.limits.substep_max_iter)
    ended = False                       # the branch's end was looked for (not singular)
    while True:
        t = t_prev + dt
        if t_target - t < 1e-12 * max(1.0, abs(t_target)):
            t = t_target
        pred, known = branch.predict(t)
        if known and dt > min_dt and distance(model, branch.hist[-1], pred) > MAX_PATH_STEP:
            dt *= 0.5                   # a step the path's shape cannot be trusted over
            n_sub += 1
            continue
        full = n_sub == 0 and t == t_target
        st, out = branch_newton(model, pred, settings, history, frame, counters, max_iter,
                                "newton" if full else "substep")
        total_it += out.iterations
        why = branch.jump(pred, st, known) if out.ok else out.status.value
        if not why:
            branch.accept(st)
            t_prev = t
            if t == t_target:
                out.iterations = total_it
                return st, out, n_sub
            dt = min(2.0 * dt, t_target - t_prev)
            continue
        dt *= 0.5
        n_sub += 1
        history.add(frame, 0, out.imbalance, out.error, np.nan, np.nan,
                    f"step to t={t:.9g} failed ({why}); halving to {dt:.3g}", "substep_retry")
        if not ended and (dt < min_dt or branch.near_singular(frames)):
            ended = True
            end = _branch_end(model, settings, counters, history, frame, branch, frames, t)
            if end is not None:
                st, sing, its = end
                sing.iterations = total_it + its
                sing.counts = {"plain": sing.iterations}
                return st, sing, n_sub
            total_it += branch.probe_iterations
            t_prev = branch.hist[-1].t
        if dt >= min_dt:
            continue
        out.iterations = total_it
        out.counts = {"plain": total_it}
        if out.ok:          # Newton converged, but off the branch, however small the step
            return branch.hist[-1], FrameOutcome(
                Status.STEP_TOO_SMALL, total_it, np.nan, np.nan,
                f"the equilibrium path jumps at t = {t:.6g}: {why}, also on sub-steps of "
                f"{2 * dt:.3g} (a discontinuous load or motion?)", out.counts), n_sub
        if not settings.fallback or out.status in NO_RECOVERY:
            return st, out, n_sub
        history.add(frame, 0, out.imbalance, out.error, np.nan, np.nan,
                    f"step to t={t_target:.9g} failed after {n_sub} halvings; fallback "
                    "chain from the frame's predictor", "substep_retry")
        pred, known = branch.predict(t_target)
        st, out = recover(model, pred, st, out, settings, history, frame, counters)
        why = branch.jump(pred, st, known) if out.ok else ""
        if why:
            out = FrameOutcome(Status.STEP_TOO_SMALL, out.iterations, out.imbalance, out.error,
                               f"the fallback chain's equilibrium at t = {t_target:.6g} is not "
                               f"on the branch: {why}", out.counts, out.strategy)
        return st, out, n_sub


def _branch_end(model, settings, data, history, frame, branch, frames, t_fail):
    """Where a branch that does not go on ends: bisection to ``LOCATE_REL`` from the last
    state reached towards ``t_fail`` and the diagnosis there
    (:func:`~poise.solvers.singular.diagnose` against the output frames before). Returns
    ``(state, SingularOutcome, probe iterations)``, or None (not singular; the probes'
    iterations are in ``branch.probe_iterations``)."""
    refs = branch.refs(frames)
    if not refs:
        return None
    t_lo, t_hi, its = branch.locate(history, frame, t_fail)
    hist = branch.hist
    if t_lo >= t_fail:                  # the branch goes on
        branch.probe_iterations = its
        return None
    info = singular.diagnose(model, data, hist[-1], branch.located_from, refs,
                             0.5 * (t_lo + t_hi))
    if info is None:
        branch.probe_iterations = its
        return None
    if branch.located_from is not hist[-1]:   # the fold's time, closer than probes can reach
        info = replace(info, time=singular.fold_time(model, data, info.kind, branch.located_from,
                                                     hist[-1], t_fail))
    history.add(frame, 0, np.nan, np.nan, np.nan, np.nan, info.message(), "singular")
    return hist[-1], singular.singular_outcome(info, 0), its


# ---------------------------------------------------------------------- strategy
class NewtonFrames(Strategy):
    """FIM_S: Newton with the fallback chain at every output frame (a static analysis is the
    one-frame case); later frames start from a predictor and sub-step on failure
    (:func:`fims_step`)."""

    name = "FIM_S"

    def init(self, ctx, state):
        s = ctx.settings
        if ctx.kind == "static" and s.method == "FIM_D":
            ctx.notes.append("FIM_D falls back to FIM_S for a pure static analysis")
        if ctx.kind == "quasistatic" and s.method == "MKEAM":
            ctx.notes.append("warning: MKEAM does not apply to quasi-static runs; FIM_S used")
        st, out = first_frame(ctx, state)
        if out.ok and s.require_stable:
            st, out = require_stable(ctx, st, out)
        ctx.frames, ctx.outcomes = [st], [out]
        self.k = 1
        if out.ok and ctx.time_independent and len(ctx.times) > 1:
            replicate(ctx)

    def terminate(self, ctx):
        return (len(ctx.frames) == len(ctx.times) or not ctx.outcomes[-1].ok)

    def postprocess(self, ctx):
        if ctx.kind == "quasistatic":
            path.check(ctx, fims_step)
        return None, singular.located_attrs(ctx.outcomes)

    def step(self, ctx):
        k, ts = len(ctx.frames), ctx.times
        min_dt = ctx.settings.limits.min_substep_fraction * (ts[k] - ts[k - 1])
        if getattr(self, "orient", None) is None:
            self.orient = singular.Orientation(ctx.model, ctx.data)
        st, o, nsub = fims_step(ctx.model, ctx.frames, float(ts[k]), ctx.settings, ctx.history,
                                ctx.data, k, min_dt, self.orient)
        if nsub:
            ctx.notes.append(f"frame {k}: {nsub} sub-step halvings")
        if o.strategy != "plain":
            ctx.notes.append(f"frame {k}: converged with the fallback strategy '{o.strategy}'")
        ctx.frames.append(st)
        ctx.outcomes.append(o)
        ctx.report("FIM_S", k + 1, len(ts))


def require_stable(ctx, state, out):
    """``require_stable``: classify the converged point; unstable -> a stable equilibrium
    downhill from the input, else from the unstable point
    (:func:`poise.solvers.stable.seek_stable`)."""
    model, s, active = ctx.model, ctx.settings, ctx.data.active
    info = classify(model, state, active=active)
    ctx.data.classified = (state, info)
    if acceptable(info, s) or info.klass != "unstable":
        return state, out        # judged on the output classification
    st, o, info, note = seek_stable(model, state, s, ctx.history, 0, ctx.data, info,
                                    lambda x: classify(model, x, active=active), ctx.start)
    ctx.data.classified = (st, info)     # also a failed one: its class is reported
    if note:
        ctx.notes.append(note)
    return st, replace(o, iterations=out.iterations + o.iterations)
