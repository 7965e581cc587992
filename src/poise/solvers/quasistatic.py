"""FIM_S per frame (static: one frame; quasi-static: every output time) and its sub-stepping.

* Output times: planned from the ``Simulate`` element (:mod:`poise.app.times`).
* FIM_S (:class:`NewtonFrames`): frame 0 = the prologue (redundancy detection, assembly,
  least-squares multipliers) + Newton with the fallback chain; every later frame starts from a
  predictor extrapolated in the tangent space of the previous frame
  (:class:`~poise.solvers.branch.BranchPath`) and runs Newton. A failed step is retried with
  sub-steps (:class:`SubStepping`: interval halved, down to ``Limits.min_substep_fraction`` of
  the output interval), each sub-step solved from its own predictor; failures are recorded in
  ``iterations/event``.
* Nothing in the scene depends on time (``Model.depends_on_time()``): one solve, the frame is
  replicated and the result says so (attribute ``time_independent``).
* MKEAM requested for a quasi-static run: FIM_S with a warning in the message (deck_format 1.7).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.solvers import path, singular
from poise.solvers.branch import MAX_PATH_STEP, BranchPath, distance
from poise.solvers.context import AnalysisSolver, Finished, begin, replicated
from poise.solvers.fallback import NO_RECOVERY, recover, solve_frame
from poise.solvers.history import Row
from poise.solvers.iterate import Next, Solver, evolve, iterate
from poise.solvers.newton import FrameOutcome, branch_newton
from poise.solvers.status import Status
from poise.solvers.stability import classify
from poise.solvers.stable import acceptable, seek_stable


def first_frame(env, a, state):
    """Frame 0 of every Newton-started analysis: :func:`~poise.solvers.context.begin`
    (redundancy, assembly, multipliers), then Newton with the fallback chain. Returns
    ``(analysis, state, outcome)``."""
    a, state, out = begin(env, a, state)
    if out is not None:
        return a, state, out
    a = evolve(a, start=state.copy())
    state, out = solve_frame(env.model, state, env.settings, env.history, 0, env.data)
    if out.strategy != "plain" and env.kind == "quasistatic":
        a = a.noted(f"frame 0: plain Newton failed; converged with the fallback strategy "
                    f"'{out.strategy}'")
    return a, state, out


@dataclass(frozen=True)
class _Stepping:
    """:class:`SubStepping`'s state. ``phase``: ``step`` (a sub-step), ``end`` (look for the
    end of the branch), ``fail`` (no smaller sub-step), ``recover`` (the fallback chain);
    ``t`` / ``st`` / ``out`` / ``why``: the last failed sub-step; ``result``: ``(state,
    outcome)`` once decided. ``branch``: the branch record (its accepted states and their
    orientation; :class:`~poise.solvers.branch.BranchPath`, the run's working record)."""

    branch: BranchPath
    t_prev: float
    dt: float
    n_sub: int = 0
    total_it: int = 0
    ended: bool = False          # the branch's end was looked for (not singular)
    phase: str = "step"
    t: float = np.nan
    st: object = None
    out: FrameOutcome | None = None
    why: str = ""
    result: tuple | None = None


class SubStepping(Solver[_Stepping]):
    """:func:`fims_step` as a :class:`~poise.solvers.iterate.Solver`: one step is one sub-step
    (or one decision after a failed one); the rows of failed sub-steps and of a located
    singular configuration are returned to the loop, after those the Newton runs of the step
    appended (their own loops). The budget (``Limits.max_substeps``) is never reached by a
    step that sub-steps as designed; reached, the frame fails ``step_too_small``."""

    out_of_budget = Status.STEP_TOO_SMALL

    def __init__(self, model, frames, t_target, settings, history, data, frame, min_dt):
        self.model, self.frames, self.t_target = model, frames, t_target
        self.settings, self.history, self.data = settings, history, data
        self.frame, self.min_dt = frame, min_dt
        self.max_iter = min(settings.max_num_iter, settings.limits.substep_max_iter)

    def init(self, orient):
        frames = self.frames
        branch = BranchPath(self.model, frames, self.settings, self.data,
                            self.t_target - frames[-1].t, orient, self.history, self.frame)
        return _Stepping(branch, frames[-1].t, self.t_target - frames[-1].t)

    def terminate(self, s):
        return (True, s.result[1].status) if s.result is not None else (False, None)

    def postprocess(self, s, status, used):
        if s.result is not None:
            return (*s.result, s.n_sub)
        return s.branch.hist[-1], FrameOutcome(
            Status.STEP_TOO_SMALL, s.total_it, np.nan, np.nan,
            f"no sub-step reached t = {self.t_target:.6g} within {used} sub-steps",
            {"plain": s.total_it}), s.n_sub

    def step(self, s, left):
        return getattr(self, "_" + s.phase)(s)

    def _step(self, s):
        model, t_target, branch = self.model, self.t_target, s.branch
        t = s.t_prev + s.dt
        if t_target - t < 1e-12 * max(1.0, abs(t_target)):
            t = t_target
        pred, known = branch.predict(t)
        if known and s.dt > self.min_dt and distance(model, branch.hist[-1], pred) > MAX_PATH_STEP:
            # a step the path's shape cannot be trusted over
            return Next(evolve(s, dt=s.dt * 0.5, n_sub=s.n_sub + 1))
        full = s.n_sub == 0 and t == t_target
        st, out = branch_newton(model, pred, self.settings, self.history, self.frame, self.data,
                                self.max_iter, "newton" if full else "substep")
        total = s.total_it + out.iterations
        why = branch.jump(pred, st, known) if out.ok else out.status.value
        if not why:
            branch.accept(st)
            if t == t_target:
                return Next(evolve(s, total_it=total,
                                   result=(st, evolve(out, iterations=total))))
            return Next(evolve(s, total_it=total, t_prev=t, dt=min(2.0 * s.dt, t_target - t)))
        dt = s.dt * 0.5
        row = Row(self.frame, 0, out.imbalance, out.error, np.nan, np.nan,
                  f"step to t={t:.9g} failed ({why}); halving to {dt:.3g}", "substep_retry")
        s = evolve(s, dt=dt, n_sub=s.n_sub + 1, total_it=total, t=t, st=st, out=out, why=why)
        if not s.ended and (dt < self.min_dt or branch.near_singular(self.frames)):
            return Next(evolve(s, phase="end"), 1, (row,))
        return Next(evolve(s, phase="step" if dt >= self.min_dt else "fail"), 1, (row,))

    def _end(self, s):
        """Where the branch ends (:func:`branch_end`): a located singular configuration ends
        the step; else on (or to ``fail``)."""
        s = evolve(s, ended=True)
        end = branch_end(self.model, self.data, self.history, self.frame, s.branch,
                         self.frames, s.t)
        if end is not None:
            st, sing, its, row = end
            n = s.total_it + its
            return Next(evolve(s, result=(st, evolve(sing, iterations=n, counts={"plain": n}))),
                        0, (row,))
        s = evolve(s, total_it=s.total_it + s.branch.probe_iterations,
                   t_prev=s.branch.hist[-1].t)
        return Next(evolve(s, phase="step" if s.dt >= self.min_dt else "fail"), 0)

    def _fail(self, s):
        """No smaller sub-step: a jump fails the frame; a Newton failure goes to the fallback
        chain (``recover``) unless it cannot help."""
        out = evolve(s.out, iterations=s.total_it, counts={"plain": s.total_it})
        if out.ok:          # Newton converged, but off the branch, however small the step
            return Next(evolve(s, result=(s.branch.hist[-1], FrameOutcome(
                Status.STEP_TOO_SMALL, s.total_it, np.nan, np.nan,
                f"the equilibrium path jumps at t = {s.t:.6g}: {s.why}, also on sub-steps of "
                f"{2 * s.dt:.3g} (a discontinuous load or motion?)", out.counts))), 0)
        if not self.settings.fallback or out.status in NO_RECOVERY:
            return Next(evolve(s, result=(s.st, out)), 0)
        row = Row(self.frame, 0, out.imbalance, out.error, np.nan, np.nan,
                  f"step to t={self.t_target:.9g} failed after {s.n_sub} halvings; fallback "
                  "chain from the frame's predictor", "substep_retry")
        return Next(evolve(s, out=out, phase="recover"), 0, (row,))

    def _recover(self, s):
        pred, known = s.branch.predict(self.t_target)
        st, out = recover(self.model, pred, s.st, s.out, self.settings, self.history,
                          self.frame, self.data)
        why = s.branch.jump(pred, st, known) if out.ok else ""
        if why:
            out = FrameOutcome(Status.STEP_TOO_SMALL, out.iterations, out.imbalance, out.error,
                               f"the fallback chain's equilibrium at t = {self.t_target:.6g} is "
                               f"not on the branch: {why}", out.counts, out.strategy)
        return Next(evolve(s, result=(st, out)), 0)


def fims_step(model, frames, t_target, settings, history, counters, frame, min_dt,
              orient=None):
    """FIM_S from ``frames[-1]`` to ``t_target`` on the same branch, with automatic
    sub-stepping (:class:`SubStepping` run by the one loop).

    A step whose prediction moves a body more than ``MAX_PATH_STEP`` (a path sampled too
    coarsely may pass a singular configuration and come back on the other branch within one
    output interval), whose Newton fails, or whose corrected point jumped off the branch
    (:meth:`~poise.solvers.branch.BranchPath.jump`), is halved; after a success the step
    doubles again (up to what is left). When halving reaches ``min_dt``: if the last point
    reached approaches a singular configuration (:func:`~poise.solvers.singular.diagnose`),
    the end of the branch is located by bisection and the frame is ``singular_configuration``
    at that time (the state written is the last one on the branch); else a persistent jump
    fails the frame (``step_too_small``) and a Newton failure goes to the fallback chain of a
    static solve (:func:`~poise.solvers.fallback.recover`) from the frame's predictor (its
    result must be on the branch too).

    ``orient``: the :class:`~poise.solvers.singular.Orientation` kept across the frames of a
    run (its reference is the last accepted state). Returns ``(state, outcome, n_substeps)``;
    ``frames`` is not modified. The outcome's iterations count every sub-step, probe and
    strategy.
    """
    return iterate(SubStepping(model, frames, t_target, settings, history, counters, frame,
                               min_dt), settings.limits.max_substeps, history, orient)


def branch_end(model, data, history, frame, branch, frames, t_fail):
    """Where a branch that does not go on ends: bisection to ``LOCATE_REL`` from the last
    state reached towards ``t_fail`` and the diagnosis there
    (:func:`~poise.solvers.singular.diagnose` against the output frames before). Returns
    ``(state, SingularOutcome, probe iterations, its singular row)``, or None (not singular;
    the probes' iterations are in ``branch.probe_iterations``)."""
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
        info = evolve(info, time=singular.fold_time(model, data, info.kind, branch.located_from,
                                                    hist[-1], t_fail))
    row = Row(frame, 0, np.nan, np.nan, np.nan, np.nan, info.message(), "singular")
    return hist[-1], singular.singular_outcome(info, 0), its, row


# ---------------------------------------------------------------------- strategy
@dataclass(frozen=True)
class _Fims:
    """:class:`NewtonFrames`' own state: the assembly orientation kept across the frames of a
    run (created with the first continuation step) and whether the path check ran."""

    orient: singular.Orientation | None = None
    checked: bool = False


class NewtonFrames(AnalysisSolver):
    """FIM_S: Newton with the fallback chain at every output frame (a static analysis is the
    one-frame case); later frames start from a predictor and sub-step on failure
    (:func:`fims_step`). A quasi-static run ends with the path check
    (:func:`poise.solvers.path.check`), one more step."""

    name = "FIM_S"

    def start(self, a, state):
        env, s = self.env, self.env.settings
        if env.kind == "static" and s.method == "FIM_D":
            a = a.noted("FIM_D falls back to FIM_S for a pure static analysis")
        if env.kind == "quasistatic" and s.method == "MKEAM":
            a = a.noted("warning: MKEAM does not apply to quasi-static runs; FIM_S used")
        a, st, out = first_frame(env, a, state)
        if out.ok and s.require_stable:
            a, st, out = require_stable(env, a, st, out)
        a = evolve(a.added(st, out), method=_Fims(checked=env.kind != "quasistatic"))
        if out.ok and a.time_independent and len(a.times) > 1:
            a = replicated(a)
        return a

    def terminate(self, a):
        if not a.finished or not (a.method is None or a.method.checked):
            return False, None
        return True, a.outcomes[-1].status

    def advance(self, a, left):
        env = self.env
        if a.finished:
            a, rows = path.check(env, a, fims_step)
            return Next(evolve(a, method=evolve(a.method, checked=True)), 0, rows)
        k, ts = len(a.frames), a.times
        min_dt = env.settings.limits.min_substep_fraction * (ts[k] - ts[k - 1])
        m = a.method
        if m.orient is None:
            m = evolve(m, orient=singular.Orientation(env.model, env.data))
        st, o, nsub = fims_step(env.model, list(a.frames), float(ts[k]), env.settings,
                                env.history, env.data, k, min_dt, m.orient)
        a = evolve(a.added(st, o, f"frame {k}: {nsub} sub-step halvings" if nsub else "",
                           f"frame {k}: converged with the fallback strategy '{o.strategy}'"
                           if o.strategy != "plain" else ""), method=m)
        env.report("FIM_S", k + 1, len(ts))
        return Next(a, 1)

    def step(self, a, left):
        if a.finished:              # the path check: outside the nonfinite guard, as before
            return self.advance(a, left)
        return super().step(a, left)

    def finish(self, a, status, used):
        return Finished(a, None, singular.located_attrs(a.outcomes))


def require_stable(env, a, state, out):
    """``require_stable``: classify the converged point; unstable -> a stable equilibrium
    downhill from the input, else from the unstable point
    (:func:`poise.solvers.stable.seek_stable`). Returns ``(analysis, state, outcome)``."""
    model, s, data = env.model, env.settings, env.data
    active = data.active
    info = classify(model, state, active=active)
    data.classified = (state, info)
    if acceptable(info, s) or info.klass != "unstable":
        return a, state, out        # judged on the output classification
    st, o, info, note = seek_stable(model, state, s, env.history, 0, data, info,
                                    lambda x: classify(model, x, active=active), a.start)
    data.classified = (st, info)     # also a failed one: its class is reported
    return a.noted(note), st, evolve(o, iterations=out.iterations + o.iterations)
