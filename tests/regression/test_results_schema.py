"""The results schema (poise.results.schema): every example deck's results file conforms, the
format document is generated from it, labels and request channels are written.

Conformance: every object declared, dtype and rank as declared, shape symbols consistent
within an analysis (F frames, B bodies, ...), each dataset's ``units`` attribute the declared
unit in the deck's units, every non-optional object present.
"""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from poise.results import schema
from poise.results.hdf5 import write_results
from poise.app.runner import run

from support.paths import ROOT


DECKS = sorted(p.name for p in (ROOT / "decks").glob("*.xml"))


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """deck name -> its results file (every example deck, user code allowed)."""
    tmp = tmp_path_factory.mktemp("schema")
    cache: dict[str, Path] = {}

    def get(name: str) -> Path:
        if name not in cache:
            out = tmp / (name + ".h5")
            write_results(run(str(ROOT / "decks" / name), allow_user_code=True), str(out))
            cache[name] = out
        return cache[name]
    return get


@pytest.mark.parametrize("name", DECKS)
def test_example_deck_results_conform(written, name):
    assert schema.conformance(written(name)) == []


def test_every_declared_group_is_written_by_some_deck(written):
    """The declaration holds no dead entries for element groups: each analysis group declared
    appears in at least one example deck's file (bench-only capabilities excepted)."""
    groups = set()
    for name in DECKS:
        with h5py.File(written(name), "r") as f:
            for top in f:
                if top.startswith("analysis_"):
                    groups |= set(f[top])
    declared = {it.name.split("/")[0] for it in schema.items()
                if it.scope == "analysis" and it.kind == "dataset" and "/" in it.name}
    assert declared - groups == set()


def test_labels_and_request_channels(written):
    with h5py.File(written("slider_crank_load.xml"), "r") as f:
        a = f["analysis_000"]
        assert list(a["joints/label"].asstr()[()]) == ["Crank pivot", "Crank pin", "Wrist pin",
                                                        "Slide"]
        assert list(a["forces/label"].asstr()[()]) == ["Crank torsion spring", "Slider load"]
        assert list(f["model/joints/label"].asstr()[()]) == list(a["joints/label"].asstr()[()])
        assert list(a["bodies/label"].asstr()[()]) == ["Crank", "Rod", "Slider"]
    with h5py.File(written("expr_reaction_load.xml"), "r") as f:
        a = f["analysis_000"]
        types = list(a["requests/type"].asstr()[()])
        ch = a["requests/channel"].asstr()[()]
        cu = a["requests/channel_units"].asstr()[()]
        assert ch.shape == cu.shape == (len(types), 8)
        for t, names, units in zip(types, ch, cu):
            if t == "MARKER_FORCE":
                assert list(names) == ["FM", "FX", "FY", "FZ", "TM", "TX", "TY", "TZ"]
                assert list(units) == ["N"] * 4 + ["N*mm"] * 4
            if t == "MARKER_DISPLACEMENT":
                assert list(names[:4]) == ["DM", "DX", "DY", "DZ"] and units[5] == "rad"


def test_request_channel_by_name(written):
    from poise.results.hdf5 import read_results
    res = read_results(str(written("expr_reaction_load.xml")))
    a = res.analyses[-1]
    rid = int(a.datasets["requests/id"][0])
    names = list(a.datasets["requests/channel"][0])
    k = next(i for i, n in enumerate(names) if n)
    v = np.asarray(a.datasets["requests/values"])[-1, 0, k]
    np.testing.assert_equal(res.request(rid, names[k]), v)
    np.testing.assert_equal(res.request(rid, names[k].lower()), v)
    np.testing.assert_equal(res.request(rid, k + 1), v)
    with pytest.raises(KeyError, match="channel"):
        res.request(rid, "NOPE")


def test_docs_results_format_is_generated():
    """docs/results-format.md is the generator's output (regenerate with
    ``python -m poise.results.schema --markdown docs/results-format.md``)."""
    from poise.results.schema import markdown
    committed = (ROOT / "docs" / "results-format.md").read_text(encoding="utf-8")
    assert committed == markdown(), \
        "stale: python -m poise.results.schema --markdown docs/results-format.md"


