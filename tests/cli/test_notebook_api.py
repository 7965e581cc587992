"""The library API a notebook user expects: elements by label, ``r.time``, a short repr, the
API in ``dir(poise)``, ``python -m poise``, ``FileNotFoundError`` for a missing file, explicit
``poise.solve`` options with ``quiet``, misspelt DeckSpec attributes refused, ``sweep(client=)``,
labelled arrays and per-frame tables, and the missing-extra message."""
from __future__ import annotations

import inspect
import subprocess
import sys
from dataclasses import fields

import numpy as np
import pytest

import poise
from poise.core.errors import DeckError
from poise.results.hdf5 import read_results, write_results

from support.paths import DECKS


@pytest.fixture(scope="module")
def slider(tmp_path_factory):
    """The quasi-static slider-crank (labelled joints, 21 frames), solved and read back."""
    out = tmp_path_factory.mktemp("nb") / "slider.h5"
    write_results(poise.solve(DECKS / "qs_slider_crank_11b.xml", quiet=True), str(out))
    return read_results(str(out))


def test_elements_by_label(slider):
    ids = [int(i) for i in slider.analyses[-1].datasets["joints/id"]]
    labels = list(slider.analyses[-1].datasets["joints/label"])
    k = labels.index("Wrist pin")
    F, T = slider.reaction("Wrist pin", frame=None)
    F2, T2 = slider.reaction(ids[k], frame=None)
    np.testing.assert_array_equal(F, F2)
    np.testing.assert_array_equal(F, slider.analyses[-1].datasets["joints/force"][:, k])
    with pytest.raises(KeyError, match="no joint labelled 'Wrist pn'.*'Wrist pin'"):
        slider.reaction("Wrist pn")
    flabels = list(slider.analyses[-1].datasets["forces/label"])
    j = next(i for i, lab in enumerate(flabels) if lab)
    F3, _ = slider.reaction(flabels[j], group="forces")
    np.testing.assert_array_equal(F3, slider.analyses[-1].datasets["forces/force"][-1, j])


def test_plot_results_by_label(slider):
    pytest.importorskip("matplotlib")
    fig = poise.plot_results(slider, joints=["Wrist pin"])
    try:
        assert "joints/force" in fig.poise_panels
        legend = [t.get_text() for ax in fig.axes if ax.get_legend()
                  for t in ax.get_legend().get_texts()]
        assert any(t.startswith("Wrist pin (joint") for t in legend)
        assert not any(t.startswith("Crank pin") for t in legend)
    finally:
        import matplotlib.pyplot as plt
        plt.close(fig)


def test_time_and_short_repr(slider):
    np.testing.assert_allclose(slider.time, np.linspace(0.0, 1.0, 21), atol=1e-12)
    text = repr(slider)
    assert len(text) < 300 and "quasistatic FIM_D converged, 21 frames" in text
    assert len(repr(slider.analyses[0])) < 300 and "groups: bodies" in repr(slider.analyses[0])


def test_dir_and_python_m_poise():
    names = dir(poise)
    for n in ("solve", "sweep", "load_deck", "check_deck", "read_results", "write_results",
              "plot_results", "RunResult", "DeckSpec"):
        assert n in names
        assert getattr(poise, n) is not None
    assert "os" not in names and "annotations" not in names
    p = subprocess.run([sys.executable, "-m", "poise", "--version"], capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 0 and p.stdout.startswith("poise ")


def test_missing_files_raise_file_not_found(tmp_path):
    missing = tmp_path / "nope.xml"
    for call in (lambda: poise.solve(missing), lambda: poise.load_deck(missing),
                 lambda: poise.check_deck(missing),
                 lambda: poise.read_results(tmp_path / "nope.h5"),
                 lambda: poise.sweep(missing, {"Param_Static.max_num_iter": [5]})):
        with pytest.raises(FileNotFoundError, match="nope"):
            call()


def test_solve_lists_every_option_and_is_quiet_on_request(capfd):
    from poise.solvers.settings import StaticSettings
    params = inspect.signature(poise.solve).parameters
    for f in fields(StaticSettings):
        assert params[f.name].kind is inspect.Parameter.KEYWORD_ONLY, f.name
        assert f.name in poise.solve.__doc__, f.name
    assert params["quiet"].default is False
    r = poise.solve(DECKS / "qs_spring_ramp.xml", method="FIM_S", max_imbalance=1e-9,
                    quiet=True)
    assert r.status == "converged" and r.analyses[0].settings["max_imbalance"] == 1e-9
    assert capfd.readouterr().err == ""
    with pytest.raises(TypeError, match="did you mean 'method'"):
        poise.solve(DECKS / "qs_spring_ramp.xml", metod="FIM_S")


def test_misspelt_deckspec_attribute_is_an_error():
    spec = poise.load_deck(DECKS / "pendulum_multiturn.xml")
    spec.by_id("Force_SpringDamper")[1].attrs["stifness"] = 15000.0
    with pytest.raises(DeckError, match=r"unknown attribute 'stifness' of "
                                        r"<Force_SpringDamper> \(did you mean 'stiffness'\?\)"):
        poise.solve(spec, method="FIM_S")
    with pytest.raises(DeckError, match="stifness"):
        poise.check_deck(spec)


def test_sweep_passes_a_dask_client_on(monkeypatch, tmp_path):
    import poise.app.sweep as sw
    seen = {}
    monkeypatch.setattr(sw, "run_sweep", lambda *a, **kw: seen.update(kw) or [])
    client = object()
    assert poise.sweep(DECKS / "pendulum_multiturn.xml", {"Param_Static.max_num_iter": [5]},
                       out_dir=str(tmp_path), client=client) == []
    assert seen["client"] is client


def test_to_xarray_and_dataframe(slider):
    j = slider.to_xarray("joints")
    wrist = j.force.sel(label="Wrist pin")
    k = list(slider.analyses[-1].datasets["joints/label"]).index("Wrist pin")
    np.testing.assert_array_equal(wrist.values, slider.analyses[-1].datasets["joints/force"][:, k])
    assert wrist.dims == ("frame", "axis") and wrist.attrs["units"] == "N"
    np.testing.assert_array_equal(wrist.time.values, slider.time)
    assert float(wrist.sel(axis="x").sel(time=0.49, method="nearest")) == \
        pytest.approx(slider.reaction("Wrist pin", frame=10)[0][0])
    tree = slider.to_xarray()
    assert tree["analysis_000/steps"]["time"].dims == ("step",)      # not shadowed by frames'
    df = slider.to_dataframe()
    assert list(df.columns[:1]) == ["time"] and len(df) == 21
    np.testing.assert_array_equal(df["imbalance"], slider.analyses[-1].datasets["frames/imbalance"])
    assert df.attrs["units"]["time"] == "s"
    jf = slider.to_dataframe("joints")
    np.testing.assert_array_equal(jf[("force", "Wrist pin", "y")],
                                  slider.analyses[-1].datasets["joints/force"][:, k, 1])
    with pytest.raises(KeyError, match="groups"):
        slider.to_dataframe("nope")


def test_labelled_arrays_without_the_extra(slider, monkeypatch):
    """Without xarray: an ImportError (and usage error, exit 2) naming the pip command."""
    from poise.core.errors import UsageError
    monkeypatch.setitem(sys.modules, "xarray", None)
    with pytest.raises(ImportError, match=r"pip install 'poise\[xarray\]'") as e:
        slider.to_xarray()
    assert isinstance(e.value, UsageError) and "needs xarray" in str(e.value)
