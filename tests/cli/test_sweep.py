"""poise sweep: one sweep file (netCDF-4, dimension ``case``, parameters as coordinates) whose
numbers are bitwise those of single solves, in any chunk; the index; resume per chunk (parts
of a killed sweep, the previous sweep file, a longer range); ``--per-case-files``;
``--scheduler``; ``poise.sweep`` returning the labelled dataset."""
from __future__ import annotations

import csv
import json
import os

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

import poise
from poise.app.cases import apply_case, group_cases, make_cases, resolve_param
from poise.app.chunks import make_template, solve_chunk
from poise.app.sweep import run_sweep
from poise.app.sweep_journal import PARTS
from poise.core.errors import UsageError
from poise_cli.main import cli

from support.paths import DECKS


DECK = DECKS / "pendulum_multiturn.xml"
K = "Force_SpringDamper[1].stiffness"
OUTS = ["bodies[2].position", "joints[1].force"]


def _datasets(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: out.__setitem__(n, o[()]) if isinstance(o, h5py.Dataset)
                     and not n.startswith("timings") else None)
    return out


def _bits(x) -> bytes:
    return np.ascontiguousarray(np.asarray(x)).tobytes()


def _serial(spec, params, values):
    """A single ``poise.solve`` of one case: the reference the sweep must equal bitwise."""
    case_spec, extra = apply_case(spec, params, values)
    return poise.solve(case_spec, quiet=True, **extra)


def test_parameters_and_modes():
    spec = poise.load_deck(str(DECK))
    p = resolve_param(spec, K, "10:100:10")
    assert p.values == [10.0 * i for i in range(1, 11)] and p.range == (10.0, 100.0)
    assert resolve_param(spec, K, "0.1:0.3:0.1").values == [0.1, 0.2, 0.3]
    m = resolve_param(spec, "Param_Static.method", "fim_s,MKEAM")
    assert m.values == ["FIM_S", "MKEAM"] and m.structural and not p.structural
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
    # structural values (enum, bool) make the groups a worker solves together
    groups = group_cases([p, m], make_cases([p, m], "grid"), range(20))
    assert [(g, len(idx)) for g, idx in groups.values()] == [
        ({"Param_Static.method": "FIM_S"}, 10), ({"Param_Static.method": "MKEAM"}, 10)]
    assert groups['{"Param_Static.method": "MKEAM"}'][1] == list(range(1, 20, 2))


def test_cli_usage_errors_exit_2(tmp_path):
    for s in ["Force_SpringDamper[3].stiffness=1:3:1", "Force_SpringDamper[1].stiffness=-1:3:1",
              "Param_Static.method=FIM_S,BOGUS", "Force_SpringDamper[1].stiffness"]:
        r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", s, "--out-dir", str(tmp_path)])
        assert r.exit_code == 2, (s, r.output)
        assert "--set" in r.stderr
    r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", f"{K}=1,2", "--output",
                                 "bodies[7].position", "--out-dir", str(tmp_path)])
    assert r.exit_code == 2 and "bodies[7]" in r.stderr
    r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", f"{K}=1,2", "--chunk-size", "0",
                                 "--out-dir", str(tmp_path)])
    assert r.exit_code == 2 and "--chunk-size" in r.stderr


