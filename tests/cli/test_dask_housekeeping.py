"""What a sweep on the local Dask cluster leaves on stderr and in its directory: no dashboard
port warning (8787 taken), no traceback while the cluster shuts down, ``index.csv`` headers with
the units of the ``--output`` columns, and one run at a time per output directory (a second
sweep waits for the lock, then resumes what the first one solved)."""
from __future__ import annotations

import csv
import json
import logging
import socket
import subprocess
import sys
import textwrap

import pytest
from click.testing import CliRunner

from poise.core.dirlock import LOCK_NAME, directory_lock
from poise_cli.main import cli

from support.paths import DECKS

pytest.importorskip("distributed")

DECK = DECKS / "pendulum_multiturn.xml"
POISE_SET = "Force_SpringDamper[1].stiffness=10000,20000,30000"


def _sweep(out, *extra):
    return CliRunner().invoke(cli, ["sweep", str(DECK), "--set", POISE_SET, "--workers", "1",
                                    "--out-dir", str(out), *map(str, extra)])


def test_no_dashboard_port_warning_when_8787_is_taken(tmp_path):
    s = socket.socket()
    try:
        s.bind(("", 8787))
        s.listen(1)
    except OSError:
        pass                      # taken already: the case to check
    try:
        p = subprocess.run([sys.executable, "-m", "poise_cli", "sweep", str(DECK), "--set",
                            POISE_SET, "--workers", "1", "--out-dir", str(tmp_path / "s")],
                           capture_output=True, text=True, timeout=300)
    finally:
        s.close()
    assert p.returncode == 0, p.stderr
    assert "8787" not in p.stderr and "Port" not in p.stderr and "UserWarning" not in p.stderr
    assert "Traceback" not in p.stderr


def test_index_headers_say_the_units_of_the_output_columns(tmp_path):
    r = _sweep(tmp_path / "s", "--output", "bodies[2].position", "--output", "joints[1].force",
               "--quiet")
    assert r.exit_code == 0, r.output
    with open(tmp_path / "s" / "index.csv") as f:
        header = next(csv.reader(f))
    assert [h for h in header if "[" in h and h.endswith("]") and " [" in h] == [
        "wall_time [s]", *[f"bodies[2].position[{k}] [mm]" for k in range(3)],
        *[f"joints[1].force[{k}] [N]" for k in range(3)]]
    assert "Force_SpringDamper[1].stiffness" in header and "status" in header
    doc = json.loads((tmp_path / "s" / "index.json").read_text())
    assert doc["units"]["bodies[2].position[1]"] == "mm"
    assert doc["units"]["joints[1].force[0]"] == "N" and doc["units"]["wall_time"] == "s"
    assert "bodies[2].position[1]" in doc["rows"][0]          # rows keep the bare names


def test_closing_the_cluster_says_nothing():
    """A comm closed under a heartbeat while the cluster shuts down is logged with a traceback
    on a loaded machine (CommClosedError: Stream is closed): while a client and its cluster
    close, no Dask logger emits anything (children with levels of their own included), what
    closing raises is dropped, and the levels are restored afterwards."""
    from distributed.comm.core import CommClosedError

    from poise.app import engine
    names = ["distributed", "distributed.core", "distributed.client", "distributed.worker",
             "tornado.application", "asyncio"]
    logging.getLogger("distributed.client").setLevel(logging.WARNING)     # as Dask configures
    before = {n: logging.getLogger(n).level for n in names}
    with engine._quiet_shutdown():
        assert not any(logging.getLogger(n).isEnabledFor(logging.CRITICAL) for n in names)
        raise CommClosedError("in <TCP (closed) ...>: Stream is closed")
    assert {n: logging.getLogger(n).level for n in names} == before


def test_a_second_sweep_into_the_directory_waits_then_resumes(tmp_path):
    out = tmp_path / "s"
    assert _sweep(out, "--quiet").exit_code == 0                 # every case solved once
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import sys
        from poise.core.dirlock import directory_lock
        with directory_lock({str(out)!r}, "sweep"):
            print("held", flush=True)
            sys.stdin.read()
        """)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    second = None
    try:
        assert holder.stdout.readline().strip() == "held"
        second = subprocess.Popen(
            [sys.executable, "-m", "poise_cli", "sweep", str(DECK), "--set", POISE_SET,
             "--workers", "1", "--out-dir", str(out), "--json"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        waiting = second.stderr.readline()                       # said while it waits
    finally:
        holder.stdin.close()
        holder.wait(60)
    stdout, stderr = second.communicate(timeout=300)
    assert second.returncode == 0, stderr
    assert waiting.startswith(f"waiting for the poise sweep writing into {out} (poise sweep, "
                              "pid "), waiting
    assert json.loads(stdout)["reused"] == 3                     # resumed, nothing solved again


def test_two_sweeps_into_one_directory_solve_each_case_once(tmp_path):
    out = tmp_path / "s"
    args = [sys.executable, "-m", "poise_cli", "sweep", str(DECK), "--set", POISE_SET,
            "--workers", "1", "--out-dir", str(out), "--json"]
    a = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    b = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    docs = []
    for p in (a, b):
        stdout, stderr = p.communicate(timeout=600)
        assert p.returncode == 0, stderr
        docs.append(json.loads(stdout))
    assert sorted(d["reused"] for d in docs) == [0, 3]     # one solved all three, one resumed
    assert (out / LOCK_NAME).is_file()


def test_the_lock_tells_who_holds_it(tmp_path):
    said = []
    with directory_lock(str(tmp_path), "batch", say=said.append):
        pass
    assert said == []                                          # free: nothing said
    text = (tmp_path / LOCK_NAME).read_text()
    assert text.startswith("poise batch, pid ")
