"""Pictures of a results file: convergence history and quasi-static time histories.

matplotlib with the Agg backend (no display needed). Used by ``poise plot``. Every axis carries
its unit from the deck's unit system (``units`` attribute of the results file): lengths,
forces, torques (force*length), time; angles are rad.
"""
from __future__ import annotations

import os

import numpy as np

from poise.core.atomic import atomic_output
from poise.core.errors import UsageError
from poise.core.extras import require
from poise.core.wording import shorten
from poise.results.hdf5 import read_results
from poise.results.schema import unit_symbols
from poise.viz.figure import LogFloor, legend_outside, new_figure, readable_ticks, \
    reference_lines

# the deck's unit names (one table, poise.results.schema): {"length": "mm", "force": "N", ...}
units_of = unit_symbols


def agg_pyplot():
    """pyplot on the Agg backend (pictures to files, no display needed); exit 2 with the pip
    command when matplotlib is not installed."""
    require("plot")             # exit 2 with the pip command in a lean install
    import matplotlib
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    return plt


def pick_analysis(res, index: int | None):
    if not res.analyses:
        raise UsageError("the results file has no analysis")
    if index is None:
        return res.analyses[-1]
    for a in res.analyses:
        if a.index == index:
            return a
    raise UsageError(f"--analysis {index}: the file has analyses "
                     f"{', '.join(str(a.index) for a in res.analyses)}")


def _columns(a, group: str, ids, what: str, res=None):
    """Indices and ids of ``ids`` (ids or deck labels) in ``group/id`` (all when ids is
    None)."""
    have = a.datasets.get(f"{group}/id")
    if have is None:
        if ids:
            raise UsageError(f"--{what}: the analysis has no {group}")
        return [], []
    have = [int(x) for x in np.asarray(have).ravel()]
    if ids is None:
        return list(range(len(have))), have
    labels = a.datasets.get(f"{group}/label")
    if labels is None and res is not None:
        labels = res.model_datasets.get(f"{group}/label")
    labels = [str(x) for x in np.asarray(labels if labels is not None else [""] * len(have))]
    rows = []
    for i in ids:
        if isinstance(i, str) and not i.lstrip("-").isdigit():
            hit = [k for k, lab in enumerate(labels) if lab == i]
            if len(hit) != 1:
                raise UsageError(f"--{what}: {'no' if not hit else 'more than one'} "
                                 f"{group[:-1] if group != 'bodies' else 'body'} labelled "
                                 f"{i!r}; labels: {', '.join(repr(x) for x in labels if x) or 'none'}")
            rows.append(hit[0])
        elif int(i) in have:
            rows.append(have.index(int(i)))
        else:
            raise UsageError(f"--{what}: no {group} id {i}; ids: {', '.join(map(str, have))}")
    return rows, [have[k] for k in rows]


def body_names(res) -> dict:
    """``{body id: label}``: the deck's ``label`` where present, else ``body <id>``."""
    md = res.model_datasets
    ids = [int(x) for x in np.asarray(md.get("bodies/id", []))]
    labels = [str(x) for x in np.asarray(md.get("bodies/label", [""] * len(ids)), dtype=str)]
    labels += [""] * (len(ids) - len(labels))
    return {i: (f"{lb} (body {i})" if lb.strip() else f"body {i}") for i, lb in zip(ids, labels)}


def element_names(res, a, group: str, noun: str) -> dict:
    """``{id: name}`` of ``group``'s elements: ``"<label> (<noun> <id>)"`` where the results
    carry a label (``<group>/label`` of the analysis, else of ``/model``), else
    ``"<noun> <id>"``."""
    for d in (a.datasets, res.model_datasets):
        ids, labels = d.get(f"{group}/id"), d.get(f"{group}/label")
        if ids is not None and labels is not None and len(labels) == len(ids):
            return {int(i): (f"{lb} ({noun} {int(i)})" if str(lb).strip() else f"{noun} {int(i)}")
                    for i, lb in zip(np.asarray(ids), np.asarray(labels, dtype=str))}
    return {}


