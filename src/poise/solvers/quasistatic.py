"""FIM_S per frame (static: one frame; quasi-static: every output time) and the output times.

* Output times: planned from the ``Simulate`` element (:mod:`poise.app.times`).
* FIM_S (:class:`NewtonFrames`): frame 0 = the prologue (redundancy detection, assembly,
  least-squares multipliers) + Newton with the fallback chain; every later frame starts from a predictor
  extrapolated in the tangent space of the previous frame (``Model.local_difference`` /
  ``Model.retract``; linear from 2 frames, quadratic from 3) and runs Newton. A failed step is
  retried with sub-steps (interval halved, down to ``MIN_SUBSTEP_FRACTION`` of the output
  interval), each sub-step solved from its own predictor; failures are recorded in
  ``iterations/event``.
* Nothing in the scene depends on time (``Model.depends_on_time()``): one solve, the frame is
  replicated and the result says so (attribute ``time_independent``).
* MKEAM requested for a quasi-static run: FIM_S with a warning in the message (deck_format 1.7).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from poise.solvers.context import Strategy, prologue, replicate
from poise.solvers.fallback import NO_RECOVERY, recover, solve_frame
from poise.solvers.newton import newton
from poise.solvers.stability import classify
from poise.solvers.stable import acceptable, seek_stable

MIN_SUBSTEP_FRACTION = 2.0 ** -10


# ---------------------------------------------------------------------- helpers
def predictor(model, frames, t):
    """State extrapolated to ``t`` from the last (up to 3) ``frames`` (quadratic in the tangent
    space of the last frame; multipliers by the same Lagrange weights)."""
    last = frames[-1]
    if len(frames) == 1:
        st = last.copy()
        st.t = t
        return st
    tau = t - last.t
    pts = frames[-3:-1][::-1]          # previous frames, most recent first
    taus = [p.t - last.t for p in pts]
    if len(pts) == 2 and abs(taus[0] - taus[1]) > 0:
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


def fims_step(model, frames, t_target, settings, history, counters, frame, min_dt):
    """FIM_S from ``frames[-1]`` to ``t_target`` with automatic sub-stepping; when halving
    reaches ``min_dt`` the fallback chain of a static solve (:func:`~poise.solvers.fallback.
    recover`) solves the frame at ``t_target`` from its predictor.

    Returns ``(state, outcome, n_substeps)``; ``frames`` is not modified. The outcome's
    iterations count every sub-step and strategy.
    """
    hist = list(frames[-3:])
    t_prev = hist[-1].t
    dt = t_target - t_prev
    n_sub = 0
    total_it = 0
    while True:
        t = min(t_prev + dt, t_target) if dt > 0 else t_target
        if t_target - t < 1e-12 * max(1.0, abs(t_target)):
            t = t_target
        st = predictor(model, hist, t)
        st, out = newton(model, st, settings, history, frame, counters,
                         event="newton" if n_sub == 0 and t == t_target else "substep")
        total_it += out.iterations
        if out.ok:
            hist = (hist + [st])[-3:]
            t_prev = t
            if t == t_target:
                out.iterations = total_it
                return st, out, n_sub
            continue
        dt *= 0.5
        n_sub += 1
        history.add(frame, 0, out.imbalance, out.error, np.nan, np.nan,
                    f"step to t={t:.9g} failed ({out.status.value}); halving to {dt:.3g}",
                    "substep_retry")
        if dt < min_dt:
            out.iterations = total_it
            out.counts = {"plain": total_it}
            if not settings.fallback or out.status in NO_RECOVERY:
                return st, out, n_sub
            history.add(frame, 0, out.imbalance, out.error, np.nan, np.nan,
                        f"step to t={t_target:.9g} failed after {n_sub} halvings; fallback "
                        "chain from the frame's predictor", "substep_retry")
            st, out = recover(model, predictor(model, hist, t_target), st, out, settings,
                              history, frame, counters)
            return st, out, n_sub


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
        if out.ok and s.require_stable and ctx.kind == "static":
            st, out = require_stable(ctx, st, out)
        ctx.frames, ctx.outcomes = [st], [out]
        self.k = 1
        if out.ok and ctx.time_independent and len(ctx.times) > 1:
            replicate(ctx)

    def terminate(self, ctx):
        return (len(ctx.frames) == len(ctx.times) or not ctx.outcomes[-1].ok)

    def step(self, ctx):
        k, ts = len(ctx.frames), ctx.times
        min_dt = MIN_SUBSTEP_FRACTION * (ts[k] - ts[k - 1])
        st, o, nsub = fims_step(ctx.model, ctx.frames, float(ts[k]), ctx.settings, ctx.history,
                                ctx.data, k, min_dt)
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
