"""FIM_S per frame (static: one frame; quasi-static: every output time) and the output times.

* Output times (:func:`output_times`): ``print_array_id`` (a ``Reference_Array`` of type PRINT,
  times inside [start, end]), else ``num_steps`` (equal intervals of (end - start)/num_steps),
  else ``print_interval`` (default 0.01). The start time is always the first frame
  (conventions.md) and the end time the last one.
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

import contextlib
import contextvars
import os
import sys
import time as _time

import numpy as np

from dataclasses import replace

from poise.solvers.context import Strategy, prologue, replicate
from poise.solvers.fallback import NO_RECOVERY, recover, solve_frame
from poise.solvers.newton import newton
from poise.solvers.stability import classify
from poise.solvers.stable import acceptable, seek_stable

DEFAULT_PRINT_INTERVAL = 0.01
MIN_SUBSTEP_FRACTION = 2.0 ** -10


# ---------------------------------------------------------------------- output times
#: Most output frames one quasi-static Simulate may ask for (a located deck error beyond).
MAX_FRAMES = 1_000_000


def _check_frames(sim, n: float, what: str) -> None:
    if not n <= MAX_FRAMES:          # also inf/nan: times that overflow
        from poise.core.errors import DeckError, Problem
        raise DeckError(Problem(sim.loc, f"{what} asks for {n:.3g} output frames; expected at "
                                         f"most {MAX_FRAMES} (a larger print_interval or a "
                                         "shorter run)"))


def output_times(sim, t_now: float, arrays: dict | None = None) -> np.ndarray:
    """Output times of a quasi-static ``Simulate`` starting at ``t_now`` (start included)."""
    a = sim.attrs
    t0 = float(a["start_time"]) if a.get("start_time") is not None else float(t_now)
    if a.get("end_time") is not None:
        t1 = float(a["end_time"])
    elif a.get("duration") is not None:
        t1 = t0 + float(a["duration"])
    else:
        t1 = t0
    aid = a.get("print_array_id")
    if aid is not None and arrays and aid in arrays:
        v = np.asarray(arrays[aid], float)
        v = v[(v > t0 + 1e-12 * max(1.0, abs(t0))) & (v <= t1 + 1e-12 * max(1.0, abs(t1)))]
        ts = np.unique(np.concatenate([[t0], v, [t1]]))
        return ts
    ns = a.get("num_steps", a.get("num_step"))
    if ns is not None:
        _check_frames(sim, float(ns), "num_steps")
        return np.linspace(t0, t1, int(ns) + 1)
    dt = float(a.get("print_interval") or DEFAULT_PRINT_INTERVAL)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        n = (t1 - t0) / dt
    _check_frames(sim, n, "(end_time - start) / print_interval")
    k = int(np.floor(n + 1e-9))
    ts = t0 + dt * np.arange(k + 1)
    if t1 - ts[-1] > 1e-9 * dt:
        ts = np.append(ts, t1)
    else:
        ts[-1] = t1
    return ts


def print_arrays(spec) -> dict:
    """``{id: values}`` of ``Reference_Array`` elements (values from the element text)."""
    out = {}
    if spec is None:
        return out
    for e in spec.model:
        if e.tag == "Reference_Array":
            vals = e.attrs.get("values")
            if vals is None:
                vals = [float(x) for x in (e.text or "").replace(",", " ").split()]
            out[e.id] = np.asarray(vals, float)
    return out


# ---------------------------------------------------------------------- progress
#: ``False`` silences the progress bar of quasi-static runs started in this context (``poise
#: solve --quiet`` through ``run_deck(quiet=True)``); ``None``: automatic (stderr is a terminal,
#: not in CI, ``POISE_QUIET`` unset).
PROGRESS: contextvars.ContextVar = contextvars.ContextVar("poise_progress", default=None)


@contextlib.contextmanager
def progress_bar(enabled: bool | None):
    """Context in which quasi-static progress bars are ``enabled`` (None: automatic)."""
    tok = PROGRESS.set(enabled)
    try:
        yield
    finally:
        PROGRESS.reset(tok)


class Progress:
    """A one-line progress bar on stderr for runs longer than ~1 s (TTY only, not in CI)."""

    def __init__(self, total: int, label: str, enabled: bool | None = None):
        if enabled is None:
            enabled = (sys.stderr.isatty() and not os.environ.get("CI")
                       and not os.environ.get("POISE_QUIET"))
        self.enabled = enabled
        self.total = max(total, 1)
        self.label = label
        self.t0 = _time.perf_counter()
        self.last = 0.0
        self.shown = False

    def update(self, done: int):
        if not self.enabled:
            return
        now = _time.perf_counter()
        if now - self.t0 < 1.0 or now - self.last < 0.1:
            return
        self.last = now
        f = done / self.total
        bar = "#" * int(30 * f)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {done}/{self.total} frames")
        sys.stderr.flush()
        self.shown = True

    def close(self):
        if self.shown:
            sys.stderr.write("\r" + " " * 70 + "\r")
            sys.stderr.flush()


def progress_callback():
    """A ``progress(label, done, total)`` drawing a :class:`Progress` bar per label (enabled
    as the :data:`PROGRESS` context says when this is called); ``done`` None closes it."""
    enabled = PROGRESS.get()
    bars = {}

    def progress(label, done, total):
        bar = bars.get(label)
        if bar is None:
            bar = bars[label] = Progress(total, label, enabled=enabled)
        if done is None:
            bars.pop(label).close()
        else:
            bar.update(done)
    return progress


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
    """``require_stable``: classify the converged point; unstable -> continue downhill to a
    stable equilibrium (:func:`poise.solvers.stable.seek_stable`)."""
    model, s, active = ctx.model, ctx.settings, ctx.data.active
    info = classify(model, state, active=active)
    if acceptable(info, s) or info.klass != "unstable":
        return state, out        # judged on the output classification
    st, o, _, note = seek_stable(model, state, s, ctx.history, 0, ctx.data, info,
                                 lambda x: classify(model, x, active=active))
    if note:
        ctx.notes.append(note)
    return st, replace(o, iterations=out.iterations + o.iterations)
