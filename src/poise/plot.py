"""Pictures of a results file: convergence history and quasi-static time histories.

matplotlib with the Agg backend (no display needed). Used by ``poise plot``.
"""
from __future__ import annotations

import numpy as np

from poise.errors import UsageError


def _agg():
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


def plot_results(path: str, out: str, analysis: int | None = None, bodies=None, joints=None,
                 requests=None, dpi: int = 100) -> dict:
    """Write a PNG: convergence history (+ MKEAM kinetic energy) and, for quasi-static runs,
    time histories of body positions, joint forces and request channels.

    ``bodies``/``joints``/``requests``: lists of ids (None: up to 4 of each for quasi-static
    runs). Returns ``{"output", "panels", "width", "height"}``.
    """
    from poise.results.hdf5 import read_results
    res = read_results(path)
    a = pick_analysis(res, analysis)
    d = a.datasets
    plt = _agg()
    panels = ["convergence"]
    has_ke = "iterations/kinetic_energy" in d and np.isfinite(
        np.asarray(d["iterations/kinetic_energy"], float)).any()
    if has_ke:
        panels.append("kinetic_energy")
    qs = a.analysis_type == "quasistatic" and a.n_frames > 1
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
        if bi and "bodies/position" in d:
            series.append(("bodies/position", "body position", bi, bids, "xyz"))
        if ji and "joints/force" in d:
            series.append(("joints/force", "joint force on I body", ji, jids, "xyz"))
        if ri and "requests/values" in d:
            series.append(("requests/values", "request channels", ri, rids,
                           [str(k) for k in range(1, 9)]))
        panels += [s[0] for s in series]
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.2 * len(panels)), squeeze=False)
    axes = axes[:, 0]
    title = f"{res.deck}  analysis {a.index}: {a.analysis_type} {a.method} {a.status}"

    # convergence history
    ax = axes[0]
    imb = np.asarray(d.get("iterations/imbalance", []), float)
    err = np.asarray(d.get("iterations/error", []), float)
    n = np.arange(len(imb))
    if len(imb):
        ax.semilogy(n, _pos(imb), "o-", ms=3, label="imbalance")
    if len(err):
        ax.semilogy(np.arange(len(err)), _pos(err), "s-", ms=3,
                    label="error")
    fr = np.asarray(d.get("iterations/frame", []), int)
    if len(fr) > 1:
        starts = np.nonzero(np.diff(fr))[0] + 1
        for s in starts[:200]:
            ax.axvline(s - 0.5, color="0.8", lw=0.6, zorder=0)
        if len(starts):
            ax.plot([], [], color="0.8", lw=0.6, label="new frame")
    st = a.settings or {}
    for key, style in (("max_imbalance", "--"), ("max_error", ":")):
        if isinstance(st.get(key), (int, float)) and st[key] > 0:
            ax.axhline(st[key], color="k", ls=style, lw=0.7, label=key)
    ax.set_xlabel("iteration (all frames)")
    ax.set_ylabel("scaled residual")
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
        ax.semilogy(rows, _pos(ke[rows]), "o-", ms=4, color="C3")
        ax.set_xlabel("iteration")
        ax.set_ylabel(f"peak kinetic energy [{_unit(res.units, 'energy')}]")
        ax.set_title("MKEAM: kinetic energy per iteration", fontsize=9)
        k += 1
    t = np.asarray(d.get("time", []), float)
    for key, label, cols, ids, comps in series:
        ax = axes[k]
        k += 1
        data = np.asarray(d[key], float)
        for c, i in zip(cols, ids):
            for j, comp in enumerate(comps):
                y = data[:, c, j]
                if np.isfinite(y).any() and np.ptp(np.nan_to_num(y)) + abs(np.nanmax(y)) > 0:
                    ax.plot(t[:len(y)], y, label=f"{i}.{comp}")
        ax.set_xlabel("time")
        ax.set_title(label, fontsize=9)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, ncol=4)
    fig.tight_layout()
    from poise.atomic import atomic_output
    with atomic_output(out, (path,), keep_suffix=True) as tmp:
        fig.savefig(tmp, dpi=dpi)
    w, h = fig.get_size_inches() * dpi
    plt.close(fig)
    return {"output": out, "panels": panels, "width": int(round(w)), "height": int(round(h))}


def _pos(v):
    """Non-positive values are not drawn on a log axis (exact zeros, e.g. an exact start)."""
    v = np.abs(np.asarray(v, float))
    return np.where(v > 0, v, np.nan)


def _unit(units: str, what: str) -> str:
    u = dict(p.split("=", 1) for p in str(units).split() if "=" in p)
    if what == "energy" and u:
        return f"{u.get('force', 'force').lower()}·{u.get('length', 'length').lower()}"
    return "deck units"
