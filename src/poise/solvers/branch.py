"""The branch a continuation follows: prediction, continuity, where it ends.

:class:`BranchPath` keeps the last (up to 3) accepted states of one quasi-static step
(:func:`poise.solvers.quasistatic.fims_step`) and FIM_D's checks: the prediction from them
(:func:`predictor`, quadratic in the tangent space; along the path's :func:`tangent` when a
state is alone or after a jump), the continuity test of a corrected point against its
prediction (:meth:`BranchPath.jump`: orientation, distance, return test next to a singular
configuration) and the bisection locating where a branch ends (:class:`Locate`, run by the
one loop). Measures: :func:`distance` (translations / L, rotations in rad).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from poise.core.errors import EvaluationError
from poise.solvers import singular
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.linalg import SingularMatrix
from poise.solvers.newton import branch_newton
from poise.solvers.status import Status

PREDICT_SPACING = 1e-2    # extrapolation nodes closer than this fraction of the step: dropped
MAX_PATH_STEP = 0.25      # predicted motion per step at most (translations / L, rotations in rad)
JUMP_RATIO = 1.0          # correction / predicted step above this: a suspected jump (sub-step)
JUMP_RATIO_SUB = 3.0      # ... on sub-steps <= JUMP_SUB of the interval (a kink in a drive)
JUMP_SUB = 1.0 / 8.0
JUMP_FLOOR = 10.0         # x max_error: a correction this small is never a jump
JUMP_SHRINK = 0.6         # ... nor one that shrank this much when the sub-step was halved
LOCATE_REL = 1e-7         # bisection width, relative to max(1, |t|) (then the fold law)


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
        ``LOCATE_REL`` (:class:`Locate` run by the one loop, within
        ``Limits.locate_max_probes`` probes). Returns ``(t_lo, t_hi, iterations)``; the
        accepted probes extend the branch."""
        self.located_from = self.hist[-1]
        return iterate(Locate(self, history, frame), self.settings.limits.locate_max_probes, history,
                       self.hist[-1].t, t_hi)


@dataclass(frozen=True)
class _Bracket:
    """:class:`Locate`'s state: the bracket, the probes' Newton iterations, the end time and
    whether it was probed again."""

    t_lo: float
    t_hi: float
    tol: float
    t_end: float
    its: int = 0
    tried_end: bool = False


class Locate(Solver[_Bracket]):
    """Where a branch ends, by bisection. A probe is Newton (at most ``Limits.probe_max_iter``
    iterations, continuity tested) from the prediction, and when that stops at once or lands
    off the branch, from the last state reached (next to a fold the extrapolation lands where
    the Jacobian is singular, or past a turning point of the drive on the other branch). After
    the first probe that goes on, one probe at ``t_hi`` itself: a branch that merely turned
    back near a singular point goes on (then ``t_lo == t_hi``). The accepted probes extend the
    ``branch``; the probes' Newton rows are appended by their own loops (to ``history``)."""

    out_of_budget = Status.STEP_TOO_SMALL

    def __init__(self, branch: BranchPath, history, frame: int):
        self.branch, self.history, self.frame = branch, history, frame

    def init(self, t_lo, t_hi):
        return _Bracket(t_lo, t_hi, LOCATE_REL * max(1.0, abs(t_hi)), t_hi)

    def terminate(self, s):
        return (True, Status.CONVERGED) if not s.t_hi - s.t_lo > s.tol else (False, None)

    def step(self, s, left):
        b = self.branch
        t = 0.5 * (s.t_lo + s.t_hi)
        if s.t_lo > b.located_from.t and not s.tried_end:
            t, s = s.t_end, replace(s, tried_end=True)   # once on the way: does it go on?
        pred, known = b.predict(t)
        last = b.hist[-1].copy()
        last.t = t
        ok, its = False, s.its
        for start in (pred, last):
            st, out = branch_newton(b.model, start, b.settings, self.history, self.frame,
                                    b.data, b.settings.limits.probe_max_iter, "locate")
            its += out.iterations
            ok = out.ok and not b.jump(start, st, known and start is pred, probe=True)
            if ok or (not out.ok and out.iterations > 2):   # no second start when Newton
                break                                       # worked and found nothing
        if not ok:
            return Next(replace(s, t_hi=min(s.t_hi, t), its=its))
        b.accept(st)
        return Next(replace(s, t_lo=t, its=its))

    def postprocess(self, s, status, used):
        return s.t_lo, s.t_hi, s.its
