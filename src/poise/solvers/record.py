"""What an analysis hands on: its record (status, message, datasets, attributes).

Solvers build an :class:`AnalysisRecord`; :mod:`poise.results` wraps it
(:class:`poise.results.data.AnalysisResult` adds the readers) and writes it. Keys are HDF5
paths relative to the analysis group (``docs/results-format.md``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

STATUS_CONVERGED = "converged"
STATUS_FAILED = "failed"


@dataclass
class AnalysisRecord:
    """One ``Simulate`` command's outcome: ``index`` (0-based), ``analysis_type`` (``static`` /
    ``quasistatic``), ``method`` used, ``status`` (``converged`` / ``failed``), ``message``,
    effective ``settings``, ``datasets`` (path -> array) and group ``attrs``."""

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
