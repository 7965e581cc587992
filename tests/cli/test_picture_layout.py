"""Pictures read well at the size users get: legends outside the data and inside the image,
tick labels that do not overlap, equal tolerance lines both visible, exact zeros on log axes
shown at a marked floor, request panels naming their unit. Geometry from the renderer's
extents at the saved size (never pixels)."""
from __future__ import annotations

import math

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg", force=True)

from poise.app.api import run_deck  # noqa: E402
from poise.viz.plot import plot_results  # noqa: E402
from poise.viz.workprec import work_precision_figure  # noqa: E402

from support.paths import DECKS  # noqa: E402


@pytest.fixture(scope="module")
def runs():
    """Results of each picture type: static FIM_S, static MKEAM (kinetic energy panel), a
    1001-frame quasi-static run, a quasi-static run with request channels."""
    return {
        "static": run_deck(str(DECKS / "pendulum_multiturn.xml"), {"method": "FIM_S"}),
        "mkeam": run_deck(str(DECKS / "mkeam_pendulum_multiturn.xml")),
        "qs1001": run_deck(str(DECKS / "bench" / "slider_crank_qs_1000.xml"),
                           {"method": "FIM_D"}),
        "requests": run_deck(str(DECKS / "qs_slider_crank_11b.xml"), {"method": "FIM_S"}),
        "follower": run_deck(str(DECKS / "expr_follower_load.xml")),
    }


def _saved_geometry(fig, dpi=100):
    """Draw ``fig`` as ``savefig(dpi=dpi)`` would and return its renderer."""
    fig.set_dpi(dpi)
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def _inside(inner, outer, tol=0.5) -> bool:
    return (inner.x0 >= outer.x0 - tol and inner.y0 >= outer.y0 - tol
            and inner.x1 <= outer.x1 + tol and inner.y1 <= outer.y1 + tol)


def _disjoint(a, b) -> bool:
    return a.x1 <= b.x0 or b.x1 <= a.x0 or a.y1 <= b.y0 or b.y1 <= a.y0


def _tick_labels(axis, r):
    lo, hi = sorted(axis.get_view_interval())
    k = 0 if axis.axis_name == "x" else 1
    out = []
    for t in [*axis.get_majorticklabels(), *axis.get_minorticklabels()]:
        p = t.get_position()[k]
        if t.get_visible() and t.get_text() and lo - 1e-9 * abs(lo) <= p <= hi + 1e-9 * abs(hi):
            out.append((t.get_text(), t.get_window_extent(r)))
    return out


def _check_layout(fig):
    """Every legend outside its axes and inside the figure; every title, axis label and tick
    label inside the figure; no two tick labels of an axis touch."""
    r = _saved_geometry(fig)
    fb = fig.bbox
    n_legends = 0
    for ax in fig.axes:
        leg = ax.get_legend()
        if leg is not None:
            n_legends += 1
            lb = leg.get_window_extent(r)
            assert _disjoint(lb, ax.bbox), f"legend covers the data of '{ax.get_title()}'"
            assert _inside(lb, fb), f"legend cut off the image: {lb} vs {fb}"
        for t in (ax.title, ax.xaxis.label, ax.yaxis.label):
            if t.get_text():
                assert _inside(t.get_window_extent(r), fb), t.get_text()
        for axis in (ax.xaxis, ax.yaxis):
            labels = _tick_labels(axis, r)
            for text, bb in labels:
                assert _inside(bb, fb), text
            for i, (ta, a) in enumerate(labels):
                for tb, b in labels[i + 1:]:
                    assert _disjoint(a, b), f"tick labels {ta!r} and {tb!r} overlap"
    return n_legends


@pytest.mark.parametrize("name", ["static", "mkeam", "qs1001", "requests"])
def test_plot_legends_outside_the_data_and_inside_the_image(runs, name):
    fig = plot_results(runs[name])
    assert _check_layout(fig) == len(fig.axes)          # every panel has its legend


def test_plot_with_every_request_and_long_labels(runs):
    res = runs["follower"]
    for a in res.analyses:           # a very long request label must not squeeze the data away
        labels = a.datasets.get("requests/label")
        if labels is not None:
            a.datasets["requests/label"] = np.array(["a rather long request label " * 4]
                                                    * len(labels))
    fig = plot_results(res, bodies=[2], requests=[1, 2, 3])
    _check_layout(fig)
    for ax in fig.axes:
        assert ax.bbox.width > 0.45 * fig.bbox.width      # the data keeps most of the width


def test_the_1001_frame_plot_shows_the_worst_frame_uncovered(runs):
    res = runs["qs1001"]
    a = res.analyses[-1]
    assert a.n_frames == 1001
    fig = plot_results(res)
    r = _saved_geometry(fig)
    ax = fig.axes[0]
    imb = np.asarray(a.datasets["frames/imbalance"], float)
    t = np.asarray(a.datasets["time"], float)
    k = int(np.nanargmax(imb))
    px = ax.transData.transform((t[k], imb[k]))
    assert ax.bbox.contains(*px)
    assert not ax.get_legend().get_window_extent(r).contains(*px)


