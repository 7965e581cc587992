"""Benchmark and animation pictures, checked on the Figure objects (never on pixels):
``poise bench --plot`` (the work-precision diagram) and ``poise animate`` (--every,
--max-frames, units on the axes, every marker of a body drawn)."""
from __future__ import annotations

import json
import sys

import h5py
import matplotlib
import numpy as np
import pytest
from click.testing import CliRunner

from support.paths import DECKS


matplotlib.use("Agg", force=True)

from poise.viz.animate import animate_results, pick_frames  # noqa: E402
from poise.viz.workprec import work_precision_figure  # noqa: E402
from poise_cli.main import cli  # noqa: E402


def _row(m, tol, t, err, status="converged"):
    return {"method": m, "tol": tol, "solve_s": {"median": t}, "error_abs": err,
            "status": status}


def test_work_precision_figure_lines_axes_legend():
    rows = [_row("FIM_S", 1e-2, 0.01, 1e-3), _row("FIM_S", 1e-6, 0.02, 1e-7),
            _row("FIM_S", 1e-10, 0.03, 0.0),
            _row("MKEAM", 1e-2, 1.0, 1e-4, "failed"), _row("MKEAM", 1e-6, 2.0, 1e-8)]
    fig = work_precision_figure(rows, "mm", "deck.xml", "FIM_S at 1e-12")
    ax = fig.axes[0]
    assert ax.get_xscale() == ax.get_yscale() == "log"
    assert ax.get_xlabel() == "solve time [s]" and ax.get_ylabel() == "CG position error [mm]"
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    fims = next(v for k, v in lines.items() if k.startswith("FIM_S"))
    np.testing.assert_allclose(fims.get_xdata(), [0.01, 0.02, 0.03])
    assert fims.get_ydata()[2] < 1e-7                 # error 0: drawn below the others
    np.testing.assert_allclose(lines["MKEAM"].get_ydata(), [1e-4, 1e-8])
    assert "MKEAM: not converged" in lines           # a red cross on the failed rung
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend[:2] == ["FIM_S", "MKEAM"] and legend[-1].startswith("exactly 0 (drawn at")
    assert "FIM_S at 1e-12" in ax.get_title()


def test_bench_plot_cli(tmp_path):
    png, jl = tmp_path / "wp.png", tmp_path / "wp.jsonl"
    r = CliRunner().invoke(cli, ["bench", str(DECKS / "pendulum_multiturn.xml"), "--repeat", "1",
                                 "--tolerances", "1e-2,1e-8", "--plot", str(png), "--out",
                                 str(jl)])
    assert r.exit_code == 0, r.output
    assert png.stat().st_size > 0
    rows = [json.loads(x) for x in jl.read_text().splitlines()]
    assert [x["tol"] for x in rows] == [1e-2, 1e-8]
    # the reference is the tightest FIM_S rung by default: every rung has an error
    assert all(x["error"] is not None and x["reference"] == "FIM_S 1e-12" for x in rows)
    assert rows[0]["error_abs"] > rows[1]["error_abs"]
    assert f"wrote {png}" in r.stderr


def test_bench_plot_without_matplotlib_exits_2(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    r = CliRunner().invoke(cli, ["bench", str(DECKS / "pendulum_multiturn.xml"), "--plot",
                                 str(tmp_path / "x.png")])
    assert r.exit_code == 2 and "pip install 'poise[plot]'" in r.stderr


def test_pick_frames():
    assert pick_frames(10) == list(range(10))
    # default: at most 200 spread evenly, first and last kept; --every 1: all of them
    d = pick_frames(1001)
    assert len(d) == 200 and d[0] == 0 and d[-1] == 1000
    assert max(np.diff(d)) - min(np.diff(d)) <= 1                 # evenly spread
    assert pick_frames(1001, every=1) == list(range(1001))
    assert pick_frames(10, every=4) == [0, 4, 8, 9]             # the last frame is kept
    assert pick_frames(101, max_frames=5) == [0, 25, 50, 75, 100]
    assert pick_frames(101, every=10, max_frames=3) == [0, 50, 100]


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    d = tmp_path_factory.mktemp("anim")
    out = {}
    for name, method in (("pendulum_multiturn", "FIM_S"), ("qs_slider_crank_rev", None)):
        p = d / f"{name}.h5"
        args = ["solve", str(DECKS / f"{name}.xml"), "-o", str(p), "-q"]
        r = CliRunner().invoke(cli, args + (["--method", method] if method else []))
        assert r.exit_code == 0, r.output
        out[name] = p
    return out


def test_animate_draws_every_marker_with_units(results, tmp_path):
    p = results["pendulum_multiturn"]
    info = animate_results(str(p), str(tmp_path / "a.png"), keep_figure=True, progress=False)
    ax = info["figure"].axes[0]
    assert ax.get_xlabel() == "global X [mm]" and ax.get_ylabel() == "global Y [mm]"
    with h5py.File(p) as f:
        P = f["analysis_000/bodies/position"][-1][0]
        R = f["analysis_000/bodies/orientation"][-1][0]
        ids = list(f["model/markers/id"][()])
        off = f["model/markers/offset"][ids.index(202)]          # "Pendulum tip"
    tip = P + R @ off
    ends = [(ln.get_xdata()[-1], ln.get_ydata()[-1]) for ln in ax.get_lines()
            if len(ln.get_xdata()) == 2]
    assert any(np.allclose(e, tip[:2]) for e in ends), (ends, tip)
    assert len(ends) == 2                  # CG -> hinge and CG -> tip
    matplotlib.pyplot.close(info["figure"])


def test_animate_every_and_max_frames(results, tmp_path):
    gif = tmp_path / "q.gif"
    r = CliRunner().invoke(cli, ["animate", str(results["qs_slider_crank_rev"]), "-o", str(gif),
                                 "--every", "5", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["frames"] == 11                  # 51 frames: 0, 5, ..., 50
    r = CliRunner().invoke(cli, ["animate", str(results["qs_slider_crank_rev"]), "-o", str(gif),
                                 "--max-frames", "4", "--json", "-q"])
    assert r.exit_code == 0 and json.loads(r.stdout)["frames"] == 4 and r.stderr == ""
