"""Quasi-static analysis: output times, FIM_S (a static solve per output time), dispatch to FIM_D.

* Output times (:func:`output_times`): ``print_array_id`` (a ``Reference_Array`` of type PRINT,
  times inside [start, end]), else ``num_steps`` (equal intervals of (end - start)/num_steps),
  else ``print_interval`` (default 0.01). The start time is always the first frame
  (conventions.md) and the end time the last one.
* FIM_S: frame 0 = redundancy detection + assembly + least-squares multipliers + Newton, exactly
  like :class:`~poise.solvers.static.StaticAnalysis`; every later frame starts from a predictor
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
import os
import sys
import time as _time

import numpy as np

from poise.core.progress import PROGRESS
from poise.model.model import Evaluation
from poise.results.data import STATUS_CONVERGED, STATUS_FAILED, AnalysisResult
from poise.solvers.history import History
from poise.solvers.fallback import NO_RECOVERY, recover, solve_frame
from poise.solvers.newton import (Counters, FrameOutcome, Scales, assemble, initial_multipliers,
                                  measures, newton)
from poise.solvers.static import (StaticAnalysis, detect_redundancy, frame_outputs, stack_frames,
                                  strategy_attrs)
from poise.solvers.status import MESSAGES, Status

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
#: (poise.core.progress.PROGRESS: a callable there is the orchestration's callback, to which
#: :class:`Progress` reports instead of drawing)


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
        # a callable ``enabled`` is the callback(label, done, total) of poise.core.progress:
        # reports go there and this class draws nothing
        self.report = enabled if callable(enabled) else None
        if self.report is not None:
            enabled = False
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
        if self.report is not None:
            self.report(self.label, done, self.total)
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
        if self.report is not None:
            self.report(self.label, None, self.total)
        if self.shown:
            sys.stderr.write("\r" + " " * 70 + "\r")
            sys.stderr.flush()


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


def _evaluation_error_fails_frame(fn):
    """An expression or element that cannot be evaluated anywhere in frame 0 (redundancy
    detection, assembly, Newton) ends it as a NONFINITE outcome (exit 1), not an exception."""
    import functools

    @functools.wraps(fn)
    def wrapper(model, state, settings, history, counters, redundancy):
        from poise.core.errors import EvaluationError
        try:
            return fn(model, state, settings, history, counters, redundancy)
        except EvaluationError as e:
            red = np.zeros(0, int) if redundancy is None else redundancy
            return (state, FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, str(e)), red, [],
                    False)
    return wrapper


@_evaluation_error_fails_frame
def first_frame(model, state, settings, history, counters, redundancy):
    """Frame 0 of a quasi-static run: like StaticAnalysis (redundancy, assembly, multipliers,
    Newton). Returns ``(state, outcome, redundancy, notes, moved)``."""
    notes = []
    if redundancy is None:
        redundancy = detect_redundancy(model, state)
    else:
        model.row_active[:] = True
        model.row_active[redundancy] = False
    if len(redundancy):
        notes.append(f"{len(redundancy)} redundant constraint equations removed")
    state, moved, ast = assemble(model, state, settings, history, 0, counters)
    if moved:
        notes.append("initial configuration assembled onto the constraints")
    if not ast.ok:
        return state, FrameOutcome(Status.ASSEMBLY_FAILED, 0, np.nan, np.nan,
                                   MESSAGES[Status.ASSEMBLY_FAILED]), redundancy, notes, moved
    state = initial_multipliers(model, state, counters)
    state, out = solve_frame(model, state, settings, history, 0, counters)
    if out.strategy != "plain":
        notes.append(f"frame 0: plain Newton failed; converged with the fallback strategy "
                     f"'{out.strategy}'")
    return state, out, redundancy, notes, moved


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


# ---------------------------------------------------------------------- driver
class QuasiStaticAnalysis:
    """Quasi-static run (FIM_S or FIM_D) of one ``Simulate`` command.

    ``cls(model, request, redundancy=...)``; ``run(state, index) -> (state, AnalysisResult)``.
    """

    def __init__(self, model, request, redundancy=None, spec=None):
        self.model = model
        self.request = request
        self.settings = request.settings
        self.redundancy = redundancy
        self.counters = Counters()
        self.history = History()
        self.spec = spec if spec is not None else getattr(request, "spec", None)
        self.progress_enabled = PROGRESS.get()

    def times(self, state):
        arrays = getattr(self.request, "arrays", None)
        if arrays is None:
            arrays = print_arrays(self.spec)
        return output_times(self.request.simulate, state.t, arrays)

    def run(self, state, index: int = 0):
        s = self.settings
        notes = []
        method = s.method
        if method == "MKEAM":
            notes.append("warning: MKEAM does not apply to quasi-static runs; FIM_S used")
            method = "FIM_S"
        if method == "FIM_D":
            from poise.solvers.fim_d import run_fim_d
            return run_fim_d(self, state, index, notes)
        return self.run_fim_s(state, index, notes)

    # ------------------------------------------------------------------ FIM_S
    def run_fim_s(self, state, index, notes):
        model, s = self.model, self.settings
        ts = self.times(state)
        self._times = ts
        state = state.copy()
        state.t = float(ts[0])
        state, out, self.redundancy, n0, moved = first_frame(
            model, state, s, self.history, self.counters, self.redundancy)
        notes += n0
        frames, outcomes = [state], [out]
        time_indep = not model.depends_on_time()
        prog = Progress(len(ts), "FIM_S", enabled=self.progress_enabled)
        if out.ok and time_indep and len(ts) > 1:
            notes.append("nothing in the scene depends on time: solved once, frame replicated")
            for t in ts[1:]:
                st = state.copy()
                st.t = float(t)
                frames.append(st)
                outcomes.append(FrameOutcome(out.status, 0, out.imbalance, out.error,
                                             "replicated"))
        elif out.ok:
            for k in range(1, len(ts)):
                min_dt = MIN_SUBSTEP_FRACTION * (ts[k] - ts[k - 1])
                st, o, nsub = fims_step(model, frames, float(ts[k]), s, self.history,
                                        self.counters, k, min_dt)
                if nsub:
                    notes.append(f"frame {k}: {nsub} sub-step halvings")
                if o.strategy != "plain":
                    notes.append(f"frame {k}: converged with the fallback strategy "
                                 f"'{o.strategy}'")
                frames.append(st)
                outcomes.append(o)
                prog.update(k + 1)
                if not o.ok:
                    break
        prog.close()
        return self.finish(frames, outcomes, index, "FIM_S", notes, moved, time_indep)

    # ------------------------------------------------------------------ results
    def finish(self, frames, outcomes, index, method, notes, moved, time_indep, extra=None,
               measured=None):
        """Results of the run. Every frame's outcome is certified on its output evaluation
        (:func:`~poise.solvers.certify.certify`). ``measured``: ``{frame index: history row}``
        of frames whose history row takes its imbalance / constraint error / worst equation
        from that evaluation (FIM_D's interpolated frames)."""
        model, s = self.model, self.settings
        ar = AnalysisResult(index=index, analysis_type="quasistatic", method=method,
                            settings=dict(s.as_dict(), method_requested=s.method))
        ar.attrs["reactions_unique"] = bool(len(self.redundancy) == 0)
        ar.attrs["assembled"] = bool(moved)
        ar.attrs["time_independent"] = bool(time_indep)
        ar.attrs["n_frames"] = len(frames)
        sa = StaticAnalysis(model, self.request, redundancy=self.redundancy)
        measured = measured or {}
        sc = Scales(model, s) if measured else None

        def measure_row(k, imb, cerr, worst):
            if k not in measured:
                return
            row = list(self.history.rows[measured[k]])
            row[2], row[3], row[6] = imb, cerr, worst
            self.history.rows[measured[k]] = tuple(row)

        def measure(k):
            def on_eval(ev, active):
                ms = measures(model, Evaluation(r=ev.r, phi=np.where(active, ev.phi, 0.0),
                                                J=None), sc)
                measure_row(k, ms[0], ms[1], ms[3])
            return on_eval

        # all frames at once where the model allows it (same datasets, array work per frame)
        from poise.solvers.frames import frames_datasets
        d = frames_datasets(sa, frames, outcomes, measure_row if measured else None)
        if d is None:
            per = [sa.frame_datasets(st, [o], on_eval=measure(k) if k in measured else None)
                   for k, (st, o) in enumerate(zip(frames, outcomes))]
            d = {}
            # keys every frame has (a failed frame has no stability classification)
            for key in [k for k in per[0] if all(k in p for p in per[1:])]:
                if key.endswith("/id") or key.endswith("/tag") or key.endswith("/unique") \
                        or key.endswith("/label"):
                    d[key] = per[0][key]
                else:
                    d[key] = np.concatenate([np.asarray(p[key]) for p in per])
        ar.datasets.update(d)
        ok = all(o.ok for o in outcomes) and len(frames) == len(self.times_cache(frames))
        ar.status = STATUS_CONVERGED if ok else STATUS_FAILED
        failed = next((o for o in outcomes if not o.ok), None)
        first = failed.message if failed is not None else "converged"
        if failed is not None:
            k = outcomes.index(failed)
            first = f"frame {k} (t={frames[k].t:.9g}) failed: {failed.message}"
        ar.message = "; ".join([first] + notes)
        ar.datasets.update(stack_frames([frame_outputs(model, st) for st in frames]))
        from poise.solvers.compliance import attach     # after the frame datasets (stability)
        attach(ar, model, frames, outcomes, self.redundancy, s)
        ar.datasets.update(self.history.datasets())
        ar.attrs.update(strategy_attrs(ar.datasets))
        ar.datasets.update(sa.redundancy_datasets())
        if extra:
            ar.datasets.update(extra)
        return frames[-1], ar

    def times_cache(self, frames):
        if not hasattr(self, "_times"):
            self._times = self.times(frames[0])
        return self._times
