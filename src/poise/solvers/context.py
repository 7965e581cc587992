"""What an analysis runs with, its frozen state, the analysis-strategy contract, its start.

An analysis strategy is a :class:`~poise.solvers.iterate.Solver` (:class:`AnalysisSolver`)
over one frozen, typed :class:`Analysis` (output times, frames, outcomes, notes, redundancy,
the strategy's own frozen ``method`` state); :class:`Env` is what it runs with (model,
request, settings, the per-solve workspace :class:`~poise.solvers.data.SolveData`, the
history, progress). The driver (:mod:`poise.solvers.driver`) runs it by
:func:`~poise.solvers.iterate.iterate`, which appends every history row. :func:`begin` is
the start every analysis shares: redundancy detection once per model, assembly onto the
constraints, least-squares multipliers.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Generic, TypeVar

import numpy as np

from poise.core.errors import EvaluationError
from poise.solvers.data import SolveData
from poise.solvers.history import History
from poise.solvers.iterate import Next, Solver, evolve
from poise.solvers.newton import FrameOutcome, initial_multipliers
from poise.solvers.reach import assemble
from poise.solvers.redundancy import detect_redundancy, without_rows
from poise.solvers.status import MESSAGES, Status


M = TypeVar("M")


@dataclass(frozen=True)
class Env:
    """What one analysis runs with, the same from start to end: the ``model``, the ``request``
    (``kind``, ``settings``, ``transient``, ``output_times``), its ``settings``, the per-solve
    workspace ``data`` (active rows, counters, caches), the ``history`` the loop appends to and
    ``progress(label, done, total)`` or None (``done`` None: finished)."""

    model: Any
    request: Any
    settings: Any
    data: SolveData
    history: History
    progress: Callable | None = None

    @property
    def kind(self) -> str:
        return self.request.kind

    def report(self, label: str, done, total: int) -> None:
        if self.progress is not None:
            self.progress(label, done, total)


@dataclass(frozen=True)
class Analysis(Generic[M]):
    """One analysis in progress, frozen (``evolve`` / the helpers make the next).

    ``times``: the output times; ``frames`` / ``outcomes``: the solved frames and their
    :class:`~poise.solvers.newton.FrameOutcome`; ``notes``: message parts; ``redundancy``:
    the redundant rows (None until detected; handed on to the next analysis); ``moved``: the
    input was assembled; ``time_independent``: nothing depends on time; ``start``: frame 0's
    assembled input (``require_stable`` descends from it); ``method``: the strategy's own
    frozen state (None when it has none)."""

    times: np.ndarray
    frames: tuple = ()
    outcomes: tuple = ()
    notes: tuple = ()
    redundancy: np.ndarray | None = None
    moved: bool = False
    time_independent: bool = False
    start: Any = None
    method: M | None = None

    def added(self, state, outcome, *notes) -> "Analysis[M]":
        """With one more frame (``state``, its ``outcome``) and ``notes``."""
        return evolve(self, frames=self.frames + (state,), outcomes=self.outcomes + (outcome,),
                      notes=self.notes + tuple(n for n in notes if n))

    def noted(self, *notes) -> "Analysis[M]":
        return evolve(self, notes=self.notes + tuple(n for n in notes if n))

    @property
    def finished(self) -> bool:
        """Every output time has its frame, or the last frame failed."""
        return bool(self.outcomes) and (len(self.frames) == len(self.times)
                                        or not self.outcomes[-1].ok)

    def nonfinite(self, state, message: str) -> "Analysis[M]":
        """Ended by an element that cannot be evaluated: a ``nonfinite`` frame (the input
        ``state`` when no frame was solved yet; else the last frame's outcome when it has none,
        else a repeat of the last frame)."""
        out = FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, message)
        a = self if self.redundancy is not None else evolve(self, redundancy=np.zeros(0, int))
        if not a.frames:
            return evolve(a, frames=(state,), outcomes=(out,))
        if len(a.outcomes) < len(a.frames):
            return evolve(a, outcomes=a.outcomes + (out,))
        return evolve(a, frames=a.frames + (a.frames[-1],), outcomes=a.outcomes + (out,))


@dataclass(frozen=True)
class Finished:
    """What an analysis strategy hands the driver: the final :class:`Analysis`, the method's
    own record (:class:`~poise.solvers.record.IdaSteps`, :class:`~poise.solvers.record.MkeamRun`
    or None) and analysis attributes."""

    analysis: Analysis
    method_data: Any = None
    attrs: dict = field(default_factory=dict)


class AnalysisSolver(Solver[Analysis]):
    """How the frames of an analysis are produced: a :class:`~poise.solvers.iterate.Solver`
    over :class:`Analysis`, configured with the :class:`Env` it runs in.

    * ``name``: the method written to the results; ``stage_totals``: write the per-stage
      iteration totals (``iterations_<stage>``).
    * ``start(a, state) -> Analysis``: frame 0 (after :func:`begin`) and the method's state.
    * ``advance(a, left) -> Next[Analysis]``: the next frame(s); ``spent``: output frames added.
    * ``terminate`` (default: :attr:`Analysis.finished`), pure.
    * ``finish(a, status, used) -> Finished``: after the last step, before the record is built.

    ``init`` / ``step`` wrap ``start`` / ``advance``: an element that cannot be evaluated
    (:class:`~poise.core.errors.EvaluationError`) ends the analysis as a ``nonfinite`` frame
    (:meth:`Analysis.nonfinite`), never an exception. The budget is the number of output times.
    """

    name = ""
    stage_totals = True
    out_of_budget = Status.MAX_ITERATIONS

    def __init__(self, env: Env):
        self.env = env

    def init(self, a: Analysis, state) -> Analysis:
        try:
            return self.start(a, state)
        except EvaluationError as e:
            return a.nonfinite(state, str(e))

    def step(self, a: Analysis, left: int) -> Next[Analysis]:
        try:
            return self.advance(a, left)
        except EvaluationError as e:
            return Next(a.nonfinite(a.frames[-1], str(e)), 0)

    def terminate(self, a: Analysis):
        if not a.finished:
            return False, None
        return True, a.outcomes[-1].status

    def postprocess(self, a: Analysis, status, used) -> Finished:
        return self.finish(a, status, used)

    def start(self, a: Analysis, state) -> Analysis:
        raise NotImplementedError

    def advance(self, a: Analysis, left: int) -> Next[Analysis]:
        raise NotImplementedError

    def finish(self, a: Analysis, status, used) -> Finished:
        return Finished(a)


def begin(env: Env, a: Analysis, state, multipliers: bool = True):
    """Redundancy (once per model), assembly onto the constraints and, with ``multipliers``,
    least-squares initial multipliers. Returns ``(analysis, state, outcome)``; ``outcome`` is
    None when the frame can be solved, else why not (assembly failed)."""
    model, data = env.model, env.data
    red = a.redundancy
    ev = None
    if red is None:
        # one evaluation (every row) for the redundancy test, the assembly's start and,
        # where nothing moved and no multiplier is set, the least-squares multipliers: all of
        # them read the constraint Jacobian alone (no stiffness tangents assembled)
        ev = data.evaluate(model, state, "phi_q", every_row=True) if model.nc else None
        red = detect_redundancy(model, state, data.workspace, evaluation=ev)
    data.set_redundancy(red)
    a = evolve(a, redundancy=red)
    if len(red):
        a = a.noted(f"{len(red)} redundant constraint equations removed")
    if ev is not None:
        ev = without_rows(model, ev, data.mask(model))
    state, moved, ast = assemble(model, state, env.settings, env.history, 0, data, ev=ev)
    a = evolve(a, moved=moved)
    if moved:
        a = a.noted("initial configuration assembled onto the constraints")
    if not ast.ok:
        return a, state, FrameOutcome(Status.ASSEMBLY_FAILED, 0, np.nan, np.nan,
                                      MESSAGES[Status.ASSEMBLY_FAILED])
    if multipliers:
        same = ev is not None and not moved and not np.any(state.lam)   # r at lam = 0
        state = initial_multipliers(model, state, data, ev=ev if same else None)
    return a, state, None


def replicated(a: Analysis) -> Analysis:
    """Nothing in the scene depends on time: frame 0 stands for every output time."""
    state, out = a.frames[0], a.outcomes[0]
    frames, outcomes = [], []
    for t in a.times[1:]:
        st = state.copy()
        st.t = float(t)
        frames.append(st)
        outcomes.append(FrameOutcome(out.status, 0, out.imbalance, out.error, "replicated"))
    return evolve(a, frames=a.frames + tuple(frames), outcomes=a.outcomes + tuple(outcomes),
                  notes=a.notes + ("nothing in the scene depends on time: solved once, frame "
                                   "replicated",))