def request_channels(a, cols) -> list:
    """Legend names of the 8 channels of each request column: the file's channel name and
    unit (``FX [N]``), else ``ch1``..``ch8``; an unused channel is ``None``."""
    names = a.datasets.get("requests/channel")
    units = a.datasets.get("requests/channel_units")
    out = []
    for c in cols:
        if names is None:
            out.append([f"ch{k}" for k in range(1, 9)])
            continue
        row = [str(x) for x in np.asarray(names)[c]]
        urow = [str(x) for x in np.asarray(units)[c]] if units is not None else [""] * 8
        out.append([(f"{n} [{u}]" if u else n) if n else None for n, u in zip(row, urow)])
    return out


# tolerance lines: distinct colour and style, named in the legend; lines at equal heights are
# interleaved (poise.viz.figure.reference_lines)
_TOL_STYLE = {"max_imbalance": dict(color="C3", ls="--", lw=1.2),
              "max_imbalance·L": dict(color="C3", ls=":", lw=1.2),
              "max_error": dict(color="C2", ls="-.", lw=1.2)}

#: figure width [in]; panel heights [in] (the iterations-per-frame panel is shorter)
WIDTH, PANEL, SHORT_PANEL = 10.0, 3.2, 1.76
#: above this many points a series is drawn as a line without markers
MARKERS_UP_TO = 200
#: legend names longer than this are shortened (a long deck label must not squeeze the data)
LABEL_CHARS = 60


def _tolerance_values(a, L: float | None) -> list:
    """``[(y, label, style)]`` of the tolerance lines a frame is measured against:
    ``max_imbalance`` for force rows, ``max_imbalance·L`` for moment rows (L the model size, so
    the same deck converges alike in m and mm) and ``max_error``."""
    st = a.settings or {}

    def num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0

    imb, err = st.get("max_imbalance"), st.get("max_error")
    out = []
    if num(imb):
        out.append((imb, "max_imbalance", f"max_imbalance = {imb:.0e} {{force}} (force rows)"))
        if L is not None and np.isfinite(L) and L > 0 and L != 1.0:
            out.append((imb * L, "max_imbalance·L",
                        f"max_imbalance·L = {imb * L:.1e} {{torque}} (moment rows)"))
    if num(err):
        out.append((err, "max_error", f"max_error = {err:.0e}"))
    return out


def _tolerances(ax, tols, U: dict):
    """Draw the tolerance lines. The plotted imbalance is the largest of both kinds of row, so a
    moment-row point between the two imbalance lines is within its tolerance."""
    reference_lines(ax, [(y, label.format(**U), dict(zorder=1, **_TOL_STYLE[key]))
                         for y, key, label in tols])


def _marked(fmt: str, n: int) -> str:
    """``fmt`` without its marker for long series (1001 frames of dots hide each other)."""
    return "-" if n > MARKERS_UP_TO else fmt


def _request_groups(a, cols, names):
    """The request channels of ``cols`` grouped by unit: ``[(unit or None, [(col, channel
    index, legend name)])]``; unit None: the file declares no channel units (older files), ""
    an expression channel (its unit is not declared)."""
    units = a.datasets.get("requests/channel_units")
    chans = request_channels(a, cols) if units is None else [
        [str(n) or None for n in np.asarray(a.datasets["requests/channel"])[c]] for c in cols]
    groups: dict = {}
    for c, name, row in zip(cols, names, chans):
        for j, comp in enumerate(row):
            if comp is None:
                continue
            u = None if units is None else str(np.asarray(units)[c][j])
            groups.setdefault(u, []).append((c, j, f"{name} {comp}"))
    return list(groups.items())


