"""HDF5 results writer/reader: round trip, layout, determinism, atomicity."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
import time

import h5py
import numpy as np
import pytest

from poise.results import hdf5
from poise.results.hdf5 import (
    FORMAT,
    FORMAT_VERSION,
    ResultsFormatError,
    read_results,
    read_summary,
    write_results,
)

from support.paths import TESTS
from support.results import make_result


def test_round_trip(tmp_path):
    path = tmp_path / "r.h5"
    src = make_result()
    write_results(src, str(path))
    back = read_results(str(path))
    assert back.deck == src.deck and back.deck_sha256 == src.deck_sha256
    assert back.units == src.units and back.command == src.command
    assert back.active_effects == src.active_effects
    assert back.warnings == src.warnings
    assert {k: v for k, v in back.timings.items() if k != "write"} == src.timings
    assert back.timings["write"] > 0.0               # the writer records its own time
    assert back.counts == src.counts
    assert back.status == "failed"
    assert set(back.model_datasets) == set(src.model_datasets)
    assert [a.index for a in back.analyses] == [0, 1]
    for a, b in zip(src.analyses, back.analyses, strict=True):
        assert (b.analysis_type, b.method, b.status, b.message) == \
            (a.analysis_type, a.method, a.status, a.message)
        assert b.settings == a.settings
        assert set(b.datasets) == set(a.datasets)
        for k, v in a.datasets.items():
            w = b.datasets[k]
            assert w.shape == v.shape, k
            if v.dtype.kind == "U":
                assert w.tolist() == v.tolist(), k
            else:
                assert w.dtype == v.dtype, k
                np.testing.assert_array_equal(w, v, err_msg=k)
    assert back.analyses[0].attrs == {"reactions_unique": True, "assembled": False}


def test_layout_and_attributes(tmp_path):
    path = tmp_path / "r.h5"
    write_results(make_result(), str(path))
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == FORMAT
        assert f.attrs["format_version"] == FORMAT_VERSION
        assert f.attrs["status"] == "failed"
        assert list(f.attrs["active_effects"]) == ["gravity", "revolute"]
        assert "created" not in f.attrs
        for k in ("poise_version", "deck", "deck_sha256", "units", "command"):
            assert k in f.attrs
        assert set(f) >= {"model", "timings", "counts", "warnings", "analysis_000",
                          "analysis_001"}
        assert f["timings"].attrs["solve"] == pytest.approx(0.2)
        assert f["counts"].attrs["residuals"] == 40
        g = f["analysis_000"]
        assert g.attrs["analysis_type"] == "static" and g.attrs["method"] == "FIM_S"
        assert json.loads(g.attrs["settings"]) == {"max_imbalance": 1e-6, "max_num_iter": 25}
        assert bool(g.attrs["reactions_unique"]) is True
        assert isinstance(g["bodies"], h5py.Group)
        assert g["bodies/position"].shape == (1, 2, 3)
        assert g["frames/strategy_iterations"].dtype == np.int32
        lab = g["bodies/label"]
        assert h5py.check_string_dtype(lab.dtype).encoding == "utf-8"
        assert h5py.check_string_dtype(lab.dtype).length is None  # variable length
        assert lab.asstr()[1] == "bras \u00e9l\u00e8ve"
        assert g["frames/converged"].dtype == np.bool_
        assert g["redundant/tag"].shape == (0,)
        for name in ("bodies/position", "bodies/label", "iterations/event"):
            assert g[name].chunks is None and g[name].compression is None
        assert h5py.check_string_dtype(f["warnings"].dtype) is not None


def _dataset_bytes(path) -> dict:
    out = {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                data = obj[()]
                out[name] = repr(data.tolist()) if data.dtype.kind == "O" else data.tobytes()
        f.visititems(visit)
    return out


def test_deterministic_bytes(tmp_path):
    p1, p2 = tmp_path / "a.h5", tmp_path / "b.h5"
    write_results(make_result(), str(p1))
    time.sleep(1.1)  # HDF5 object timestamps have 1 s resolution: they must not be written
    write_results(make_result(), str(p2))
    b1, b2 = p1.read_bytes(), p2.read_bytes()
    assert len(b1) == len(b2)
    # identical but for the value of /timings "write" (one float64)
    assert sum(x != y for x, y in zip(b1, b2, strict=True)) <= 8
    with h5py.File(p1) as f1, h5py.File(p2) as f2:
        a1 = {k: v for k, v in f1["timings"].attrs.items() if k != "write"}
        a2 = {k: v for k, v in f2["timings"].attrs.items() if k != "write"}
        assert a1 == a2


def test_timings_only_difference(tmp_path):
    p1, p2 = tmp_path / "a.h5", tmp_path / "b.h5"
    write_results(make_result({"parse": 0.01, "solve": 0.2}), str(p1))
    write_results(make_result({"parse": 0.37, "solve": 9.5}), str(p2))
    assert _dataset_bytes(p1) == _dataset_bytes(p2)
    b1, b2 = p1.read_bytes(), p2.read_bytes()
    assert len(b1) == len(b2)
    # the two float attributes and the write time
    assert sum(x != y for x, y in zip(b1, b2, strict=True)) <= 24


def test_summary(tmp_path):
    path = tmp_path / "r.h5"
    write_results(make_result(), str(path))
    s = read_summary(str(path))
    json.dumps(s)  # plain JSON-serialisable
    assert s["status"] == "failed" and s["format_version"] == 1
    a0, a1 = s["analyses"]
    assert a0["iterations"] == 5 and a0["imbalance"] == pytest.approx(3.2e-9)
    assert a0["reactions_unique"] is True and a0["frames"] == 1
    assert a0["datasets"]["bodies/position"] == [1, 2, 3]
    assert a1["frames"] == 3 and a1["iterations"] == 32
    assert a1["imbalance"] == pytest.approx(12.5)
    assert a1["stability"] == ["stable", "stable", "unknown"]
    assert s["model"] == {"bodies/id": [2], "bodies/mass": [2]}


def test_not_a_results_file(tmp_path):
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w") as f:
        f["x"] = 1
    with pytest.raises(ResultsFormatError, match="not a poise results file"):
        read_summary(str(plain))
    text = tmp_path / "t.h5"
    text.write_text("hello")
    with pytest.raises(ResultsFormatError):
        read_summary(str(text))


def _leftovers(d):
    return sorted(p.name for p in d.iterdir())


def test_atomic_on_exception(tmp_path, monkeypatch):
    final = tmp_path / "out.h5"
    calls = {"n": 0}
    real = hdf5._write_datasets

    def boom(group, datasets, where, *rest):
        calls["n"] += 1
        if where.startswith("/analysis_001"):
            raise RuntimeError("disk on fire")
        return real(group, datasets, where, *rest)

    monkeypatch.setattr(hdf5, "_write_datasets", boom)
    with pytest.raises(RuntimeError, match="disk on fire"):
        write_results(make_result(), str(final))
    assert calls["n"] >= 2  # failed mid-write, after data went to the temp file
    assert _leftovers(tmp_path) == []


def test_atomic_keeps_previous_file(tmp_path):
    final = tmp_path / "out.h5"
    write_results(make_result(), str(final))
    before = final.read_bytes()
    bad = make_result()
    bad.analyses[0].datasets["/absolute"] = np.zeros(1)
    with pytest.raises(ValueError, match="invalid dataset path"):
        write_results(bad, str(final))
    assert final.read_bytes() == before
    assert _leftovers(tmp_path) == ["out.h5"]


def test_sigkill_mid_write_leaves_no_final_file(tmp_path):
    final = tmp_path / "killed.h5"
    script = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(TESTS)!r})
        from support.results import make_result
        from poise.results import hdf5
        real = hdf5._write_datasets
        def slow(group, datasets, where, *rest):
            real(group, datasets, where, *rest)
            if where.startswith("/analysis_000"):
                group.file.flush()
                print("mid-write", flush=True)
                time.sleep(60)
        hdf5._write_datasets = slow
        hdf5.write_results(make_result(), {str(final)!r})
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "mid-write"
        tmps = [p for p in tmp_path.iterdir() if p.name.startswith(".killed.h5.tmp-")]
        assert len(tmps) == 1        # claimed first; the image is built in memory, written last
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert not final.exists()


def test_overwrites_existing(tmp_path):
    final = tmp_path / "out.h5"
    final.write_bytes(b"old junk")
    write_results(make_result(), str(final))
    assert read_summary(str(final))["status"] == "failed"
    assert _leftovers(tmp_path) == ["out.h5"]


def test_reserved_attr_clash(tmp_path):
    r = make_result()
    r.analyses[0].attrs["method"] = "X"
    with pytest.raises(ValueError, match="clash"):
        write_results(r, str(tmp_path / "x.h5"))
    assert _leftovers(tmp_path) == []


def test_low_level_datasets_equal_high_level_bytes(tmp_path):
    """``_create_dataset`` must write what ``create_dataset(..., track_times=False)`` writes,
    byte for byte, for every kind of array a results file holds."""
    import h5py
    arrays = {
        "scalar_f": np.float64(2.5), "scalar_i": np.int64(-3), "empty": np.zeros((0, 3)),
        "vec": np.arange(5.0), "mat_f_order": np.asfortranarray(np.arange(12.0).reshape(3, 4)),
        "ints": np.arange(7, dtype=np.int32), "flags": np.array([True, False, True]),
        "strings": hdf5._to_array(np.array(["a", "bé", ""], dtype=object), "t"),
        "scalar_str": hdf5._to_array(np.array("x"), "t"), "u8": np.arange(4, dtype=np.uint8),
    }
    lo, hi = tmp_path / "lo.h5", tmp_path / "hi.h5"
    with h5py.File(lo, "w") as f:
        for k in sorted(arrays):
            hdf5._create_dataset(f, k, np.asarray(arrays[k]))
    with h5py.File(hi, "w") as f:
        for k in sorted(arrays):
            a = np.asarray(arrays[k])
            f.create_dataset(k, data=a, dtype=a.dtype, track_times=False)
    assert lo.read_bytes() == hi.read_bytes()
    with h5py.File(lo) as f:
        assert f["scalar_f"].shape == () and f["scalar_f"][()] == 2.5
        assert f["empty"].shape == (0, 3)
        np.testing.assert_array_equal(f["mat_f_order"][()], np.arange(12.0).reshape(3, 4))
        assert [s.decode() for s in f["strings"][()]] == ["a", "bé", ""]


def test_units_attribute_on_every_dataset(tmp_path):
    """Every dataset carries ``units`` in the deck's units (here N, kg, mm, s); netCDF
    dimensions that are not variables (``frame``, ``body``, ...) are not datasets of the
    schema."""
    path = tmp_path / "u.h5"
    write_results(make_result(), str(path))
    with h5py.File(path, "r") as f:
        units = {}
        f.visititems(lambda n, o: units.__setitem__(n, o.attrs.get("units"))
                     if isinstance(o, h5py.Dataset) and not hdf5._is_dimension(
                         n.split("/", 1)[-1] if "/" in n else n) else None)
    assert None not in units.values()
    assert units["analysis_000/bodies/position"] == "mm"
    assert units["analysis_000/joints/torque"] == "N*mm"
    assert units["analysis_000/frames/imbalance"] == "mixed"   # largest of N and N*mm rows
    assert units["analysis_000/time"] == "s"
    assert units["analysis_000/bodies/orientation"] == "1"
    assert units["model/bodies/mass"] == "kg"
    assert units["analysis_000/bodies/label"] == ""          # text


@pytest.mark.parametrize("where, value, match", [
    ("dataset", ("bodies/positon", np.zeros((1, 2, 3))), "'bodies/positon' is not declared"),
    ("attr", ("n_redundant", 0), "'n_redundant' is not declared"),
    ("dataset", ("bodies/position", np.zeros((1, 2))), "does not match the declared"),
    ("dataset", ("frames/status", np.zeros(1)), "does not match the declared str"),
])
def test_undeclared_objects_refused(tmp_path, where, value, match):
    """The writer refuses what the schema does not declare (and wrong dtypes / ranks), naming
    the path; nothing is left behind."""
    from poise.results.schema import UndeclaredError
    r = make_result()
    key, v = value
    (r.analyses[0].datasets if where == "dataset" else r.analyses[0].attrs)[key] = v
    with pytest.raises(UndeclaredError, match=match) as e:
        write_results(r, str(tmp_path / "x.h5"))
    assert "/analysis_000" in str(e.value)
    assert _leftovers(tmp_path) == []


def test_inconsistent_shapes_still_written_and_reported(tmp_path):
    """A capability writing a dataset whose frame count disagrees with the others does not
    lose the results: the file is written (the odd axis gets dimension ``frame_<n>``), reads
    back, opens in xarray, and the schema conformance names the inconsistency."""
    import xarray as xr

    from poise.results.schema import conformance
    r = make_result()
    r.analyses[1].datasets["frames/iterations"] = np.array([3, 4])       # 2 rows, F = 3
    path = tmp_path / "odd.h5"
    write_results(r, str(path))
    back = read_results(str(path))
    assert set(back.analyses[1].datasets) == set(r.analyses[1].datasets)
    tree = xr.open_datatree(path, engine="h5netcdf")
    assert tree["analysis_001/frames"]["iterations"].dims == ("frame_2",)
    assert any("frames/iterations" in p for p in conformance(path))