def test_docs_name_every_declared_object():
    from poise.results.schema import markdown
    text = markdown()
    for it in schema.items():
        assert f"`{it.name}`" in text, it.path
    assert "planned" not in text


def test_units_strings():
    u = "force=NEWTON mass=KILOGRAM length=MILLIMETER time=SECOND"
    assert schema.unit_string("force*length", u) == "N*mm"
    assert schema.unit_string("force/length", u) == "N/mm"
    assert schema.unit_string("length/time^2", u) == "mm/s^2"
    assert schema.unit_string("1", u) == "1" and schema.unit_string("rad", u) == "rad"
    assert schema.unit_string("mass", "force=POUND_FORCE mass=SLUG length=FOOT "
                              "time=SECOND") == "slug"


def test_sweep_outputs_come_from_the_schema():
    outs = schema.element_outputs()
    assert "position" in outs["bodies"] and "force" in outs["gears"]
    assert "positon" not in outs["bodies"]


def test_cli_undeclared_dataset_is_an_internal_error_naming_it(tmp_path, monkeypatch):
    """A capability writing a dataset the schema does not declare fails loudly (exit 4, the
    path named), and no results file is left."""
    from click.testing import CliRunner

    from poise.results.labels import Labeller
    from poise_cli.main import cli
    real = Labeller.datasets

    def extra(self, datasets, model=None):
        out = real(self, datasets, model)
        if "time" in datasets:
            out["bodies/positon"] = np.zeros((1, 1, 3))
        return out
    monkeypatch.setattr(Labeller, "datasets", extra)
    out = tmp_path / "x.h5"
    r = CliRunner().invoke(cli, ["solve", str(ROOT / "decks" / "double_pendulum.xml"), "-o",
                                 str(out), "--quiet"])
    assert r.exit_code == 4, r.output
    assert "internal error" in r.stderr and "/analysis_000/bodies/positon" in r.stderr
    assert "not declared in the results schema" in r.stderr
    assert not out.exists()


def test_result_unit_accessor(written):
    from poise.results.hdf5 import read_results
    res = read_results(str(written("slider_crank_load.xml")))
    assert res.unit("bodies/position") == "mm" and res.unit("joints/torque") == "N*mm"
    assert res.unit("model/bodies/mass") == "kg"
    with h5py.File(written("slider_crank_load.xml"), "r") as f:
        assert f["analysis_000/joints/torque"].attrs["units"] == res.unit("joints/torque")


# ------------------------------------------------------------------- netCDF-4 / xarray view
def _declared_dataset(path: str):
    """The declaration of the dataset at tree path ``path`` (``/analysis_000/joints/force``)."""
    top, _, rel = path.lstrip("/").partition("/")
    if top == "model":
        return schema.lookup("model", "dataset", rel)
    if top.startswith("analysis_"):
        return schema.lookup("analysis", "dataset", rel)
    return schema.lookup("root", "dataset", path.lstrip("/"))


@pytest.mark.parametrize("name", DECKS)
def test_example_deck_opens_in_xarray_as_declared(written, name):
    """``xarray.open_datatree(file, engine="h5netcdf")`` gives every declared dataset with its
    declared dimension names (no phony dimensions), ``units`` and ``long_name``; element ids
    and labels are coordinates, and so is each analysis' ``time``."""
    import xarray as xr
    path = written(name)
    with h5py.File(path, "r") as f:
        units = f.attrs["units"]
        expected = set()
        f.visititems(lambda n, o: expected.add("/" + n) if isinstance(o, h5py.Dataset)
                     and _declared_dataset("/" + n) is not None else None)
    tree = xr.open_datatree(path, engine="h5netcdf")
    seen = set()
    for node in tree.subtree:
        ds = node.to_dataset(inherit=False)
        assert not [d for d in ds.dims if str(d).startswith("phony_dim")], node.path
        for vname, var in ds.variables.items():
            full = f"{node.path.rstrip('/')}/{vname}"
            it = _declared_dataset(full)
            if it is None:                    # a fixed-size dimension's coordinate values
                assert node.path == "/" and schema.component_dim(str(vname)), full
                assert list(var.values) == list(schema.component_values(str(vname)))
                continue
            seen.add(full)
            assert var.dims == schema.dims(it), full
            assert var.attrs["units"] == schema.unit_string(it.unit, units), full
            assert var.attrs["long_name"] == schema.long_name(it), full
        group = node.path.rsplit("/", 1)[-1]
        if "label" in ds.variables and "id" in ds.variables:
            assert {"id", "label"} <= set(ds.coords), node.path
        if group.startswith("analysis_") and "time" in ds.variables:
            assert "time" in ds.coords and ds["time"].dims == ("frame",)
    assert seen == expected