def plot_results(result_or_path, analysis: int | None = None, bodies=None, joints=None,
                 requests=None):
    """The matplotlib Figure of a RunResult or a results file: convergence (static: per
    iteration; quasi-static: final imbalance/error per frame against the tolerances, iterations
    per frame below) (+ MKEAM kinetic energy) and, for quasi-static runs, time histories of body
    positions, joint forces and request channels (one panel per channel unit).

    ``bodies``/``joints``/``requests``: lists of ids or deck labels (None: up to 4 of each for
    quasi-static runs). ``fig.poise_panels`` names the panels. Legends are right of their
    panel; log axes show exact zeros at a marked floor (poise.viz.figure).
    """
    plt = agg_pyplot()
    from matplotlib.ticker import MaxNLocator
    if isinstance(result_or_path, (str, bytes)) or hasattr(result_or_path, "__fspath__"):
        res = read_results(str(result_or_path))
    else:
        res = result_or_path
    a = pick_analysis(res, analysis)
    d = a.datasets
    U = units_of(res.units)
    qs = a.analysis_type == "quasistatic" and a.n_frames > 1
    panels = ["convergence"] + (["iterations"] if qs else [])
    has_ke = "iterations/kinetic_energy" in d and np.isfinite(
        np.asarray(d["iterations/kinetic_energy"], float)).any()
    if has_ke:
        panels.append("kinetic_energy")
    series = []
    if qs or bodies or joints or requests:
        bi, bids = _columns(a, "bodies", bodies, "bodies", res)
        ji, jids = _columns(a, "joints", joints, "joints", res)
        ri, rids = _columns(a, "requests", requests, "requests", res)
        if bodies is None:
            bi, bids = bi[:4], bids[:4]
        if joints is None:
            ji, jids = ji[:4], jids[:4]
        if requests is None:
            ri, rids = ri[:4], rids[:4]
        bn = body_names(res)
        if bi and "bodies/position" in d:
            names = [bn.get(i, f"body {i}") for i in bids]
            series.append(("bodies/position", "body CG position", f"position [{U['length']}]",
                           "bodies/position",
                           [(c, j, f"{n} {x}") for c, n in zip(bi, names)
                            for j, x in enumerate("xyz")]))
        if ji and "joints/force" in d:
            jn = element_names(res, a, "joints", "joint")
            names = [jn.get(i, f"joint {i}") for i in jids]
            series.append(("joints/force", "joint force on I body", f"force [{U['force']}]",
                           "joints/force",
                           [(c, j, f"{n} {x}") for c, n in zip(ji, names)
                            for j, x in enumerate("xyz")]))
        if ri and "requests/values" in d:
            rn = element_names(res, a, "requests", "request")
            groups = _request_groups(a, ri, [rn.get(i, f"request {i}") for i in rids])
            for u, chans in groups:
                if u is None:
                    key, title = "requests/values", "request channels"
                    ylab = f"value [{U['force']}, {U['length']}, {U['torque']}, rad by channel]"
                elif u:
                    key, title, ylab = f"requests/values [{u}]", f"request channels in {u}", \
                        f"value [{u}]"
                else:
                    key, title = "requests/values [expression]", \
                        "request channels: expressions (unit not declared in the deck)"
                    ylab = "value [unit not declared]"
                series.append((key, title, ylab, "requests/values", chans))
        panels += [s[0] for s in series]
    heights = [PANEL if p != "iterations" else SHORT_PANEL for p in panels]
    fig, axes = new_figure(plt, WIDTH, heights)
    fig.poise_panels = panels
    title = (f"{os.path.basename(str(res.deck))}  analysis {a.index}: {a.analysis_type} "
             f"{a.method} {a.status}")
    t = np.asarray(d.get("time", []), float)
    tlab = f"time [{U['time']}]"
    L = res.model_datasets.get("length_scale")
    L = float(np.asarray(L)) if L is not None else None
    tols = _tolerance_values(a, L)

    ax = axes[0]
    if qs:
        # one point per frame: the imbalance/error that frame ended with, against the tolerance
        imb = np.asarray(d.get("frames/imbalance", []), float)
        err = np.asarray(d.get("frames/error", []), float)
        floor = LogFloor(imb, err, [y for y, _, _ in tols])
        if len(imb):
            floor.plot(ax, t[:len(imb)], imb, _marked("o-", len(imb)), ms=3, color="C0",
                       lw=1.0, label="final imbalance per frame")
        if len(err):
            floor.plot(ax, t[:len(err)], err, _marked("s-", len(err)), ms=3, color="C1",
                       lw=1.0, label="final error per frame")
        conv = np.asarray(d.get("frames/converged", []), bool)
        if len(conv) and len(imb) and (~conv).any():
            bad = np.nonzero(~conv)[0]
            y = np.abs(np.nan_to_num(imb[bad], nan=1.0))
            ax.semilogy(t[bad], np.where(y > 0, y, floor.level), "x", color="r", ms=8,
                        label="frame not converged")
        _tolerances(ax, tols, U)
        floor.legend_entry(ax)
        ax.set_xlabel(tlab)
        ax.set_ylabel(f"imbalance [{U['force']}, {U['torque']}], error [1]")
        ax.set_title(title, fontsize=9)
        legend_outside(ax)
        ax2 = axes[1]
        it = np.asarray(d.get("frames/iterations", []), int)
        what = ("corrections onto the equilibrium per frame" if a.method == "FIM_D"
                else "iterations per frame")
        ax2.step(t[:len(it)], it, where="mid", color="C0", label=what)
        ax2.set_xlabel(tlab)
        ax2.set_ylabel("iterations")
        ax2.yaxis.set_major_locator(MaxNLocator(integer=True))
        # a little below 0: a run of zero-iteration frames is not hidden by the axis line
        ax2.set_ylim(bottom=-0.25, top=max(1, int(it.max()) if len(it) else 1) + 0.5)
        legend_outside(ax2)
        k = 2
    else:
        imb = np.asarray(d.get("iterations/imbalance", []), float)
        err = np.asarray(d.get("iterations/error", []), float)
        floor = LogFloor(imb, err, [y for y, _, _ in tols])
        if len(imb):
            floor.plot(ax, np.arange(len(imb)), imb, _marked("o-", len(imb)), ms=3, color="C0",
                       label="imbalance")
        if len(err):
            floor.plot(ax, np.arange(len(err)), err, _marked("s-", len(err)), ms=3, color="C1",
                       label="error")
        _tolerances(ax, tols, U)
        floor.legend_entry(ax)
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel(f"imbalance [{U['force']}, {U['torque']}], error [1]")
        ax.set_title(title, fontsize=9)
        if len(imb) or len(err):
            ax.set_xlim(-0.5, max(len(imb), len(err)) - 0.5)
            legend_outside(ax)
        else:
            ax.text(0.5, 0.5, "no iteration history", ha="center", transform=ax.transAxes)
        k = 1
    if has_ke:
        ax = axes[k]
        ke = np.asarray(d["iterations/kinetic_energy"], float)
        rows = np.nonzero(np.isfinite(ke))[0]
        floor = LogFloor(ke[rows])
        floor.plot(ax, rows, ke[rows], "o-", ms=4, color="C3", label="peak kinetic energy")
        floor.legend_entry(ax)
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlim(-0.5, len(ke) - 0.5)          # the iteration axis of the panel above
        ax.set_ylabel(f"kinetic energy [{U['energy']}]")
        ax.set_title("MKEAM: kinetic energy per iteration", fontsize=9)
        legend_outside(ax)
        k += 1
    for _key, label, ylab, dataset, chans in series:
        ax = axes[k]
        k += 1
        data = np.asarray(d[dataset], float)
        for c, j, name in chans:
            y = data[:, c, j]
            if np.isfinite(y).any() and np.ptp(np.nan_to_num(y)) + abs(np.nanmax(y)) > 0:
                ax.plot(t[:len(y)], y, "o-" if len(y) == 1 else "-", ms=4,
                        label=shorten(name, LABEL_CHARS))
        ax.set_xlabel(tlab)
        ax.set_ylabel(ylab)
        ax.set_title(label, fontsize=9)
        legend_outside(ax, fontsize=7)
    readable_ticks(fig)
    return fig


def write_plot(path: str, out: str, analysis: int | None = None, bodies=None, joints=None,
               requests=None, dpi: int = 100) -> dict:
    """Write the PNG of :func:`plot_results` atomically. Returns ``{"output", "panels", "width",
    "height"}``."""
    fig = plot_results(path, analysis=analysis, bodies=bodies, joints=joints, requests=requests)
    with atomic_output(out, (path,), keep_suffix=True) as tmp:
        fig.savefig(tmp, dpi=dpi)
    w, h = fig.get_size_inches() * dpi
    agg_pyplot().close(fig)
    return {"output": out, "panels": fig.poise_panels, "width": int(round(w)),
            "height": int(round(h))}

