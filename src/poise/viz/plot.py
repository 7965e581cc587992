"""Pictures of a results file: convergence history and quasi-static time histories.

matplotlib with the Agg backend (no display needed). Used by ``poise plot``. Every axis carries
its unit from the deck's unit system (``units`` attribute of the results file): lengths,
forces, torques (force*length), time; angles are rad.
"""
from __future__ import annotations

import numpy as np

from poise.core.atomic import atomic_output
from poise.core.errors import UsageError
from poise.core.extras import require
from poise.results.hdf5 import read_results
from poise.results.schema import unit_symbols

# the deck's unit names (one table, poise.results.schema): {"length": "mm", "force": "N", ...}
units_of = unit_symbols


def _agg():
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


# tolerance lines: distinct colour and style, named in the legend
_TOL_STYLE = {"max_imbalance": dict(color="C3", ls="--", lw=1.2),
              "max_imbalance·L": dict(color="C3", ls=":", lw=1.2),
              "max_error": dict(color="C2", ls="-.", lw=1.2)}


def _tolerances(ax, a, L: float | None, U: dict):
    """The tolerance lines a frame is measured against: ``max_imbalance`` for force rows,
    ``max_imbalance·L`` for moment rows (L the model size, so the same deck converges alike
    in m and mm) and ``max_error``. The plotted imbalance is the largest of both kinds of row,
    so a moment-row point between the two imbalance lines is within its tolerance."""
    st = a.settings or {}

    def num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0

    imb, err = st.get("max_imbalance"), st.get("max_error")
    if num(imb):
        ax.axhline(imb, label=f"max_imbalance = {imb:.0e} {U['force']} (force rows)", zorder=1,
                   **_TOL_STYLE["max_imbalance"])
        if L is not None and np.isfinite(L) and L > 0 and L != 1.0:
            ax.axhline(imb * L, label=f"max_imbalance·L = {imb * L:.1e} {U['torque']} "
                       "(moment rows)", zorder=1, **_TOL_STYLE["max_imbalance·L"])
    if num(err):
        ax.axhline(err, label=f"max_error = {err:.0e}", zorder=1, **_TOL_STYLE["max_error"])


