"""The work-precision diagram of ``poise bench DECK --plot FILE.png``.

One line per method through its ladder rungs: the CG-position error against the reference
solution (vertical, deck length unit) against the median solve time (horizontal, seconds),
log-log; rungs that did not converge are marked with a red cross, rungs that hit the reference
exactly (error 0) are drawn at a floor below the others, marked, and the legend says so.
"""
from __future__ import annotations

import numpy as np

from poise.core.atomic import atomic_output
from poise.core.errors import UsageError
from poise.viz.figure import LogFloor, legend_outside, new_figure, readable_ticks
from poise.viz.plot import agg_pyplot

MARKS = {"FIM_S": "o-", "MKEAM": "s-", "FIM_D": "^-"}
#: figure size [in]: the data area stays about 6.4 x 4.8 in beside the legend
WIDTH, HEIGHT = 8.4, 5.0


def work_precision_figure(rows: list[dict], length_unit: str, title: str = "",
                          reference: str = ""):
    """The matplotlib Figure (rows: ``poise bench`` rows with ``method``, ``tol``,
    ``solve_s['median']``, ``error_abs``, ``status``). The legend is right of the data; rungs
    that land on the same spot share one label (``1e-04, 1e-06``); errors of exactly 0 are drawn
    at a floor (poise.viz.figure.LogFloor); tick labels do not overlap."""
    plt = agg_pyplot()
    fig, (ax,) = new_figure(plt, WIDTH, [HEIGHT])
    floor = LogFloor([r["error_abs"] for r in rows if r.get("error_abs") is not None])
    marks = []
    for m in dict.fromkeys(r["method"] for r in rows):
        pts = [r for r in rows if r["method"] == m and r.get("solve_s")]
        x = np.array([r["solve_s"]["median"] for r in pts], float)
        y = np.array([r.get("error_abs") if r.get("error_abs") is not None else np.nan
                      for r in pts], float)
        ln = floor.plot(ax, x, y, MARKS.get(m, "x-"), label=m)
        ax.set_xscale("log")
        y = np.where(y == 0, floor.level, y)
        marks += [(xi, yi, r["tol"], ln.get_color()) for r, xi, yi in zip(pts, x, y)]
        bad = [k for k, r in enumerate(pts) if r["status"] != "converged"]
        if bad:
            ax.plot(x[bad], y[bad], "rx", ms=10, label=f"{m}: not converged")
    floor.legend_entry(ax)
    ax.set_xlabel("solve time [s]")
    ax.set_ylabel(f"CG position error [{length_unit}]")
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax)
    ax.set_title((title + "\n" if title else "") + "work-precision"
                 + (f" (reference: {reference})" if reference else ""), fontsize=10)
    readable_ticks(fig)             # also the draw that fixes the data -> pixel transform
    _label_rungs(ax, marks)
    return fig


def _label_rungs(ax, marks, dx: float = 30.0, dy: float = 10.0) -> None:
    """Label each rung with its tolerance. Rungs of one line whose points lie within ``dx`` x
    ``dy`` pixels of each other (their labels would collide) share one label: ``1e-04, 1e-06``,
    or ``1e-02 ... 1e-10`` for three or more consecutive rungs. A label that would still touch
    an earlier one goes below its point."""
    if not marks:
        return
    xy = ax.transData.transform([(x, y) for x, y, _, _ in marks])
    done, placed = set(), []
    r = ax.figure.canvas.get_renderer()
    for i, (x, y, _, colour) in enumerate(marks):
        if i in done or not np.all(np.isfinite(xy[i])):
            continue
        group = [j for j in range(i, len(marks)) if j not in done and marks[j][3] == colour
                 and abs(xy[j][0] - xy[i][0]) <= dx and abs(xy[j][1] - xy[i][1]) <= dy]
        done.update(group)
        tols = [f"{marks[j][2]:.0e}" for j in group]
        run = group == list(range(group[0], group[0] + len(group)))
        text = f"{tols[0]} ... {tols[-1]}" if len(tols) >= 3 and run else ", ".join(tols)
        t = ax.annotate(text, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7,
                        color=colour)
        if any(t.get_window_extent(r).overlaps(p) for p in placed):
            t.set_position((4, -11))
        placed.append(t.get_window_extent(r))


def check_picture_format(out: str, option: str = "--plot") -> None:
    """Refuse, before any work, a picture path whose extension matplotlib cannot write
    (:class:`UsageError`, exit 2); no extension means PNG. PGF is refused (it needs LaTeX)."""
    import os
    agg_pyplot()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    ext = os.path.splitext(os.fspath(out))[1].lower().lstrip(".")
    formats = sorted(set(FigureCanvasAgg.get_supported_filetypes()) - {"pgf"})
    if ext and ext not in formats:
        raise UsageError(f"{option} {os.fspath(out)!r}: format {ext!r} is not supported; "
                         f"expected one of {', '.join(formats)} (e.g. FILE.png)")


def write_work_precision(rows: list[dict], out: str, length_unit: str, title: str = "",
                         reference: str = "", dpi: int = 100) -> None:
    """Write :func:`work_precision_figure` to ``out`` (PNG), atomically."""
    fig = work_precision_figure(rows, length_unit, title, reference)
    with atomic_output(out, keep_suffix=True) as tmp:
        fig.savefig(tmp, dpi=dpi)
    agg_pyplot().close(fig)
