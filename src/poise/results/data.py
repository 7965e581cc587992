"""In-memory results of a run, mirroring the HDF5 layout one to one.

A :class:`RunResult` holds one :class:`AnalysisResult` per ``Simulate`` command. Each analysis
stores its datasets in a flat dict keyed by the HDF5 path *relative to its group*
(``"bodies/position"``, ``"iterations/imbalance"``, ...), so that new capabilities add datasets
without touching the writer. ``docs/results-format.md`` documents every key.

Conventions: leading axis F = output frames; B bodies; J joints; R requests. Lengths, forces and
torques are in the deck's units; angles in radians.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

STATUS_CONVERGED = "converged"
STATUS_FAILED = "failed"


@dataclass
class AnalysisResult:
    """Result of one ``Simulate`` command.

    Attributes
    ----------
    index : int
        0-based position among the deck's analyses (group ``/analysis_{index:03d}``).
    analysis_type : str
        ``"static"`` or ``"quasistatic"``.
    method : str
        Method actually used (``"FIM_S"``, ``"FIM_D"``, ``"MKEAM"``).
    status : str
        ``"converged"`` or ``"failed"``.
    message : str
        Human-readable outcome (why it failed, fallbacks taken, ...).
    settings : dict
        Effective settings after defaults < deck < CLI (written as JSON).
    datasets : dict[str, numpy.ndarray]
        HDF5 path relative to the analysis group -> array. String arrays are numpy ``str_``
        arrays; the writer stores them as variable-length UTF-8.
    attrs : dict[str, Any]
        Extra group attributes (scalars or strings).
    """

    index: int
    analysis_type: str
    method: str
    status: str = STATUS_FAILED
    message: str = ""
    settings: dict = field(default_factory=dict)
    datasets: dict[str, np.ndarray] = field(default_factory=dict)
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        return self.status == STATUS_CONVERGED

    @property
    def n_frames(self) -> int:
        t = self.datasets.get("time")
        return 0 if t is None else int(len(t))

    def settings_json(self) -> str:
        return json.dumps(self.settings, sort_keys=True, default=str)


@dataclass
class RunResult:
    """Result of running every analysis of one deck.

    Attributes
    ----------
    deck : str
        Deck path as given.
    deck_sha256 : str
    units : str
        Description of the deck's units, e.g. ``"force=NEWTON mass=KILOGRAM length=MILLIMETER time=SECOND"``.
    active_effects : list[str]
        Element families compiled and evaluated for this deck (e.g. ``["gravity", "revolute",
        "spring_translational"]``).
    command : str
        The command line (or API call) that produced the run.
    analyses : list[AnalysisResult]
    model_datasets : dict[str, numpy.ndarray]
        Datasets under ``/model`` (ids, labels, masses, dof counts ...).
    timings : dict[str, float]
        Wall time per phase in seconds (``parse``, ``compile``, ``solve``, ``write``, ...).
    counts : dict[str, int]
        Residual / Jacobian / factorisation counts summed over the run.
    warnings : list[str]
        Located warnings emitted while reading/compiling the deck.
    attrs : dict[str, Any]
        Extra root attributes (e.g. ``run_overrides``, ``sweep_case_hash`` written by
        ``poise batch``/``poise sweep``); may not clash with the reserved root attributes.
    """

    deck: str
    deck_sha256: str
    units: str = ""
    active_effects: list[str] = field(default_factory=list)
    command: str = ""
    analyses: list[AnalysisResult] = field(default_factory=list)
    model_datasets: dict[str, np.ndarray] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def status(self) -> str:
        if self.analyses and all(a.converged for a in self.analyses):
            return STATUS_CONVERGED
        return STATUS_FAILED

    @property
    def exit_code(self) -> int:
        return 0 if self.status == STATUS_CONVERGED else 1