def plot_results(result_or_path, analysis: int | None = None, bodies=None, joints=None,
                 requests=None):
    """The matplotlib Figure of a RunResult or a results file: convergence (static: per
    iteration; quasi-static: final imbalance/error per frame against the tolerances, iterations
    per frame below) (+ MKEAM kinetic energy) and, for quasi-static runs, time histories of body
    positions, joint forces and request channels.

    ``bodies``/``joints``/``requests``: lists of ids or deck labels (None: up to 4 of each for
    quasi-static runs). ``fig.poise_panels`` names the panels.
    """
    plt = _agg()
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
            series.append(("bodies/position", "body CG position", f"position [{U['length']}]",
                           bi, [bn.get(i, f"body {i}") for i in bids], ["xyz"] * len(bi)))
        if ji and "joints/force" in d:
            jn = element_names(res, a, "joints", "joint")
            series.append(("joints/force", "joint force on I body", f"force [{U['force']}]",
                           ji, [jn.get(i, f"joint {i}") for i in jids], ["xyz"] * len(ji)))
        if ri and "requests/values" in d:
            rn = element_names(res, a, "requests", "request")
            chans = request_channels(a, ri)
            ylab = ("value [unit per channel: see legend]" if "requests/channel_units" in d
                    else f"value [{U['force']}, {U['length']}, {U['torque']}, rad by channel]")
            series.append(("requests/values", "request channels", ylab,
                           ri, [rn.get(i, f"request {i}") for i in rids], chans))
        panels += [s[0] for s in series]
    heights = [1.0 if p != "iterations" else 0.55 for p in panels]
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.2 * sum(heights)), squeeze=False,
                             gridspec_kw=dict(height_ratios=heights))
    axes = axes[:, 0]
    fig.poise_panels = panels
    title = f"{res.deck}  analysis {a.index}: {a.analysis_type} {a.method} {a.status}"
    t = np.asarray(d.get("time", []), float)
    tlab = f"time [{U['time']}]"
    L = res.model_datasets.get("length_scale")
    L = float(np.asarray(L)) if L is not None else None

    ax = axes[0]
    if qs:
        # one point per frame: the imbalance/error that frame ended with, against the tolerance
        imb = np.asarray(d.get("frames/imbalance", []), float)
        err = np.asarray(d.get("frames/error", []), float)
        if len(imb):
            ax.semilogy(t[:len(imb)], _pos(imb), "o-", ms=3, color="C0",
                        label="final imbalance per frame")
        if len(err):
            ax.semilogy(t[:len(err)], _pos(err), "s-", ms=3, color="C1",
                        label="final error per frame")
        conv = np.asarray(d.get("frames/converged", []), bool)
        if len(conv) and len(imb) and (~conv).any():
            bad = np.nonzero(~conv)[0]
            ax.semilogy(t[bad], _pos(np.nan_to_num(imb[bad], nan=1.0)), "x", color="r", ms=8,
                        label="frame not converged")
        _tolerances(ax, a, L, U)
        ax.set_xlabel(tlab)
        ax.set_ylabel(f"imbalance [{U['force']}, {U['torque']}], error [1]")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=8, loc="best")
        ax2 = axes[1]
        it = np.asarray(d.get("frames/iterations", []), int)
        what = ("corrections onto the equilibrium per frame" if a.method == "FIM_D"
                else "iterations per frame")
        ax2.step(t[:len(it)], it, where="mid", color="C0", label=what)
        ax2.set_xlabel(tlab)
        ax2.set_ylabel("iterations")
        ax2.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax2.set_ylim(bottom=0, top=max(1, int(it.max()) if len(it) else 1) + 0.5)
        ax2.legend(fontsize=8, loc="upper right")
        k = 2
    else:
        imb = np.asarray(d.get("iterations/imbalance", []), float)
        err = np.asarray(d.get("iterations/error", []), float)
        if len(imb):
            ax.semilogy(np.arange(len(imb)), _pos(imb), "o-", ms=3, color="C0",
                        label="imbalance")
        if len(err):
            ax.semilogy(np.arange(len(err)), _pos(err), "s-", ms=3, color="C1", label="error")
        _tolerances(ax, a, L, U)
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel(f"imbalance [{U['force']}, {U['torque']}], error [1]")
        ax.set_title(title, fontsize=9)
        if len(imb) or len(err):
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, "no iteration history", ha="center", transform=ax.transAxes)
        k = 1
    if has_ke:
        ax = axes[k]
        ke = np.asarray(d["iterations/kinetic_energy"], float)
        rows = np.nonzero(np.isfinite(ke))[0]
        ax.semilogy(rows, _pos(ke[rows]), "o-", ms=4, color="C3", label="peak kinetic energy")
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylabel(f"kinetic energy [{U['energy']}]")
        ax.set_title("MKEAM: kinetic energy per iteration", fontsize=9)
        ax.legend(fontsize=8)
        k += 1
    for key, label, ylab, cols, names, comps in series:
        ax = axes[k]
        k += 1
        data = np.asarray(d[key], float)
        for c, name, col_comps in zip(cols, names, comps):
            for j, comp in enumerate(col_comps):
                if comp is None:               # an unused request channel
                    continue
                y = data[:, c, j]
                if np.isfinite(y).any() and np.ptp(np.nan_to_num(y)) + abs(np.nanmax(y)) > 0:
                    ax.plot(t[:len(y)], y, label=f"{name} {comp}")
        ax.set_xlabel(tlab)
        ax.set_ylabel(ylab)
        ax.set_title(label, fontsize=9)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    return fig


def write_plot(path: str, out: str, analysis: int | None = None, bodies=None, joints=None,
               requests=None, dpi: int = 100) -> dict:
    """Write the PNG of :func:`plot_results` atomically. Returns ``{"output", "panels", "width",
    "height"}``."""
    fig = plot_results(path, analysis=analysis, bodies=bodies, joints=joints, requests=requests)
    with atomic_output(out, (path,), keep_suffix=True) as tmp:
        fig.savefig(tmp, dpi=dpi)
    w, h = fig.get_size_inches() * dpi
    _agg().close(fig)
    return {"output": out, "panels": fig.poise_panels, "width": int(round(w)),
            "height": int(round(h))}


def _pos(v):
    """Non-positive values are not drawn on a log axis (exact zeros, e.g. an exact start)."""
    v = np.abs(np.asarray(v, float))
    return np.where(v > 0, v, np.nan)
