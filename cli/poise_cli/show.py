"""``poise show``: summarise a results file."""
from __future__ import annotations

from collections import Counter

import click

from poise.core.wording import ELLIPSIS
from poise_cli.errors import EXIT_USAGE, report_exception
from poise_cli.options import debug_option, json_option
from poise_cli.summary import analysis_line, analysis_time, fmt_num, print_json, sanitize

#: per-frame stability classes are listed one by one up to this many frames
MAX_LISTED_FRAMES = 20


def _stability_lines(stab: list[str] | None) -> list[str]:
    if not stab:
        return []
    counts = Counter(stab)
    line = "  stability: " + ", ".join(f"{k} x{v}" for k, v in sorted(counts.items()))
    out = [line]
    if len(stab) <= MAX_LISTED_FRAMES and len(counts) > 1:
        out.append("  stability per frame: " + " ".join(stab))
    return out


def _at(a: dict, what: str) -> str:
    """`` at frame 412 (t=0.41)``: the worst frame of ``what`` when there are several."""
    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.results.summary import frame_at
    return frame_at(a.get("frames", 0), a.get(f"{what}_frame"), a.get(f"{what}_time"))


def format_summary(s: dict) -> list[str]:
    lines = [
        f"file: {s['file']} ({s['format']} v{s['format_version']}, poise {s['poise_version']})",
        f"deck: {s['deck']} (sha256 {str(s['deck_sha256'])[:16]}{ELLIPSIS})",
        f"status: {s['status']}",
    ]
    if s.get("units"):
        lines.append(f"units: {s['units']}")
    lines.append("active effects: " + (", ".join(s["active_effects"]) or "(none)"))
    if s.get("command"):
        lines.append(f"command: {s['command']}")
    for a in s["analyses"]:
        lines.append(analysis_line({**a, "message": ""}, analysis_time(s["timings"], a["index"])))
        if a.get("message"):
            lines.append(f"  message: {' '.join(str(a['message']).split())}")
        lines.append(f"  frames: {a['frames']}, worst imbalance {fmt_num(a['imbalance'])}"
                     f"{_at(a, 'imbalance')}, worst error {fmt_num(a['error'])}{_at(a, 'error')}")
        if a.get("reactions_unique") is not None:
            lines.append(f"  reactions unique: {'yes' if a['reactions_unique'] else 'no'}")
        red = a["datasets"].get("redundant/id")
        if red is not None:
            lines.append(f"  redundant equations: {red[0] if red else 0}")
        lines += _stability_lines(a.get("stability"))
        if a.get("stability_class") in ("unstable", "neutral") and a.get("stability_modes"):
            lines.append(f"  {a['stability_class']} modes{_at(a, 'stability')}: "
                         f"{a['stability_modes']}")
    if s["timings"]:
        lines.append(timings_line(s["timings"]))
    if s["counts"]:
        lines.append("counts: " + ", ".join(f"{k} {v}" for k, v in s["counts"].items()))
    if s["warnings"]:
        lines.append(f"warnings: {len(s['warnings'])}")
        lines += [f"  {w}" for w in s["warnings"]]
    return lines


@click.command(short_help="Summarise an HDF5 results file.")
@click.argument("results", type=click.Path(exists=True, dir_okay=False, readable=True))
@json_option
@debug_option
def show(results, as_json, debug):
    """Summarise the HDF5 results file RESULTS: status, per analysis type, method, frames,
    iterations, final imbalance, stability classes, timings and counts.

    Exit code 0 when the file was read (whatever the run's status), 2 when RESULTS is not a
    poise results file.
    """
    ctx = click.get_current_context()
    try:
        # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
        from poise.results.hdf5 import ResultsFormatError, read_summary
        try:
            summary = read_summary(results)
        except ResultsFormatError as exc:
            click.echo(f"poise: error: {exc}", err=True)
            if as_json:
                print_json({"file": results, "exit_code": EXIT_USAGE,
                            "status": "usage_error", "error": str(exc)})
            ctx.exit(EXIT_USAGE)
            return
    except (Exception, KeyboardInterrupt) as exc:
        if isinstance(exc, click.exceptions.Exit):
            raise
        code, info = report_exception(exc, debug=debug)
        if as_json:
            print_json({"file": results, "exit_code": code, **info})
        ctx.exit(code)
        return
    if as_json:
        print_json(sanitize(summary))
    else:
        click.echo("\n".join(format_summary(summary)))
    ctx.exit(0)


def timings_line(t: dict) -> str:
    """``parse, compile, solve (its phases + the rest), write, import; total`` — what the run's
    accuracy cost (``import``: modules first needed by this run, outside the other phases).
    ``analysis_*`` entries are parts of ``solve`` (printed per analysis above)."""
    def num(k):
        v = t.get(k)
        return float(v) if isinstance(v, (int, float)) else None
    parts = []
    for k in ("parse", "compile"):
        if num(k) is not None:
            parts.append(f"{k} {num(k):.3g}")
    solve = num("solve")
    if solve is not None:
        ph = [(k[6:], num(k)) for k in t if k.startswith("solve_") and num(k) is not None]
        inner = ", ".join(f"{k} {v:.3g}" for k, v in ph)
        if ph:
            inner += f", other {max(solve - sum(v for _, v in ph), 0.0):.3g}"
        parts.append(f"solve {solve:.3g}" + (f" ({inner})" if inner else ""))
    if num("write") is not None:
        parts.append(f"write {num('write'):.3g}")
    if num("import") is not None:
        parts.append(f"import {num('import'):.3g}")
    known = {"parse", "compile", "solve", "write", "import"}
    parts += [f"{k} {num(k):.3g}" for k in t if k not in known and not k.startswith(
        ("solve_", "analysis_")) and num(k) is not None]
    total = sum(num(k) or 0.0 for k in ("parse", "compile", "solve", "write", "import"))
    return "timings [s]: " + ", ".join(parts) + f"; total {total:.3g}"

