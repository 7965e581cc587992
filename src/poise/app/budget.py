"""The memory a run will need, estimated before anything is solved; a run that would not fit is
refused with the estimate (never a ``MemoryError`` or an allocator failure after minutes).

Two things grow without bound with what a deck (or an option) asks for:

* quasi-static output frames: every frame's state, history and outputs are held until the
  results file is written, about :data:`FRAME_BYTES` plus :data:`FRAME_BYTES_PER_COORD` per
  coordinate per frame (measured: a 1-body ramp, 10-link and 50-link chains);
* compliance matrices requested for ``all`` markers or a marker list (``auto`` bounds itself,
  :mod:`poise.solvers.compliance`): per converged frame the 6M x 6M matrix plus the dense
  right-hand sides and solutions of the KKT solve, 2 x (nq + nc) x 6M numbers.

The budget is the memory available (``MemAvailable``), capped by ``POISE_MAX_MEMORY`` when set
(bytes, or with a unit: ``8G``, ``512M``, ``2GiB``): a run that fits the machine is never
refused by an arbitrary default. Too many
frames is the deck's problem (located at its ``Simulate``, exit 3); a compliance request the
deck's (``Param_Static compliance_markers``, exit 3) or the command line's (exit 2).
"""
from __future__ import annotations

import os
import re

from poise.core.errors import DeckError, Problem, UsageError

FRAME_BYTES = 24_000
FRAME_BYTES_PER_COORD = 250
ENV = "POISE_MAX_MEMORY"
#: estimates below this (a fraction of the interpreter's own memory) are not checked against the
#: memory available, only against ``POISE_MAX_MEMORY`` when set (a small solve reads no files)
SMALL_BYTES = 16 * 2**20
_UNITS = {"": 1, "B": 1, "K": 10**3, "M": 10**6, "G": 10**9, "T": 10**12,
          "KI": 2**10, "MI": 2**20, "GI": 2**30, "TI": 2**40}


def memory_budget() -> tuple[int, str]:
    """``(bytes, where it comes from)``: the memory available, or ``POISE_MAX_MEMORY`` where
    that is smaller."""
    text = os.environ.get(ENV, "").strip()
    limit, src = None, ""
    if text:
        m = re.fullmatch(r"(\d+(?:\.\d*)?(?:[eE][+-]?\d+)?)\s*([kKmMgGtT]?[iI]?)[bB]?", text)
        if not m:
            raise UsageError(f"{ENV}={text!r}: expected a size such as 8G, 512M or 2GiB")
        limit, src = int(float(m.group(1)) * _UNITS[m.group(2).upper()]), ENV
    avail = available_memory()
    if avail is not None and (limit is None or avail < limit):
        return avail, f"the memory available ({ENV} to cap it)"
    if limit is None:                   # nothing known about this machine: no refusal
        return 2**63, "no known limit"
    return limit, src


def available_memory() -> int | None:
    """``MemAvailable`` of /proc/meminfo (Linux), else the free physical pages, else None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def size_text(n: float) -> str:
    for unit, k in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= k:
            return f"{n / k:.3g} {unit}"
    return f"{n:.0f} B"


def check_memory(spec, model, analyses, overrides=None) -> None:
    """Refuse (see the module doc) the ``analyses`` (planned :class:`AnalysisRequest` of
    ``spec``, compiled ``model``) whose estimate exceeds :func:`memory_budget`."""
    from poise.solvers.compliance import select   # lazy: scipy-free here, but only if needed

    budget = None
    t_now = 0.0
    for req in analyses:
        n_frames = 1
        if req.kind == "quasistatic":
            times = req.output_times(t_now)
            n_frames = len(times)
            t_now = float(times[-1])
        frames = n_frames * (FRAME_BYTES + FRAME_BYTES_PER_COORD * model.nq)
        comp, m = 0, 0
        spec_markers = getattr(req.settings, "compliance_markers", "none")
        if spec_markers not in ("auto", "none"):
            rows, _ = select(model, req.settings)
            m = 0 if rows is None else 6 * len(rows)
            comp = n_frames * 8 * (m * m + 2 * (model.nq + model.nc) * m)
        if frames + comp <= SMALL_BYTES and not os.environ.get(ENV, "").strip():
            continue             # below what the process itself holds: no /proc/meminfo read
        if budget is None:
            budget, src = memory_budget()
        if frames + comp <= budget:
            continue
        need = f"more than the {size_text(budget)} of {src}"
        if comp > frames:
            msg = (f"the compliance matrix of {m // 6} markers ({m} x {m}"
                   + (f", {n_frames} frames" if n_frames > 1 else "")
                   + f") needs about {size_text(comp + frames)} of memory, {need}; name fewer "
                   "markers (compliance_markers=\"ID ID ...\") or none")
            if "compliance_markers" in (overrides or {}):
                raise UsageError(f"--compliance-markers: {msg}")
            src_el = next((e for e in reversed([*spec.model, *spec.commands])
                           if e.tag == "Param_Static"
                           and e.attrs.get("compliance_markers") is not None), req.simulate)
            raise DeckError(Problem(src_el.loc, msg))
        raise DeckError(Problem(req.simulate.loc, (
            f"{n_frames} output frames need about {size_text(frames + comp)} of memory "
            f"({model.nq} coordinates), {need}; a larger print_interval or a shorter run")))
