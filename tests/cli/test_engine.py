"""Batch and sweep on one engine: a real ``dask scheduler`` (started here on
127.0.0.1, a free port) with zero workers makes sweep and batch say they wait for workers, then
exit 2 within --worker-timeout, saying why (the last progress line: "gave up"), with nothing from Dask under --quiet; batch runs on a scheduler with one worker;
``batch --json`` and ``sweep --json`` have one shape."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from poise_cli.main import cli

from support.paths import DECKS


GOOD = DECKS / "pendulum_multiturn.xml"
GOOD2 = DECKS / "double_pendulum.xml"
SET = "Force_SpringDamper[1].stiffness=10000,20000"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, proc, seconds: float = 60) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        assert proc.poll() is None, "dask scheduler exited"
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise TimeoutError("dask scheduler did not start")


def _stop(proc) -> None:
    proc.terminate()
    try:
        proc.wait(20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@pytest.fixture
def scheduler():
    """A ``dask scheduler`` on 127.0.0.1 (no dashboard); yields its address."""
    port = _free_port()
    p = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1",
                          "--port", str(port), "--no-dashboard"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_port(port, p)
        yield f"tcp://127.0.0.1:{port}", p
    finally:
        _stop(p)


def _inv(*args):
    return CliRunner().invoke(cli, [*map(str, args)])


@pytest.mark.parametrize("quiet", [False, True])
def test_zero_workers_sweep_and_batch_exit_2_within_the_timeout(scheduler, tmp_path, quiet):
    address, _ = scheduler
    q = ["--quiet"] if quiet else []
    t0 = time.monotonic()
    r = _inv("sweep", GOOD, "--set", SET, "--scheduler", address, "--worker-timeout", 3,
             "--out-dir", tmp_path / "s", *q)
    assert r.exit_code == 2, r.output
    assert time.monotonic() - t0 < 30
    t0 = time.monotonic()
    rb = _inv("batch", GOOD, GOOD2, "--scheduler", address, "--worker-timeout", 3,
              "--out-dir", tmp_path / "b", "--json", *q)
    assert rb.exit_code == 2, rb.output
    assert time.monotonic() - t0 < 30
    for res in (r, rb):
        lines = res.stderr.splitlines()
        assert lines[-1].startswith("poise: error: no Dask worker at tcp://127.0.0.1:")
        assert "for 3 s" in lines[-1] and "2 of 2" in lines[-1]
        if quiet:        # nothing but the error: no Dask log line or warning
            assert lines == lines[-1:], res.stderr
        else:            # said while waiting, and the last progress line says it gave up
            assert f"waiting for Dask workers at {address} (up to 3 s)" in lines, res.stderr
            assert lines[-2].startswith("poise: ") and lines[-2].endswith(", gave up"), lines
            assert "0/2" in lines[-2]
    doc = json.loads(rb.stdout)
    assert doc["status"] == "no_workers" and doc["exit_code"] == 2 and doc["rows"] == []
    # what finished is kept: the index / summary exist (here empty)
    assert json.loads((tmp_path / "s" / "index.json").read_text())["rows"] == []
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["rows"] == []


def test_batch_on_a_scheduler_with_one_worker_and_one_json_shape(scheduler, tmp_path):
    address, _ = scheduler
    w = subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nworkers", "1",
                          "--nthreads", "1", "--no-dashboard"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        rb = _inv("batch", GOOD, GOOD2, "--scheduler", address, "--out-dir", tmp_path / "b",
                  "--json", "--worker-timeout", 60)
        assert rb.exit_code == 0, rb.output
        b = json.loads(rb.stdout)
        assert [Path(x["deck"]).name for x in b["rows"]] == [GOOD.name, GOOD2.name]
        assert all(x["status"] == "converged" and Path(x["output"]).is_file() for x in b["rows"])
        rs = _inv("sweep", GOOD, "--set", SET, "--scheduler", address, "--out-dir",
                  tmp_path / "s", "--json")
        assert rs.exit_code == 0, rs.output
        s = json.loads(rs.stdout)
    finally:
        _stop(w)
    common = ["command", "out_dir", "exit_code", "n", "counts", "reused", "table"]
    assert list(b)[:7] == list(s)[:7] == common and list(b)[-1] == list(s)[-1] == "rows"
    assert (b["command"], s["command"]) == ("batch", "sweep")
    assert b["n"] == s["n"] == 2 and b["counts"] == s["counts"] == {"converged": 2}
    assert len(s["rows"]) == 2 and s["rows"][1]["Force_SpringDamper[1].stiffness"] == 20000.0
    # up to date: both reuse every row
    rb = _inv("batch", GOOD, GOOD2, "--out-dir", tmp_path / "b", "--json", "-j", "1")
    assert json.loads(rb.stdout)["reused"] == 2


def test_batch_scheduler_without_dask_exits_2(tmp_path, monkeypatch):
    for n in ("dask", "distributed"):
        monkeypatch.setitem(sys.modules, n, None)
    r = _inv("batch", GOOD, "--scheduler", "tcp://127.0.0.1:1", "--out-dir", tmp_path)
    assert r.exit_code == 2 and "pip install 'poise[sweep]'" in r.stderr
