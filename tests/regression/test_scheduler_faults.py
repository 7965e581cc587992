"""A ``--scheduler`` that is not a Dask scheduler (the reliability study's fake_scheduler.py): a
port that accepts connections and never answers ends batch and sweep with exit 2 within about
``--worker-timeout`` (it never returned); one that answers random bytes with exit 2 "not a
Dask scheduler" (it was exit 4, MemoryError: 3 EiB); a port nobody listens on "cannot
connect"."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from poise_cli.main import cli

from support.paths import DATA, DECKS

FAKE = DATA / "reliability" / "decks" / "fake_scheduler.py"
DECK = DECKS / "pendulum_multiturn.xml"

pytest.importorskip("distributed")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(params=["silent", "garbage"])
def fake(request):
    port = _free_port()
    p = subprocess.Popen([sys.executable, str(FAKE), request.param, str(port)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 60
        while True:
            assert p.poll() is None, "fake scheduler exited"
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            assert time.monotonic() < end, "fake scheduler did not start"
            time.sleep(0.1)
        yield request.param, f"tcp://127.0.0.1:{port}"
    finally:
        p.kill()
        p.wait()


@pytest.mark.parametrize("command", ["batch", "sweep"])
def test_a_fake_scheduler_is_a_usage_error(fake, command, tmp_path):
    mode, address = fake
    args = [command, str(DECK)] + (["--set", "Force_SpringDamper[1].stiffness=1e4,2e4"]
                                   if command == "sweep" else [])
    r = CliRunner().invoke(cli, args + ["--scheduler", address, "--worker-timeout", "3",
                                        "--out-dir", str(tmp_path / "o"), "--json"])
    assert r.exit_code == 2, r.output
    line = r.stderr.strip().splitlines()[-1]
    if mode == "silent":
        assert line == f"poise: error: --scheduler '{address}': no answer from a Dask " \
                       "scheduler within 3 s", line
    else:
        assert line == f"poise: error: --scheduler '{address}': not a Dask scheduler (its " \
                       "answer is not Dask's protocol)", line
    doc = json.loads(r.stdout)
    assert doc["exit_code"] == 2 and doc["status"] == "usage_error"
    assert "Traceback" not in r.stderr and "MemoryError" not in r.stderr


def test_nobody_listening_cannot_connect(tmp_path):
    address = f"tcp://127.0.0.1:{_free_port()}"
    r = CliRunner().invoke(cli, ["batch", str(DECK), "--scheduler", address,
                                 "--worker-timeout", "2", "--out-dir", str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    assert f"--scheduler '{address}': cannot connect" in r.stderr
