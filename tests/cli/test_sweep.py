"""poise sweep: Dask LocalCluster sweeps checked against serial solves, resume, --scheduler."""
from __future__ import annotations

import csv
import json
import os

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

import poise
from poise.core.errors import UsageError
from poise.app.cases import apply_case, make_cases, resolve_param
from poise.app.sweep import run_case
from poise_cli.main import cli

from support.paths import DECKS


DECK = DECKS / "pendulum_multiturn.xml"
K = "Force_SpringDamper[1].stiffness"


def _datasets(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: out.__setitem__(n, o[()]) if isinstance(o, h5py.Dataset)
                     else None)
        attrs = {k: f.attrs[k] for k in f.attrs}
    return out, attrs


def _same(a, b):
    assert sorted(a) == sorted(b)
    for k in a:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.dtype == y.dtype and x.shape == y.shape, k
        if x.dtype.kind in "biuf":
            assert x.tobytes() == y.tobytes(), k      # bitwise
        else:
            assert x.tolist() == y.tolist(), k


def test_parameters_and_modes():
    spec = poise.load_deck(str(DECK))
    p = resolve_param(spec, K, "10:100:10")
    assert p.values == [10.0 * i for i in range(1, 11)] and p.range == (10.0, 100.0)
    assert resolve_param(spec, K, "0.1:0.3:0.1").values == [0.1, 0.2, 0.3]
    m = resolve_param(spec, "Param_Static.method", "fim_s,MKEAM")
    assert m.values == ["FIM_S", "MKEAM"]
    g = resolve_param(spec, "Force_Gravity.grav_y", [-9810, -1000])
    assert g.values == [-9810.0, -1000.0]
    assert len(make_cases([p, m], "grid")) == 20
    assert make_cases([p, m], "grid")[1] == {K: 10.0, "Param_Static.method": "MKEAM"}
    with pytest.raises(UsageError, match="same number"):
        make_cases([p, m], "zip")
    r1 = make_cases([p, m], "random", n=7, seed=3)
    assert r1 == make_cases([p, m], "random", n=7, seed=3) and len(r1) == 7
    assert all(10 <= c[K] <= 100 for c in r1)
    for bad, msg in [("Force_SpringDamper[9].stiffness", "no <Force_SpringDamper id=9>"),
                     ("Force_SpringDamper[1].stiff", "no attribute"),
                     ("Nope[1].x", "unknown element"),
                     ("Force_SpringDamper[1].i_marker_id", "cannot be swept"),
                     ("Reference_Marker.pos_x", "address one as")]:
        with pytest.raises(UsageError, match=msg):
            resolve_param(spec, bad, "1,2")
    with pytest.raises(UsageError, match="out of bounds"):
        resolve_param(spec, K, "-10:10:10")
    with pytest.raises(UsageError, match="not a number"):
        resolve_param(spec, K, "1,abc")
    # substitution leaves the parsed deck untouched
    new, ov = apply_case(spec, [p], {K: 50.0})
    assert new.by_id("Force_SpringDamper")[1].attrs["stiffness"] == 50.0
    assert spec.by_id("Force_SpringDamper")[1].attrs["stiffness"] == 20000.0 and ov == {}


def test_cli_usage_errors_exit_2(tmp_path):
    for s in ["Force_SpringDamper[3].stiffness=1:3:1", "Force_SpringDamper[1].stiffness=-1:3:1",
              "Param_Static.method=FIM_S,BOGUS", "Force_SpringDamper[1].stiffness"]:
        r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", s, "--out-dir", str(tmp_path)])
        assert r.exit_code == 2, (s, r.output)
        assert "--set" in r.stderr
    r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", f"{K}=1,2", "--output",
                                 "bodies[7].position", "--out-dir", str(tmp_path)])
    assert r.exit_code == 2 and "bodies[7]" in r.stderr


def test_determinism_same_case_bitwise(tmp_path):
    spec = poise.load_deck(str(DECK))
    p = resolve_param(spec, K, "15000")
    data = DECK.read_bytes()
    for name in ("a.h5", "b.h5"):
        row = run_case(data, str(DECK), [p], 0, {K: 15000.0}, None, str(tmp_path / name), "h",
                       [])
        assert row["status"] == "converged"
    a, aa = _datasets(tmp_path / "a.h5")
    b, ba = _datasets(tmp_path / "b.h5")
    _same(a, b)
    assert {k: str(v) for k, v in aa.items()} == {k: str(v) for k, v in ba.items()}


