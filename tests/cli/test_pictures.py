"""`poise plot`: units on every axis, element labels in legends, integer iteration ticks,
distinct tolerance lines (checked on the Figure objects, never on pixels)."""
import matplotlib
import pytest

from support.paths import DECKS


matplotlib.use("Agg", force=True)

from matplotlib.ticker import MaxNLocator  # noqa: E402

from poise.app.api import run_deck  # noqa: E402
from poise.viz.plot import plot_results, units_of  # noqa: E402


def _labels(fig):
    return [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]


def _legend_texts(ax):
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg else []


def test_units_of_a_unit_system():
    u = units_of("force=NEWTON mass=KILOGRAM length=MILLIMETER time=SECOND")
    assert (u["force"], u["length"], u["mass"], u["time"]) == ("N", "mm", "kg", "s")
    assert u["torque"] == "N*mm" and u["angle"] == "rad"


def test_static_convergence_plot_has_units_integer_ticks_and_tolerances():
    res = run_deck(str(DECKS / "pendulum_multiturn.xml"), {"method": "FIM_S"})
    fig = plot_results(res)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "iteration"
    assert isinstance(ax.xaxis.get_major_locator(), MaxNLocator)
    assert "[N, N*mm]" in ax.get_ylabel()                  # the deck is N-kg-mm-s
    texts = _legend_texts(ax)
    tol = [ln for ln in ax.get_lines() if ln.get_label().startswith("max_")]
    # force rows meet max_imbalance, moment rows max_imbalance*L: both lines are drawn
    assert {ln.get_label().split(" =")[0] for ln in tol} == {"max_imbalance", "max_imbalance·L",
                                                              "max_error"}
    styles = {(ln.get_color(), ln.get_linestyle()) for ln in tol}
    assert len(styles) == 3                                # distinct lines
    L = float(res.model_datasets["length_scale"])
    imb = res.analyses[-1].settings["max_imbalance"]
    levels = {ln.get_label().split(" =")[0]: ln.get_ydata()[0] for ln in tol}
    assert levels["max_imbalance"] == pytest.approx(imb)
    assert levels["max_imbalance·L"] == pytest.approx(imb * L)
    assert any(t.startswith("max_imbalance = ") and t.endswith("N (force rows)") for t in texts)


@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_quasistatic_plot_labels_units_and_bodies(method):
    res = run_deck(str(DECKS / "qs_slider_crank_11b.xml"), {"method": method})
    fig = plot_results(res)
    assert fig.poise_panels[:2] == ["convergence", "iterations"]
    for xlabel, _ in _labels(fig):
        assert xlabel == "time [s]"
    pos = fig.axes[fig.poise_panels.index("bodies/position")]
    assert pos.get_ylabel() == "position [mm]"
    texts = " ".join(_legend_texts(pos))
    for label in ("Crank (body 2)", "Rod (body 3)", "Slider (body 4)"):
        assert label in texts
    jf = fig.axes[fig.poise_panels.index("joints/force")]
    assert jf.get_ylabel() == "force [N]"
    it = fig.axes[fig.poise_panels.index("iterations")]
    assert isinstance(it.yaxis.get_major_locator(), MaxNLocator)
    # one point per frame on the convergence panel, not one line per frame
    conv = fig.axes[0]
    per_frame = [ln for ln in conv.get_lines() if ln.get_label().startswith("final imbalance")]
    assert len(per_frame) == 1
    assert len(per_frame[0].get_xdata()) == len(res.analyses[0].datasets["time"])


def test_legends_name_joints_and_request_channels():
    """Joint and request legends use the deck labels and the file's channel names (not
    ``joint 1`` / ``request 1 ch4``)."""
    res = run_deck(str(DECKS / "qs_slider_crank_11b.xml"), {"method": "FIM_S"})
    fig = plot_results(res)
    jf = " | ".join(_legend_texts(fig.axes[fig.poise_panels.index("joints/force")]))
    assert "Crank pivot (joint 1)" in jf
    # the deck's one request is an EXPRESSION request: its channels have no declared unit
    rq = _legend_texts(fig.axes[fig.poise_panels.index("requests/values [expression]")])
    assert rq and all(" ch" not in t for t in rq)
    assert any(t.startswith("Driving torque on crank (global) (request 1) expr") for t in rq)
