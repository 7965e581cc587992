"""One solver driver for every analysis: the strategy run by the one loop, one typed record.

A static analysis is a quasi-static one with one frame. :class:`Driver` builds what the
analysis runs with (:class:`~poise.solvers.context.Env`: model, settings, the per-solve data,
the history) and runs the strategy :data:`METHODS` maps the request to, an
:class:`~poise.solvers.context.AnalysisSolver`, by :func:`~poise.solvers.iterate.iterate`
over the output times (frozen :class:`~poise.solvers.context.Analysis` states; the loop
appends every history row). Then it builds the one record (:func:`build_result`: measurement
and certification of the frames, the verdict, the compliance matrices, explicit steps;
:mod:`poise.results.layout` writes the record). Every frame a strategy solves by Newton gets
the fallback chain (:func:`poise.solvers.fallback.solve_frame`). An element that cannot be
evaluated ends the analysis as a ``nonfinite`` frame, never an exception. A strategy still on
the older :class:`~poise.solvers.context.Strategy` contract runs in the driver's own loop.
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError
from poise.solvers.compliance import compliance_step
from poise.solvers.context import Analysis, AnalysisSolver, Context, Env
from poise.solvers.data import SolveData
from poise.solvers.frames import frame_outputs, measure_frame, measure_frames, stack_frames
from poise.solvers.iterate import iterate
from poise.solvers.newton import FrameOutcome
from poise.solvers.quasistatic import NewtonFrames
from poise.solvers.record import STATUS_CONVERGED, STATUS_FAILED, AnalysisRecord, FrameSet
from poise.solvers.stable import require_stable_check
from poise.solvers.status import Status

#: (analysis kind, Param_Static method) -> strategy (``module:Class`` for the ones imported
#: only when used: MKEAM and FIM_D need scipy / SUNDIALS, which the small-deck FIM_S path never
#: loads). FIM_D of a static analysis and MKEAM of a quasi-static one run FIM_S (the message
#: says so); ``require_stable`` is part of FIM_S's static frame
#: (:func:`poise.solvers.quasistatic.require_stable`).
METHODS = {
    ("static", "FIM_S"): NewtonFrames,
    ("static", "FIM_D"): NewtonFrames,
    ("static", "MKEAM"): "poise.solvers.mkeam:MkeamMethod",
    ("quasistatic", "FIM_S"): NewtonFrames,
    ("quasistatic", "FIM_D"): "poise.solvers.fim_d:IdaContinuation",
    ("quasistatic", "MKEAM"): NewtonFrames,
}


def strategy_for(request):
    """The strategy class of ``request``, or None and why (an unsupported analysis type)."""
    cls = METHODS.get((request.kind, request.settings.method))
    if cls is None:
        return None, f"analysis_type {request.kind.upper()} is not supported; expected Static"
    if isinstance(cls, str):
        import importlib
        mod, name = cls.split(":")
        cls = getattr(importlib.import_module(mod), name)
    return cls, None


class Driver:
    """One analysis: ``Driver(model, request, redundancy=None, progress=None).run(state,
    index) -> (state, AnalysisRecord)``; afterwards ``data`` (counters) and ``redundancy``
    (handed to the next analysis: detection runs once per model). ``request``: ``kind``,
    ``settings``, ``transient`` and, quasi-static, ``output_times(t_start)``.

    ``progress``: ``progress(label, done, total)`` for the frames of a quasi-static run
    (``done`` None when finished), or None.
    """

    def __init__(self, model, request, redundancy=None, progress=None):
        self.model = model
        self.request = request
        self.strategy_cls, why = strategy_for(request)
        if self.strategy_cls is None:
            raise ValueError(why)
        self.ctx = Context(model=model, request=request, settings=request.settings,
                           data=SolveData.for_model(model, () if redundancy is None
                                                    else redundancy),
                           redundancy=redundancy, progress=progress)

    @property
    def env(self) -> Env:
        """What an :class:`~poise.solvers.context.AnalysisSolver` runs with."""
        ctx = self.ctx
        return Env(ctx.model, ctx.request, ctx.settings, ctx.data, ctx.history, ctx.progress)

    @property
    def data(self) -> SolveData:
        return self.ctx.data

    @property
    def redundancy(self):
        return self.ctx.redundancy

    def run(self, state, index: int = 0):
        ctx = self.ctx
        cls = self.strategy_cls
        strategy = cls(self.env) if issubclass(cls, AnalysisSolver) else cls()
        state = state.copy()
        if ctx.kind == "quasistatic":
            ctx.times = np.asarray(self.request.output_times(state.t), float)
            state.t = float(ctx.times[0])
            ctx.time_independent = not self.model.depends_on_time()
        else:
            ctx.times = np.array([state.t])
        if isinstance(strategy, AnalysisSolver):
            method_data, attrs = self._run(strategy, state)
            return ctx.frames[-1], build_result(ctx, strategy, index, method_data, attrs)
        label = strategy.name
        try:
            strategy.init(ctx, state)
            while not strategy.terminate(ctx):
                strategy.step(ctx)
        except EvaluationError as e:      # an element or expression that cannot be evaluated
            if ctx.redundancy is None:
                ctx.redundancy = np.zeros(0, int)
            if not ctx.frames:
                ctx.frames, ctx.outcomes = [state], []
            if len(ctx.outcomes) < len(ctx.frames):
                ctx.outcomes.append(FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, str(e)))
            else:
                ctx.frames.append(ctx.frames[-1])
                ctx.outcomes.append(FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, str(e)))
        finally:
            if ctx.kind == "quasistatic":
                ctx.report(label, None, len(ctx.times))
        method_data, attrs = strategy.postprocess(ctx)
        return ctx.frames[-1], build_result(ctx, strategy, index, method_data, attrs)

    def _run(self, strategy, state):
        """An :class:`~poise.solvers.context.AnalysisSolver` run by the one loop over the
        output times; the final :class:`~poise.solvers.context.Analysis` is handed to the
        record. Returns ``(method_data, attrs)``."""
        ctx = self.ctx
        a = Analysis(times=ctx.times, redundancy=ctx.redundancy,
                     time_independent=ctx.time_independent)
        try:
            done = iterate(strategy, len(ctx.times), ctx.history, a, state)
        finally:
            if ctx.kind == "quasistatic":
                ctx.report(strategy.name, None, len(ctx.times))
        a = done.analysis
        ctx.frames, ctx.outcomes, ctx.notes = list(a.frames), list(a.outcomes), list(a.notes)
        ctx.redundancy, ctx.moved, ctx.start = a.redundancy, a.moved, a.start
        return done.method_data, done.attrs


def build_result(ctx, strategy, index, method_data=None, method_attrs=None) -> AnalysisRecord:
    """The record of an analysis, in explicit steps: the frames are measured (one output
    evaluation each: every outcome certified there, :func:`~poise.solvers.certify.certify`;
    history rows recorded ``measured_at`` a frame show its measures: FIM_D's interpolated
    frames), the verdict (``require_stable`` of a static frame), the compliance matrices;
    then the record."""
    model, s = ctx.model, ctx.settings
    static = ctx.kind == "static"
    frames = _measured_frames(ctx, static)
    outcomes = frames.outcomes
    if static:
        out = outcomes[0]
        status = STATUS_CONVERGED if out.ok else STATUS_FAILED
        message = "; ".join([m for m in [out.message] + ctx.notes if m])
        frames, message, refused = require_stable_check(frames, message, s)  # every method
        if refused:
            status = STATUS_FAILED
    else:
        ok = all(o.ok for o in outcomes) and len(ctx.frames) == len(ctx.times)
        status = STATUS_CONVERGED if ok else STATUS_FAILED
        failed = next((o for o in outcomes if not o.ok), None)
        first = "converged"
        if failed is not None:
            k = outcomes.index(failed)
            first = f"frame {k} (t={ctx.frames[k].t:.9g}) failed: {failed.message}"
        message = "; ".join([first] + ctx.notes)
    compliance, attrs = compliance_step(model, frames, ctx.redundancy, s)
    attrs = {"reactions_unique": bool(len(ctx.redundancy) == 0), "assembled": bool(ctx.moved),
             **({} if static else {"time_independent": bool(ctx.time_independent),
                                   "n_frames": len(ctx.frames)}),
             **attrs, **(method_attrs or {})}
    return AnalysisRecord(
        index=index, analysis_type=ctx.kind, method=strategy.name, status=status,
        message=message, settings=dict(s.as_dict(), method_requested=s.method), attrs=attrs,
        frames=frames,
        element_outputs=stack_frames([frame_outputs(model, st) for st in ctx.frames]),
        history=ctx.history, redundant=tuple(model.row_info[r] for r in ctx.redundancy),
        compliance=compliance, method_data=method_data, stage_totals=strategy.stage_totals)


def _measured_frames(ctx, static: bool):
    """The :class:`~poise.solvers.record.FrameSet` of every frame: all at once where the
    model allows it (quasi-static), else frame by frame."""
    if static:
        return measure_frame(ctx, ctx.frames[0], ctx.outcomes)
    fs = measure_frames(ctx, ctx.frames, ctx.outcomes)
    if fs is not None:
        return fs
    return FrameSet.concatenate([measure_frame(ctx, st, [o])
                                 for st, o in zip(ctx.frames, ctx.outcomes)])