@pytest.mark.parametrize("sets", [
    {K: [12000.0, 15000.0, 21000.0]},                               # the model changes
    {"Param_Static.max_num_iter": [20, 30, 40], "Param_Static.max_error": [1e-9, 1e-10, 1e-11]},
])                                                                   # settings only: one model
def test_a_case_gives_the_bits_of_a_single_solve_in_any_chunk(tmp_path, sets):
    """The worker's chunk solver (no Dask: the same function) against ``poise.solve`` of each
    case alone, bitwise, whatever the chunk it is solved in and its place there."""
    from poise.app.sweep import frame_layout
    from poise.app.chunks import SweepJob
    from poise.app.sweep_index import outputs_of, parse_outputs
    spec = poise.load_deck(str(DECK))
    params = [resolve_param(spec, k, v) for k, v in sets.items()]
    cases = make_cases(params, "zip")
    job = SweepJob(DECK.read_bytes(), str(DECK), tuple(params), {},
                   outputs_of(parse_outputs(spec, OUTS)), frame_layout(spec, params, cases, {}),
                   case_dir=str(tmp_path), width=5, key="k")
    template = make_template(job, {})
    assert template.settings_only == ("Param_Static.max_num_iter" in sets)
    alone = [solve_chunk(template, [(i, c)])[0] for i, c in enumerate(cases)]
    together = solve_chunk(template, list(enumerate(cases))[::-1])[::-1]
    for i, c in enumerate(cases):
        ref = _serial(spec, params, c).analyses[-1].datasets
        for rec in (alone[i], together[i]):
            assert rec.status == "converged" and rec.case == i
            assert rec.iterations == int(np.sum(ref["frames/iterations"]))
            assert rec.converged.tolist() == np.asarray(ref["frames/converged"]).tolist()
            assert _bits(rec.outputs["bodies[2].position"]) == _bits(ref["bodies/position"][:, 0])
            assert _bits(rec.outputs["joints[1].force"]) == _bits(ref["joints/force"][:, 0])
        # --per-case-files: the case's own file holds the single solve's datasets, bitwise
        d = _datasets(tmp_path / rec.file)
        for key, v in ref.items():
            if np.asarray(v).dtype.kind in "biuf":
                assert _bits(v) == _bits(d[f"analysis_000/{key}"]), key


