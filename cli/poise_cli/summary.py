"""Human and JSON summaries shared by the commands (no heavy imports at module level)."""
from __future__ import annotations

import json
import math
import os
import sys
from typing import Any

import click

#: version of the ``poise solve --json`` summary layout (bump on incompatible changes)
SUMMARY_VERSION = 1


def use_colour() -> bool:
    """Colour only on an interactive stderr, never when NO_COLOR is set."""
    try:
        return sys.stderr.isatty() and "NO_COLOR" not in os.environ
    except (AttributeError, ValueError):
        return False


def styled_status(status: str) -> str:
    if not use_colour():
        return status
    return click.style(status, fg="green" if status == "converged" else "red", bold=True)


def finite_or_none(x: Any) -> float | None:
    if x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _dataset(a, key):
    return a.datasets.get(key) if hasattr(a, "datasets") else None


def analysis_iterations(a) -> int | None:
    """Total Newton iterations of an AnalysisResult (sum over frames)."""
    it = _dataset(a, "frames/iterations")
    if it is not None and len(it):
        return int(sum(int(x) for x in it))
    it = _dataset(a, "iterations/iteration")
    if it is not None:
        return int(len(it))
    v = a.attrs.get("iterations") if hasattr(a, "attrs") else None
    return int(v) if v is not None else None


def analysis_imbalance(a) -> float | None:
    """Imbalance at the last frame."""
    imb = _dataset(a, "frames/imbalance")
    if imb is not None and len(imb):
        return finite_or_none(imb[-1])
    return finite_or_none(a.attrs.get("imbalance")) if hasattr(a, "attrs") else None


def analysis_time(timings: dict, index: int) -> float | None:
    """Wall time of one analysis if the runner recorded it in RunResult.timings."""
    for key in (f"analysis_{index:03d}", f"analysis_{index}", f"solve_{index:03d}"):
        if key in timings:
            return finite_or_none(timings[key])
    return None


def fmt_num(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def analysis_line(index: int, analysis_type: str, method: str, status: str,
                  iterations: int | None, imbalance: float | None, frames: int,
                  seconds: float | None, message: str = "") -> str:
    """``analysis 0: static FIM_S converged in 5 iterations, imbalance 3.2e-09, 0.012 s``."""
    verb = "in" if status == "converged" else "after"
    parts = [f"analysis {index}: {analysis_type} {method} {styled_status(status)}"]
    if iterations is not None:
        parts[0] += f" {verb} {iterations} iteration{'s' if iterations != 1 else ''}"
    if frames != 1:
        parts[0] += f" ({frames} frames)"
    parts.append(f"imbalance {fmt_num(imbalance)}")
    if seconds is not None:
        parts.append(f"{seconds:.3g} s")
    line = ", ".join(parts)
    if status != "converged" and message:
        line += f": {' '.join(message.split())}"
    return line


def analysis_summary(a) -> dict:
    """The per-analysis entry of the ``--json`` summary."""
    return {
        "index": int(a.index),
        "analysis_type": a.analysis_type,
        "method": a.method,
        "status": a.status,
        "message": a.message,
        "frames": a.n_frames,
        "iterations": analysis_iterations(a),
        "imbalance": analysis_imbalance(a),
    }


def solve_summary(deck: str, output: str | None, status: str, exit_code: int,
                  analyses: list[dict], timings: dict, warnings: list[str],
                  **extra: Any) -> dict:
    out = {
        "summary_version": SUMMARY_VERSION,
        "deck": deck,
        "output": output,
        "status": status,
        "exit_code": exit_code,
        "analyses": analyses,
        "timings": {k: finite_or_none(v) for k, v in timings.items()},
        "warnings": warnings,
    }
    out.update(extra)
    return out


def print_json(data: Any) -> None:
    click.echo(json.dumps(sanitize(data), indent=2, default=_json_default, allow_nan=False))


def _json_default(o: Any) -> Any:
    # numpy scalars/arrays without importing numpy here
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    if isinstance(o, (set, tuple)):
        return list(o)
    return str(o)


def sanitize(obj: Any) -> Any:
    """Replace non-finite floats by None recursively (strict JSON)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: sanitize(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [sanitize(v) for v in obj]
    if hasattr(obj, "tolist"):
        return sanitize(obj.tolist())
    return obj
