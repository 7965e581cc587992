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

_ABBREV = {
    # length
    "MILLIMETER": "mm", "CENTIMETER": "cm", "METER": "m", "KILOMETER": "km", "NANOMETER": "nm",
    "MICROMETER": "µm", "INCH": "in", "FOOT": "ft", "MILE": "mi", "YARD": "yd", "ANGSTROM": "Å",
    "MILLIINCH": "mil", "MILS": "mil", "MICROINCH": "µin",
    # force
    "NEWTON": "N", "KNEWTON": "kN", "KILONEWTON": "kN", "MEGANEWTON": "MN", "CENTINEWTON": "cN",
    "MILLINEWTON": "mN", "MICRONEWTON": "µN", "NANONEWTON": "nN", "POUND_FORCE": "lbf",
    "KPOUND_FORCE": "kip", "OUNCE_FORCE": "ozf", "DYNE": "dyn", "KILOGRAM_FORCE": "kgf",
    "POUNDAL": "pdl",
    # mass
    "KILOGRAM": "kg", "GRAM": "g", "MILLIGRAM": "mg", "MEGAGRAM": "Mg", "TONNE": "t",
    "MICROGRAM": "µg", "NANOGRAM": "ng", "POUND_MASS": "lbm", "SLUG": "slug", "OUNCE_MASS": "oz",
    "KPOUND_MASS": "klbm", "US_TON": "ton", "SLINCH": "slinch",
    # time
    "SECOND": "s", "MILLISECOND": "ms", "MICROSECOND": "µs", "NANOSECOND": "ns", "MINUTE": "min",
    "HOUR": "h", "DAY": "d",
}


def units_of(units) -> dict:
    """``{"length", "force", "mass", "time", "torque", "energy", "angle"}`` unit strings of the
    deck's unit system (the results file's ``units`` attribute, e.g. ``force=NEWTON ...``)."""
    u = dict(p.split("=", 1) for p in str(units or "").split() if "=" in p)
    out = {k: _ABBREV.get(str(u.get(k, "")).upper(), str(u.get(k, "")).lower() or f"{k} unit")
           for k in ("length", "force", "mass", "time")}
    out["torque"] = out["energy"] = f"{out['force']}*{out['length']}"
    out["angle"] = "rad"
    return out


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


def _columns(a, group: str, ids, what: str):
    """Indices of ``ids`` in ``group/id`` (all when ids is None)."""
    have = a.datasets.get(f"{group}/id")
    if have is None:
        if ids:
            raise UsageError(f"--{what}: the analysis has no {group}")
        return [], []
    have = [int(x) for x in np.asarray(have).ravel()]
    if ids is None:
        return list(range(len(have))), have
    bad = [i for i in ids if i not in have]
    if bad:
        raise UsageError(f"--{what}: no {group} id {', '.join(map(str, bad))}; "
                         f"ids: {', '.join(map(str, have))}")
    return [have.index(i) for i in ids], list(ids)


def body_names(res) -> dict:
    """``{body id: label}``: the deck's ``label`` where present, else ``body <id>``."""
    md = res.model_datasets
    ids = [int(x) for x in np.asarray(md.get("bodies/id", []))]
    labels = [str(x) for x in np.asarray(md.get("bodies/label", [""] * len(ids)), dtype=str)]
    labels += [""] * (len(ids) - len(labels))
    return {i: (f"{lb} (body {i})" if lb.strip() else f"body {i}") for i, lb in zip(ids, labels)}


# tolerance lines: distinct colour and style, named in the legend
_TOL_STYLE = {"max_imbalance": dict(color="C3", ls="--", lw=1.2),
              "max_error": dict(color="C2", ls="-.", lw=1.2)}


def _tolerances(ax, a):
    st = a.settings or {}
    for key, style in _TOL_STYLE.items():
        v = st.get(key)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0:
            ax.axhline(v, label=f"{key} = {v:.0e}", zorder=1, **style)


def plot_results(result_or_path, analysis: int | None = None, bodies=None, joints=None,
                 requests=None):
    """The matplotlib Figure of a RunResult or a results file: convergence (static: per
    iteration; quasi-static: final imbalance/error per frame against the tolerances, iterations
    per frame below) (+ MKEAM kinetic energy) and, for quasi-static runs, time histories of body
    positions, joint forces and request channels.

    ``bodies``/``joints``/``requests``: lists of ids (None: up to 4 of each for quasi-static
    runs). ``fig.poise_panels`` names the panels.
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
        bi, bids = _columns(a, "bodies", bodies, "bodies")
        ji, jids = _columns(a, "joints", joints, "joints")
        ri, rids = _columns(a, "requests", requests, "requests")
        if bodies is None:
            bi, bids = bi[:4], bids[:4]
        if joints is None:
            ji, jids = ji[:4], jids[:4]
        if requests is None:
            ri, rids = ri[:4], rids[:4]
        bn = body_names(res)
        if bi and "bodies/position" in d:
            series.append(("bodies/position", "body CG position", f"position [{U['length']}]",
                           bi, [bn.get(i, f"body {i}") for i in bids], "xyz"))
        if ji and "joints/force" in d:
            series.append(("joints/force", "joint force on I body", f"force [{U['force']}]",
                           ji, [f"joint {i}" for i in jids], "xyz"))
        if ri and "requests/values" in d:
            series.append(("requests/values", "request channels",
                           f"value [{U['force']}, {U['length']}, {U['torque']}, rad by channel]",
                           ri, [f"request {i}" for i in rids],
                           [f"ch{k}" for k in range(1, 9)]))
        panels += [s[0] for s in series]
    heights = [1.0 if p != "iterations" else 0.55 for p in panels]
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.2 * sum(heights)), squeeze=False,
                             gridspec_kw=dict(height_ratios=heights))
    axes = axes[:, 0]
    fig.poise_panels = panels
    title = f"{res.deck}  analysis {a.index}: {a.analysis_type} {a.method} {a.status}"
    t = np.asarray(d.get("time", []), float)
    tlab = f"time [{U['time']}]"

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
        _tolerances(ax, a)
        ax.set_xlabel(tlab)
        ax.set_ylabel(f"imbalance [{U['force']}, {U['torque']}], error [1]")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=8, loc="best")
        ax2 = axes[1]
        it = np.asarray(d.get("frames/iterations", []), int)
        ax2.step(t[:len(it)], it, where="mid", color="C0", label="Newton iterations per frame")
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
        _tolerances(ax, a)
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
        for c, name in zip(cols, names):
            for j, comp in enumerate(comps):
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
