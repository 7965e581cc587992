"""The work-precision diagram of ``poise bench DECK --plot FILE.png``.

One line per method through its ladder rungs: the CG-position error against the reference
solution (vertical, deck length unit) against the median solve time (horizontal, seconds),
log-log; rungs that did not converge are marked with a red cross, rungs that hit the reference
exactly (error 0) are drawn at a floor below the others and the legend says so.
"""
from __future__ import annotations

import numpy as np

from poise.core.atomic import atomic_output
from poise.core.errors import UsageError
from poise.viz.plot import _agg

MARKS = {"FIM_S": "o-", "MKEAM": "s-", "FIM_D": "^-"}


def work_precision_figure(rows: list[dict], length_unit: str, title: str = "",
                          reference: str = ""):
    """The matplotlib Figure (rows: ``poise bench`` rows with ``method``, ``tol``,
    ``solve_s['median']``, ``error_abs``, ``status``)."""
    plt = _agg()
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    errs = [r["error_abs"] for r in rows if r.get("error_abs")]
    floor = min(errs) / 10 if errs else 1e-16
    for m in dict.fromkeys(r["method"] for r in rows):
        pts = [r for r in rows if r["method"] == m and r.get("solve_s")]
        x = np.array([r["solve_s"]["median"] for r in pts], float)
        y = np.array([r.get("error_abs") if r.get("error_abs") is not None else np.nan
                      for r in pts], float)
        exact = y == 0
        y = np.where(exact, floor, y)
        label = m + (f" (error 0 drawn at {floor:.0e})" if exact.any() else "")
        ln, = ax.loglog(x, y, MARKS.get(m, "x-"), label=label)
        for r, xi, yi in zip(pts, x, y):
            ax.annotate(f"{r['tol']:.0e}", (xi, yi), textcoords="offset points",
                        xytext=(4, 4), fontsize=7, color=ln.get_color())
        bad = [k for k, r in enumerate(pts) if r["status"] != "converged"]
        if bad:
            ax.plot(x[bad], y[bad], "rx", ms=10, label=f"{m}: not converged")
    ax.set_xlabel("solve time [s]")
    ax.set_ylabel(f"CG position error [{length_unit}]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title((title + "\n" if title else "") + "work-precision"
                 + (f" (reference: {reference})" if reference else ""), fontsize=10)
    fig.tight_layout()
    return fig


def check_picture_format(out: str, option: str = "--plot") -> None:
    """Refuse, before any work, a picture path whose extension matplotlib cannot write
    (:class:`UsageError`, exit 2); no extension means PNG. PGF is refused (it needs LaTeX)."""
    import os
    _agg()
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
    _agg().close(fig)
