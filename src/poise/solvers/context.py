"""The solve context every strategy works on, the strategy contract and the common prologue.

:class:`Context` is what one analysis carries (model, per-solve data, settings, history,
frames); :class:`Strategy` is the contract the driver (:mod:`poise.solvers.driver`) runs:
``init`` (frame 0), ``step`` until ``terminate``, then ``postprocess`` (the shape
of optimistix's iterative solvers and scipy ``_ivp``'s ``OdeSolver``). :func:`prologue` is the
start every analysis shares: redundancy detection once per model, assembly onto the
constraints, least-squares multipliers.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from poise.solvers.data import SolveData
from poise.solvers.history import History
from poise.solvers.newton import FrameOutcome, assemble, initial_multipliers
from poise.solvers.redundancy import detect_redundancy
from poise.solvers.status import MESSAGES, Status


@dataclass
class Context:
    """One analysis in progress.

    ``request``: the analysis request (``kind``, ``settings``, ``transient``, ``simulate``,
    ``arrays``); ``data``: active rows and counters; ``redundancy``: redundant rows (None until
    detected; detection runs once per model and is handed on to later analyses); ``frames`` /
    ``outcomes``: the solved frames; ``times``: the output times; ``notes``: message parts;
    ``progress``: ``progress(label, done, total)`` or None (``done`` None: finished);
    ``infos``: classifications made during the solve (:mod:`poise.solvers.path`), reused by
    the output.
    """

    model: Any
    request: Any
    settings: Any
    data: SolveData
    history: History = field(default_factory=History)
    redundancy: np.ndarray | None = None
    frames: list = field(default_factory=list)
    outcomes: list = field(default_factory=list)
    times: np.ndarray | None = None
    notes: list = field(default_factory=list)
    moved: bool = False
    time_independent: bool = False
    progress: Callable | None = None
    start: Any = None        # frame 0's assembled input (require_stable descends from it)
    infos: dict = field(default_factory=dict)   # id(state) -> (state, StabilityInfo) classified

    @property
    def kind(self) -> str:
        return self.request.kind

    def report(self, label: str, done, total: int) -> None:
        if self.progress is not None:
            self.progress(label, done, total)


class Strategy:
    """How the frames of an analysis are produced.

    * ``name``: the method written to the results.
    * ``init(ctx, state)``: solve frame 0 (after :func:`prologue`) and set up.
    * ``step(ctx)``: advance (append frames/outcomes to ``ctx``); called while not
      ``terminate(ctx)``.
    * ``postprocess(ctx) -> (method_data, attrs)``: after the last step, before the result is
      built: the method's own record (:class:`~poise.solvers.record.IdaSteps`,
      :class:`~poise.solvers.record.MkeamRun` or None) and analysis attributes (and message
      notes).
    * ``stage_totals``: write the per-stage iteration totals (``iterations_<stage>``).
    """

    name = ""
    stage_totals = True

    def init(self, ctx: Context, state) -> None:
        raise NotImplementedError

    def step(self, ctx: Context) -> None:
        raise NotImplementedError

    def terminate(self, ctx: Context) -> bool:
        return True

    def postprocess(self, ctx: Context) -> tuple:
        return None, {}


def prologue(ctx: Context, state, multipliers: bool = True):
    """Redundancy (once per model), assembly onto the constraints and, with ``multipliers``,
    least-squares initial multipliers. Returns ``(state, outcome)``; ``outcome`` is None when
    the frame can be solved, else why not (assembly failed)."""
    model = ctx.model
    if ctx.redundancy is None:
        ctx.redundancy = detect_redundancy(model, state, ctx.data.workspace)
    ctx.data.set_redundancy(ctx.redundancy)
    if len(ctx.redundancy):
        ctx.notes.append(f"{len(ctx.redundancy)} redundant constraint equations removed")
    state, ctx.moved, ast = assemble(model, state, ctx.settings, ctx.history, 0, ctx.data)
    if ctx.moved:
        ctx.notes.append("initial configuration assembled onto the constraints")
    if not ast.ok:
        return state, FrameOutcome(Status.ASSEMBLY_FAILED, 0, np.nan, np.nan,
                                   MESSAGES[Status.ASSEMBLY_FAILED])
    if multipliers:
        state = initial_multipliers(model, state, ctx.data)
    return state, None


def replicate(ctx: Context) -> None:
    """Nothing in the scene depends on time: frame 0 stands for every output time."""
    state, out = ctx.frames[0], ctx.outcomes[0]
    ctx.notes.append("nothing in the scene depends on time: solved once, frame replicated")
    for t in ctx.times[1:]:
        st = state.copy()
        st.t = float(t)
        ctx.frames.append(st)
        ctx.outcomes.append(FrameOutcome(out.status, 0, out.imbalance, out.error, "replicated"))