def test_equal_imbalance_and_error_lines_stay_distinguishable(runs):
    res = runs["static"]
    st = res.analyses[-1].settings
    assert st["max_imbalance"] == st["max_error"]          # the deck's two tolerances agree
    ax = plot_results(res).axes[0]
    lines = {ln.get_label().split(" =")[0]: ln for ln in ax.get_lines()
             if ln.get_label().startswith("max_")}
    a, b = lines["max_imbalance"], lines["max_error"]
    assert a.get_ydata()[0] == b.get_ydata()[0]
    assert a.get_color() != b.get_color()
    # one dash pattern, shifted: their dashes alternate, neither hides the other
    (oa, sa), (ob, sb) = a._unscaled_dash_pattern, b._unscaled_dash_pattern
    assert sa == sb and len(sa) == 2
    on, period = sa[0], sum(sa)
    shift = (ob - oa) % period
    assert on <= shift <= period - on


def test_exact_zeros_drawn_at_a_marked_floor(runs):
    res = runs["static"]
    d = res.analyses[-1].datasets
    err = np.asarray(d["iterations/error"], float)
    imb = np.asarray(d["iterations/imbalance"], float)
    assert (err == 0).any()                  # the start row records an exact 0 error
    ax = plot_results(res).axes[0]
    line = next(ln for ln in ax.get_lines() if ln.get_label() == "error")
    y = np.asarray(line.get_ydata(), float)
    positive = np.concatenate([err[err > 0], imb[imb > 0]])
    floor = y[err == 0]
    assert np.all(np.isfinite(floor)) and np.all(floor > 0)
    assert np.all(floor < positive.min())                # below everything, not a gap
    assert np.all(floor >= positive.min() / 100)         # and close enough to read
    marks = [ln for ln in ax.get_lines() if ln.get_marker() == "v" and len(ln.get_xdata())]
    assert any(np.allclose(ln.get_ydata(), floor[0]) for ln in marks)
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(t.startswith("exactly 0 (drawn at") for t in texts)
    ax.set_ylim(ax.get_ylim())
    assert ax.get_ylim()[0] <= floor.min()               # the floor is on the axis


def test_request_panels_name_their_units(runs):
    res = runs["follower"]
    fig = plot_results(res, requests=[1, 2, 3])
    a = res.analyses[-1]
    units = np.asarray(a.datasets["requests/channel_units"]).astype(str)
    req = [(p, ax) for p, ax in zip(fig.poise_panels, fig.axes) if p.startswith("requests/")]
    declared = {u for u in units.ravel() if u}
    shown = {ax.get_ylabel() for _, ax in req}
    assert {f"value [{u}]" for u in declared} <= shown          # N, N*mm, mm, rad
    assert "value [unit not declared]" in shown                  # the expression channels
    for p, ax in req:
        u = p[p.index("[") + 1:-1]
        assert ax.get_ylabel() == (f"value [{u}]" if u != "expression"
                                   else "value [unit not declared]")


def _row(m, tol, t, err, status="converged"):
    return {"method": m, "tol": tol, "solve_s": {"median": t}, "error_abs": err,
            "status": status}


@pytest.mark.parametrize("rows", [
    # a narrow time range (minor ticks labelled) and rungs on top of each other
    [_row("FIM_S", 1e-2, 0.0231, 1e-6), _row("FIM_S", 1e-4, 0.0227, 5e-13),
     _row("FIM_S", 1e-6, 0.0222, 5e-13), _row("FIM_S", 1e-8, 0.0236, 0.0),
     _row("FIM_S", 1e-10, 0.0255, 0.0)],
    # several decades, two methods, a failed rung
    [_row("FIM_S", 1e-2, 0.0231, 1e-6), _row("FIM_S", 1e-6, 0.03, 1e-10),
     _row("MKEAM", 1e-2, 0.93, 2e-12, "failed"), _row("MKEAM", 1e-4, 1.02, 2e-12),
     _row("MKEAM", 1e-6, 1.12, 2e-12), _row("FIM_D", 1e-2, 3.0, 1e-3),
     _row("FIM_D", 1e-6, 40.0, 1e-7)],
    # less than a decade of errors and times
    [_row("FIM_S", 1e-2, 0.51, 3e-6), _row("FIM_S", 1e-4, 0.55, 2e-6),
     _row("FIM_S", 1e-6, 0.62, 1.5e-6)],
], ids=["narrow", "decades", "tight"])
def test_work_precision_ticks_and_rung_labels_do_not_overlap(rows):
    fig = work_precision_figure(rows, "mm", "deck.xml", "FIM_S at 1e-12")
    _check_layout(fig)
    ax = fig.axes[0]
    r = fig.canvas.get_renderer()
    assert len(_tick_labels(ax.xaxis, r)) >= 2            # the time axis is still labelled
    notes = [t for t in ax.texts if t.get_text()]
    boxes = [t.get_window_extent(r) for t in notes]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            assert _disjoint(a, b), [t.get_text() for t in notes]
    named = ", ".join(t.get_text() for t in notes)
    for x in rows:                                        # every rung is named somewhere
        tol = f"{x['tol']:.0e}"
        assert tol in named or " ... " in named, (tol, named)
    assert math.isfinite(ax.get_ylim()[0]) and ax.get_ylim()[0] > 0
