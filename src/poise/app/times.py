"""Output times of a quasi-static ``Simulate`` (the planning step; solvers get the times).

``print_array_id`` (a ``Reference_Array`` of type PRINT, times inside [start, end]), else
``num_steps`` (equal intervals of (end - start)/num_steps), else ``print_interval`` (default
0.01). The start time is always the first frame (conventions.md) and the end time the last one.
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import DeckError, Problem

DEFAULT_PRINT_INTERVAL = 0.01


#: Most output frames one quasi-static Simulate may ask for (a located deck error beyond).
MAX_FRAMES = 1_000_000


def _check_frames(sim, n: float, what: str) -> None:
    if not n <= MAX_FRAMES:          # also inf/nan: times that overflow
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
