"""What an analysis hands on: typed records, never file paths.

The driver (:mod:`poise.solvers.driver`) returns one :class:`AnalysisRecord`: the verdict
(status, message), the effective settings, analysis attributes and the data as typed records:
the output frames (:class:`FrameSet`: states, certified outcomes, element loads, numeric
stability), the iteration history (:class:`poise.solvers.history.History`, declared columns),
the redundant constraint rows, the compliance matrices (:class:`ComplianceRecord`) and the
method's own statistics (:class:`IdaSteps`, :class:`MkeamRun`). :mod:`poise.results.layout`
is the one module that maps them onto the results file's paths (``docs/results-format.md``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from poise.solvers.history import STRATEGIES

STATUS_CONVERGED = "converged"
STATUS_FAILED = "failed"


@dataclass(frozen=True, eq=False)
class GroupLoads:
    """One output group's element loads over the frames: ``ids`` (n,), ``force`` / ``torque``
    (F, n, 3); ``tag`` (n,) the deck tag of each element (``forces``), ``unique`` (n,) whether
    each reaction is uniquely determined (``joints``, ``jprims``), else None."""

    ids: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    tag: np.ndarray | None = None
    unique: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class FrameSet:
    """Every output frame of an analysis: the ``states`` (F,), ``time`` (F,); the bodies'
    ``body_id`` (B,),
    ``position`` (F, B, 3), ``orientation`` (F, B, 3, 3) and ``rotation_from_input``
    (F, B, 3) (turns counted); per output group its :class:`GroupLoads`; the certified
    outcomes (:class:`~poise.solvers.newton.FrameOutcome`, one per frame, not changed once
    here: :meth:`with_outcome` makes a new set), the numeric stability of each frame
    (:class:`~poise.solvers.stability_modes.StabilityInfo`) and its ``measures``
    (``(imbalance, constraint error, worst equation)`` of its output evaluation, None if it
    could not be evaluated)."""

    states: tuple
    time: np.ndarray
    body_id: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    rotation_from_input: np.ndarray
    groups: dict
    outcomes: tuple
    stability: tuple
    measures: tuple

    def __len__(self) -> int:
        return len(self.time)

    def with_outcome(self, k: int, outcome) -> "FrameSet":
        """The same frames with frame ``k``'s outcome replaced."""
        outs = list(self.outcomes)
        outs[k] = outcome
        return replace(self, outcomes=tuple(outs))

    @cached_property
    def strategy_iterations(self) -> np.ndarray:
        """(F, len(STRATEGIES)) each frame's iterations split by recovery stage (columns in
        :data:`~poise.solvers.history.STRATEGIES` order; a frame's work not split is
        ``plain``: the rows sum to the frames' iterations). Made once (the frames' dataset
        and the stage totals read it)."""
        it = np.zeros((len(self.outcomes), len(STRATEGIES)), np.int64)
        for k, o in enumerate(self.outcomes):
            c = o.counts or {"plain": o.iterations}
            for j, name in enumerate(STRATEGIES):
                it[k, j] = int(c.get(name, 0))
            it[k, 0] += int(o.iterations) - int(it[k].sum())
        return it

    @staticmethod
    def concatenate(sets: list) -> "FrameSet":
        """Frame sets one after the other; element ids, tags and reaction uniqueness are
        the first set's."""
        first = sets[0]
        cat = np.concatenate
        groups = {g: replace(gl, force=cat([s.groups[g].force for s in sets]),
                             torque=cat([s.groups[g].torque for s in sets]))
                  for g, gl in first.groups.items()}
        return FrameSet(states=sum((s.states for s in sets), ()),
                        time=cat([s.time for s in sets]), body_id=first.body_id,
                        position=cat([s.position for s in sets]),
                        orientation=cat([s.orientation for s in sets]),
                        rotation_from_input=cat([s.rotation_from_input for s in sets]),
                        groups=groups, outcomes=sum((s.outcomes for s in sets), ()),
                        stability=sum((s.stability for s in sets), ()),
                        measures=sum((s.measures for s in sets), ()))


@dataclass(frozen=True, eq=False)
class ComplianceRecord:
    """Compliance matrices of the frames: ``matrices`` (F, 6M, 6M), ``flags`` (F,) one of
    ``ok``, ``singular``, ``unstable``, ``fd_failed``, ``not_converged``; ``marker_id`` (M,)
    the markers; ``method`` (``exact`` / ``fd``)."""

    matrices: np.ndarray
    flags: tuple
    marker_id: np.ndarray
    method: str


@dataclass(frozen=True, eq=False)
class IdaSteps:
    """FIM_D's accepted IDA steps: one array per column (``time``, ``step_size`` float; the
    counters int), each (S,)."""

    columns: dict


@dataclass(frozen=True, eq=False)
class MkeamRun:
    """An MKEAM analysis (its iterations are history rows with MKEAM's columns): the restart
    points ``iterates`` ((pos, rot) each), the MKEAM point's ``position`` / ``orientation`` and
    the potential energy where it started."""

    iterates: tuple
    position: np.ndarray
    orientation: np.ndarray
    initial_potential_energy: float


@dataclass(frozen=True, eq=False)
class AnalysisHeader:
    """What names and judges one ``Simulate`` command: ``index`` (0-based), ``analysis_type``
    (``static`` / ``quasistatic``), ``method`` used, ``status`` (``converged`` / ``failed``),
    ``message``, effective ``settings``."""

    index: int
    analysis_type: str
    method: str
    status: str = STATUS_FAILED
    message: str = ""
    settings: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        return self.status == STATUS_CONVERGED


@dataclass(frozen=True, eq=False)
class AnalysisRecord(AnalysisHeader):
    """One ``Simulate`` command's outcome: the :class:`AnalysisHeader`, group ``attrs`` and
    the data: ``frames`` (:class:`FrameSet`),
    ``element_outputs`` (what the model's frame hooks give, stacked over the frames, named by
    their element types), the ``history``, the ``redundant`` rows (``model.row_info``
    entries), ``compliance``, ``method_data`` (:class:`IdaSteps` / :class:`MkeamRun`) and
    ``stage_totals`` (write the per-stage iteration totals)."""

    attrs: dict[str, Any] = field(default_factory=dict)
    frames: FrameSet | None = None
    element_outputs: dict = field(default_factory=dict)
    history: Any = None
    redundant: tuple = ()
    compliance: ComplianceRecord | None = None
    method_data: Any = None
    stage_totals: bool = False