def test_local_cluster_sweep_one_file_matches_serial_and_resumes_per_chunk(tmp_path):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("distributed")
    out = tmp_path / "sw"
    values = "10000:30000:1000"                       # 21 cases, chunks of 4
    ds = poise.sweep(str(DECK), {K: values}, out_dir=str(out), workers=2, outputs=OUTS,
                     chunk_size=4, quiet=True)
    assert isinstance(ds, xr.Dataset)
    assert sorted(p.name for p in out.iterdir()) == [".poise.lock", "index.csv", "index.json",
                                                     "sweep.h5"]      # one file, no parts
    # one labelled dataset: case with the parameter as coordinate, axis labels, units
    assert dict(ds.sizes) == {"case": 21, "frame": 1, "axis": 3}
    assert K in ds.coords and ds[K].dims == ("case",) and float(ds[K][3]) == 13000.0
    assert not [d for d in ds.dims if str(d).startswith("phony")]
    pos = ds["bodies[2].position"]
    assert pos.dims == ("case", "frame", "axis") and pos.attrs["units"] == "mm"
    assert ds["joints[1].force"].attrs["units"] == "N" and ds.wall_time.attrs["units"] == "s"
    assert all("long_name" in ds[v].attrs for v in ds.variables)
    assert list(ds.axis.values) == ["x", "y", "z"] and ds.attrs["complete"]
    assert (ds.status == "converged").all() and (ds.exit_code == 0).all()
    # every case: the bits of a single solve
    spec = poise.load_deck(str(DECK))
    p = resolve_param(spec, K, values)
    for i in range(21):
        ref = _serial(spec, [p], {K: float(ds[K][i])}).analyses[-1].datasets
        assert _bits(pos.isel(case=i).values) == _bits(ref["bodies/position"][:, 0])
        assert _bits(ds["joints[1].force"].isel(case=i).values) == \
            _bits(ref["joints/force"][:, 0])
        assert int(ds.iterations[i]) == int(np.sum(ref["frames/iterations"]))
    y = pos.sel(axis="y").isel(frame=-1).swap_dims(case=K)
    assert float(y.sel({K: 13000.0})) == float(pos[3, -1, 1])
    ds.close()
    # the index: one row per case, the last frame flattened
    with open(out / "index.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 21 and float(table[3][K]) == 13000.0 and table[3]["file"] == ""
    rows = json.loads((out / "index.json").read_text())
    assert rows["sweep_file"] == "sweep.h5" and rows["rows"][20][K] == 30000.0
    with h5py.File(out / "sweep.h5") as f:
        assert rows["rows"][5]["bodies[2].position[1]"] == f["bodies[2].position"][5, -1, 1]
        first = {k: f[k][()] for k in f if k != "wall_time"}

    # rerun: everything taken from the sweep file, the same bits
    o = run_sweep(str(DECK), [f"{K}={values}"], out_dir=str(out), workers=2, outputs=OUTS,
                  progress=False)
    assert (o.n_cases, o.n_resumed, o.counts) == (21, 21, {"converged": 21})
    with h5py.File(out / "sweep.h5") as f:
        assert all(_bits(f[k][()]) == _bits(v) for k, v in first.items()
                   if np.asarray(v).dtype.kind in "biuf")

    # a sweep killed after two chunks: their parts stay; the next run takes them, solves the rest
    seen = []

    def stop(row):
        seen.append(row["case"])
        if len(seen) == 8:
            raise KeyboardInterrupt
    longer = "10000:32000:1000"                       # 23 cases: 2 new ones
    with pytest.raises(KeyboardInterrupt):
        run_sweep(str(DECK), [f"{K}={longer}"], out_dir=str(out), workers=1, outputs=OUTS,
                  progress=False, chunk_size=4, force=True, on_row=stop)
    parts = sorted(os.listdir(out / PARTS))
    assert len(parts) == 2 and (out / "sweep.h5").exists()   # the last complete file stays
    with h5py.File(out / "sweep.h5") as f:
        assert f.attrs["n_cases"] == 21
    os.unlink(out / "sweep.h5")                  # as if the killed sweep had been the first
    o = run_sweep(str(DECK), [f"{K}={longer}"], out_dir=str(out), workers=2, outputs=OUTS,
                  progress=False, chunk_size=4, rows=True)
    assert o.n_resumed == 8 and o.counts == {"converged": 23} and not (out / PARTS).exists()
    assert [r["case"] for r in o.rows if r["resumed"]] == sorted(seen)
    with h5py.File(out / "sweep.h5") as f:
        for k in OUTS:
            assert _bits(f[k][:21]) == _bits(first[k])


@pytest.fixture(scope="module")
def cluster():
    pytest.importorskip("distributed")
    from dask.distributed import LocalCluster
    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                     scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    yield c
    c.close()


def test_cli_scheduler_address_groups_and_per_case_files(tmp_path, cluster):
    out = tmp_path / "s"
    args = ["sweep", str(DECK), "--set", f"{K}=10000,20000", "--set",
            "Param_Static.method=FIM_S,MKEAM", "--scheduler", cluster.scheduler_address,
            "--out-dir", str(out), "--json", "--output", "bodies[2].position",
            "--per-case-files"]
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    assert js["n_cases"] == 4 and js["counts"] == {"converged": 4} and js["resumed"] == 0
    assert js["sweep_file"] == str(out / "sweep.h5")
    idx = json.loads((out / "index.json").read_text())
    assert [(row[K], row["Param_Static.method"]) for row in idx["rows"]] == \
        [(10000.0, "FIM_S"), (10000.0, "MKEAM"), (20000.0, "FIM_S"), (20000.0, "MKEAM")]
    assert [row["file"] for row in idx["rows"]] == [f"case_0000{i}.h5" for i in range(4)]
    with h5py.File(out / "sweep.h5") as f:
        assert f["Param_Static.method"].asstr()[()].tolist() == ["FIM_S", "MKEAM"] * 2
        assert f["file"].asstr()[()].tolist() == [f"case_0000{i}.h5" for i in range(4)]
        pos = f["bodies[2].position"][()]
    for i in range(4):                  # the case file and the sweep file agree, bitwise
        with h5py.File(out / f"case_0000{i}.h5") as c:
            assert json.loads(c.attrs["sweep_values"]) == {
                K: idx["rows"][i][K], "Param_Static.method": idx["rows"][i]["Param_Static.method"]}
            assert _bits(c["analysis_000/bodies/position"][:, 0]) == _bits(pos[i])
    # a rerun resumes every case; a deleted case file is solved again
    os.unlink(out / "case_00001.h5")
    r = CliRunner().invoke(cli, args)
    assert json.loads(r.stdout)["resumed"] == 3 and (out / "case_00001.h5").exists()
    assert "\x1b[" not in r.output and "\r[" not in r.output   # no progress bar off a TTY


def test_output_dataset_names_checked_against_the_schema(tmp_path):
    """A misspelt --output dataset is a usage error (exit 2) with a did-you-mean, not an
    empty column; groups come from the results schema (gears, couplers, curves, ...)."""
    r = CliRunner().invoke(cli, ["sweep", str(DECK), "--set", f"{K}=1,2", "--output",
                                 "bodies[2].positon", "--out-dir", str(tmp_path)])
    assert r.exit_code == 2, r.output
    assert "did you mean bodies[2].position?" in r.stderr
    assert not (tmp_path / "index.csv").exists() and not (tmp_path / "sweep.h5").exists()
    from poise.app.sweep import output_groups
    assert {"gears", "couplers", "curves", "contacts", "requests"} <= set(output_groups())


def test_sweep_file_rows_in_any_order_failed_cases_and_not_run(tmp_path):
    """The writer puts each chunk's rows where they belong, whatever order the chunks come
    in; a failed case keeps its status, exit code and message; rows not written read as empty
    status with NaN/-1 fills (a sweep marks them ``not_run``). No Dask: the worker's functions
    called directly."""
    xr = pytest.importorskip("xarray")
    from poise.app.chunks import SweepJob, pack
    from poise.app.sweep import frame_layout
    from poise.app.sweep_index import outputs_of, parse_outputs, source_item
    from poise.results.sweepfile import SweepWriter
    spec = poise.load_deck(str(DECK))
    params = [resolve_param(spec, "Param_Static.max_num_iter", "1,2,40,50,60")]
    cases = make_cases(params, "grid")
    outs = outputs_of(parse_outputs(spec, OUTS))
    over = {"method": "FIM_S", "fallback": False}
    job = SweepJob(DECK.read_bytes(), str(DECK), tuple(params), over, outs,
                   frame_layout(spec, params, cases, over), key="f")
    t = make_template(job, {})
    w = SweepWriter(str(tmp_path / "s.h5"), len(cases), job.layout.time, job.layout.analysis,
                    [(p.key, p.kind, [c[p.key] for c in cases]) for p in params],
                    [(o.text, source_item(o.group, o.dataset)) for o in outs],
                    {"deck": str(DECK), "units": "", "command": "test", "mode": "grid",
                     "parameters": {}, "overrides": {}, "outputs": "[]", "sweep_hash": "h",
                     "deck_sha256": spec.sha256})
    w.write(pack(solve_chunk(t, [(3, cases[3]), (0, cases[0])]), job))   # out of order
    w.write(pack(solve_chunk(t, [(2, cases[2])]), job))
    w.close(3)
    with xr.open_dataset(tmp_path / "s.h5", engine="h5netcdf") as ds:
        assert not ds.attrs["complete"] and ds.attrs["n_done"] == 3
        assert ds.status.values.tolist() == ["failed", "", "converged", "converged", ""]
        assert ds.exit_code.values.tolist() == [1, -1, 0, 0, -1]
        assert ds["Param_Static.max_num_iter"].values.tolist() == [1, 2, 40, 50, 60]
        ref = poise.solve(str(DECK), max_num_iter=1, quiet=True, **over)
        assert ref.status == "failed" and ds.message.values[0] == f"analysis 0: {ref.analyses[0].message}"
        assert int(ds.iterations[0]) == 1 and not bool(ds.converged[0, 0])
        assert np.isnan(ds["bodies[2].position"].values[1]).all()
        assert ds.iterations.values[1] == -1 and np.isnan(ds.imbalance.values[1])
        assert _bits(ds["bodies[2].position"].values[2]) == _bits(ds["bodies[2].position"].values[3])
    r = CliRunner().invoke(cli, ["show", str(tmp_path / "s.h5")])
    assert r.exit_code == 2 and "poise.open_sweep" in r.stderr
