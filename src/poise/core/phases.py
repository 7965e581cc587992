"""Wall time per solver phase of the current run (what each results file records in ``/timings``).

The runner calls :func:`reset` before solving and :func:`snapshot` after; the instrumented
places add their elapsed time with :func:`add`:

* ``evaluate`` — element kernels and the residual (``Model.evaluate``, batched frame outputs);
* ``assemble`` — KKT Jacobian assembly (``Model.jacobian``: local tangents + scatter);
* ``factorise`` — LU factorisations (``solvers.linalg.Factor``).

Phases are exclusive (none is timed inside another), so ``solve - (evaluate + assemble +
factorise)`` is the rest: linear solves, line search, retraction, IDA/RATTLE bookkeeping,
outputs. The clock is per thread (sweeps may solve in threads).
"""
from __future__ import annotations

import threading
import time

PHASES = ("evaluate", "assemble", "factorise")

_local = threading.local()
now = time.perf_counter


def _acc() -> dict:
    acc = getattr(_local, "acc", None)
    if acc is None:
        acc = _local.acc = dict.fromkeys(PHASES, 0.0)
    return acc


def reset() -> None:
    """Start a run: all phases at zero."""
    _local.acc = dict.fromkeys(PHASES, 0.0)


def add(phase: str, seconds: float) -> None:
    """Add ``seconds`` of wall time to ``phase``."""
    acc = _acc()
    acc[phase] = acc.get(phase, 0.0) + seconds


def snapshot() -> dict:
    """Copy of the accumulated times [s] per phase."""
    return dict(_acc())
