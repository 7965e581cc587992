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
evaluated ends the analysis as a ``nonfinite`` frame, never an exception.
"""
from __future__ import annotations


import numpy as np

from poise.core import memory
from poise.solvers.compliance import compliance_step
from poise.solvers.context import Analysis, Env
from poise.solvers.data import SolveData
from poise.solvers.frames import frame_outputs, measure_frame, measure_frames, stack_frames
from poise.solvers.history import History
from poise.solvers.iterate import iterate
from poise.solvers.quasistatic import NewtonFrames
from poise.solvers.record import STATUS_CONVERGED, STATUS_FAILED, AnalysisRecord, FrameSet
from poise.solvers.stable import require_stable_check

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
        self.env = Env(model, request, request.settings,
                       SolveData.for_model(model, () if redundancy is None else redundancy),
                       History(), progress)
        self.redundancy = redundancy

    @property
    def data(self) -> SolveData:
        return self.env.data

    def run(self, state, index: int = 0):
        """Solve the analysis from ``state`` (a large model's with the heap kept,
        :func:`poise.core.memory.kept_heap`): ``(last frame's state, AnalysisRecord)``."""
        with memory.kept_heap(self.model.nq + self.model.nc):
            return self._run(state, index)

    def _run(self, state, index):
        env, cls = self.env, self.strategy_cls
        state = state.copy()
        if env.kind == "quasistatic":
            times = np.asarray(self.request.output_times(state.t), float)
            state.t = float(times[0])
            independent = not self.model.depends_on_time()
        else:
            times, independent = np.array([state.t]), False
        a = Analysis(times=times, redundancy=self.redundancy, time_independent=independent)
        strategy = cls(env)
        try:
            done = iterate(strategy, len(times), env.history, a, state)
        finally:
            if env.kind == "quasistatic":
                env.report(strategy.name, None, len(times))
        a = done.analysis
        self.redundancy = a.redundancy
        return a.frames[-1], build_result(env, a, strategy, index, done.method_data, done.attrs)


def build_result(env, a, strategy, index, method_data=None, method_attrs=None) -> AnalysisRecord:
    """The record of the analysis ``a``, in explicit steps: the frames are measured (one output
    evaluation each: every outcome certified there, :func:`~poise.solvers.certify.certify`;
    history rows recorded ``measured_at`` a frame show its measures: FIM_D's interpolated
    frames), the verdict (``require_stable`` of a static frame), the compliance matrices;
    then the record."""
    model, s = env.model, env.settings
    static = env.kind == "static"
    frames = _measured_frames(env, a, static)
    outcomes = frames.outcomes
    notes = list(a.notes)
    if static:
        out = outcomes[0]
        status = STATUS_CONVERGED if out.ok else STATUS_FAILED
        message = "; ".join([m for m in [out.message] + notes if m])
        frames, message, refused = require_stable_check(frames, message, s)  # every method
        if refused:
            status = STATUS_FAILED
    else:
        ok = all(o.ok for o in outcomes) and len(a.frames) == len(a.times)
        status = STATUS_CONVERGED if ok else STATUS_FAILED
        failed = next((o for o in outcomes if not o.ok), None)
        first = "converged"
        if failed is not None:
            k = outcomes.index(failed)
            first = f"frame {k} (t={a.frames[k].t:.9g}) failed: {failed.message}"
        message = "; ".join([first] + notes)
    compliance, attrs = compliance_step(model, frames, a.redundancy, s)
    attrs = {"reactions_unique": bool(len(a.redundancy) == 0), "assembled": bool(a.moved),
             **({} if static else {"time_independent": bool(a.time_independent),
                                   "n_frames": len(a.frames)}),
             **attrs, **(method_attrs or {})}
    return AnalysisRecord(
        index=index, analysis_type=env.kind, method=strategy.name, status=status,
        message=message, settings=dict(s.as_dict(), method_requested=s.method), attrs=attrs,
        frames=frames,
        element_outputs=stack_frames([frame_outputs(model, st) for st in a.frames]),
        history=env.history, redundant=tuple(model.row_info[r] for r in a.redundancy),
        compliance=compliance, method_data=method_data, stage_totals=strategy.stage_totals)


def _measured_frames(env, a, static: bool):
    """The :class:`~poise.solvers.record.FrameSet` of every frame: all at once where the
    model allows it (quasi-static), else frame by frame."""
    if static:
        return measure_frame(env, a.redundancy, a.frames[0], a.outcomes)
    fs = measure_frames(env, a.redundancy, a.frames, a.outcomes)
    if fs is not None:
        return fs
    return FrameSet.concatenate([measure_frame(env, a.redundancy, st, [o])
                                 for st, o in zip(a.frames, a.outcomes)])