@pytest.mark.parametrize("name", ["qs_slider_crank_11b.xml", "slider_crank_load.xml",
                                  "expr_reaction_load.xml", "mkeam_pendulum_multiturn.xml"])
def test_to_xarray_equals_the_file_opened_in_xarray(written, name):
    """``RunResult.to_xarray()`` (built without a file) holds what xarray reads from the file:
    the same groups, variables, dimensions, values and attributes (plus its conveniences: the
    ``time`` coordinate on groups with frames and indexes)."""
    import xarray as xr
    from poise.results.hdf5 import read_results
    path = written(name)
    ours = read_results(str(path)).to_xarray()
    theirs = xr.open_datatree(path, engine="h5netcdf").load()
    assert {n.path for n in ours.subtree} == {n.path for n in theirs.subtree}
    for node in theirs.subtree:
        a = node.to_dataset(inherit=False)
        b = ours[node.path].to_dataset(inherit=False)
        extra = set(b.variables) - set(a.variables)
        assert extra <= {"time"}, (node.path, extra)
        assert set(a.coords) <= set(b.coords), node.path
        for v in a.variables:
            assert a[v].dims == b[v].dims, (node.path, v)
            assert a[v].attrs == b[v].attrs, (node.path, v)
            if a[v].dtype.kind in "OU":
                assert a[v].values.tolist() == b[v].values.tolist(), (node.path, v)
            else:
                np.testing.assert_array_equal(a[v].values, b[v].values, err_msg=v)
        assert set(a.attrs) == set(b.attrs), node.path


def test_open_dataset_with_group(written):
    """``xarray.open_dataset(file, group=...)``: one group, named dimensions, ids and labels
    as coordinates, units and long names."""
    import xarray as xr
    ds = xr.open_dataset(written("slider_crank_load.xml"), engine="h5netcdf",
                         group="analysis_000/joints")
    assert ds.force.dims == ("frame", "joint", "axis")
    assert list(ds.label.values) == ["Crank pivot", "Crank pin", "Wrist pin", "Slide"]
    assert {"id", "label"} <= set(ds.coords)
    assert ds.force.attrs["units"] == "N" and ds.torque.attrs["units"] == "N*mm"
    assert ds.force.attrs["long_name"] == "joint force on its I body"
    a = xr.open_dataset(written("slider_crank_load.xml"), engine="h5netcdf",
                        group="analysis_000")
    assert "time" in a.coords and a.attrs["method"] == "FIM_S"


def test_every_declared_dataset_has_a_long_name_and_dimensions():
    """A new dataset declares its long name (poise.results.schema_dims.LONG_NAMES, generic
    ``<group>/id|label|force|torque|tag|unique`` for element groups) and its dimensions follow
    from its shape (a new symbol: DIMENSIONS; a fixed size other than 3: ITEM_DIMS)."""
    from poise.results import schema_dims as sd
    missing = []
    for it in schema.items():
        if it.kind != "dataset":
            continue
        assert len(schema.dims(it)) == len(it.shape), it.path
        group, _, rest = it.name.partition("/")
        generic = sd.element_name(group) and f"<any>/<group>/{rest}" in sd.LONG_NAMES
        if f"{it.scope}/{it.name}" not in sd.LONG_NAMES and not generic:
            missing.append(f"{it.scope}/{it.name}")
    assert missing == [], "declare their long names in poise.results.schema_dims.LONG_NAMES"
