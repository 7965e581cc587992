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


def analysis_time(timings: dict, index: int) -> float | None:
    """Wall time of one analysis if the runner recorded it in RunResult.timings."""
    for key in (f"analysis_{index:03d}", f"analysis_{index}", f"solve_{index:03d}"):
        if key in timings:
            return finite_or_none(timings[key])
    return None


def fmt_num(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def analysis_line(summary: dict, seconds: float | None = None) -> str:
    """The one-line summary (:func:`poise.results.summary.summary_line`) of an analysis summary
    dict (:func:`analysis_summary` or ``read_summary``), the status word coloured on a TTY."""
    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.results.summary import AnalysisSummary, summary_line
    return summary_line(AnalysisSummary.from_dict(summary), seconds=seconds, style=styled_status)


def analysis_summary(a) -> dict:
    """The per-analysis entry of the ``--json`` summary: the fields of
    :class:`poise.results.summary.AnalysisSummary` (the same as ``poise show --json``)."""
    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.results.summary import summarize
    return summarize(a).as_dict()


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


def table_json(command: str, out_dir: str, exit_code: int, rows: list, reused: int,
               table: str, **extra) -> dict:
    """The ``--json`` document of ``poise batch`` and ``poise sweep`` (one shape): ``command``,
    ``out_dir``, ``exit_code``, ``n`` rows, ``counts`` per status, ``reused`` (rows read back
    from up-to-date files: batch's skipped, sweep's resumed), ``table`` (the CSV path), the
    ``rows`` themselves, then the command's own keys (``extra``)."""
    counts: dict = {}
    for r in rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    return {"command": command, "out_dir": out_dir, "exit_code": exit_code, "n": len(rows),
            "counts": counts, "reused": reused, "table": table, **extra,
            "rows": sanitize(list(rows))}