def test_local_cluster_sweep_matches_serial_and_resumes(tmp_path):
    out = tmp_path / "sw"
    values = "10000:30000:1000"                       # 21 cases
    rows = poise.sweep(str(DECK), {K: values}, out_dir=str(out), workers=2,
                       outputs=["bodies[2].position", "joints[1].force"])
    assert len(rows) == 21 and [r["case"] for r in rows] == list(range(21))
    assert all(r["status"] == "converged" and not r["resumed"] for r in rows)
    spec = poise.load_deck(str(DECK))
    p = resolve_param(spec, K, values)
    for r in rows:
        case_spec, _ = apply_case(spec, [p], {K: r[K]})
        serial = poise.solve(case_spec)
        a = serial.analyses[-1].datasets
        np.testing.assert_array_equal(
            [r[f"bodies[2].position[{i}]"] for i in range(3)], a["bodies/position"][-1][0])
        np.testing.assert_array_equal(
            [r[f"joints[1].force[{i}]"] for i in range(3)], a["joints/force"][-1][0])
        d, attrs = _datasets(out / r["file"])
        for key, v in a.items():        # the Dask worker's file == the serial solve, bitwise
            if np.asarray(v).dtype.kind in "biuf":
                assert np.asarray(v).tobytes() == d[f"analysis_000/{key}"].tobytes(), key
        assert r["iterations"] == int(np.sum(a["frames/iterations"]))
        assert json.loads(attrs["sweep_values"]) == {K: r[K]}
    with open(out / "index.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 21 and float(table[3][K]) == 13000.0
    assert json.loads((out / "index.json").read_text())["rows"][20][K] == 30000.0

    # interrupted sweep: some case files are missing -> only those run again
    for i in (2, 7, 19):
        os.unlink(out / f"case_{i:05d}.h5")
    rows2 = poise.sweep(str(DECK), {K: values}, out_dir=str(out), workers=2,
                        outputs=["bodies[2].position", "joints[1].force"])
    ran = [r["case"] for r in rows2 if not r["resumed"]]
    assert ran == [2, 7, 19]
    for r1, r2 in zip(rows, rows2):
        for k in r1:
            if k not in ("resumed", "wall_time"):
                assert r1[k] == r2[k], k


@pytest.fixture(scope="module")
def cluster():
    from dask.distributed import LocalCluster
    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                     scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    yield c
    c.close()


def test_cli_scheduler_address(tmp_path, cluster):
    out = tmp_path / "s"
    args = ["sweep", str(DECK), "--set", f"{K}=10000,20000", "--set",
            "Force_Gravity.grav_y=-9810,-4905", "--scheduler", cluster.scheduler_address,
            "--out-dir", str(out), "--json", "--output", "bodies[2].position"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    assert js["n_cases"] == 4 and js["counts"] == {"converged": 4} and js["resumed"] == 0
    idx = json.loads((out / "index.json").read_text())
    assert [(row[K], row["Force_Gravity.grav_y"]) for row in idx["rows"]] == \
        [(10000.0, -9810.0), (10000.0, -4905.0), (20000.0, -9810.0), (20000.0, -4905.0)]
    assert sorted(p.name for p in out.glob("case_*.h5")) == [f"case_0000{i}.h5" for i in range(4)]
    # a rerun resumes every case; deleting one reruns exactly one
    os.unlink(out / "case_00001.h5")
    r = CliRunner().invoke(cli, args)
    assert json.loads(r.stdout)["resumed"] == 3
    assert "\x1b[" not in r.output and "\r[" not in r.output   # no progress bar off a TTY


def test_output_dataset_names_checked_against_the_schema(tmp_path):
    """A misspelt --output dataset is a usage error (exit 2) with a did-you-mean, not an
    empty column; groups come from the results schema (gears, couplers, curves, ...)."""
    r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", f"{K}=1,2", "--output",
                                 "bodies[2].positon", "--out-dir", str(tmp_path)])
    assert r.exit_code == 2, r.output
    assert "did you mean bodies[2].position?" in r.stderr
    assert not (tmp_path / "index.csv").exists()
    from poise.app.sweep import output_groups
    assert {"gears", "couplers", "curves", "contacts", "requests"} <= set(output_groups())
