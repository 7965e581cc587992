"""A run killed with SIGKILL mid-solve never leaves a corrupt or half-written results file.

The results file is written only after every analysis finished, through a temporary file in the
same directory that is renamed onto the final name (atomic). A SIGKILL before the rename leaves
the previous file (if any) untouched; a temporary ``.<name>.tmp-<pid>`` may remain only if the
kill lands inside the write itself, and it never carries the final name.
"""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest

from support.paths import ROOT


POISE = str(Path(sys.executable).parent / "poise")


def _gen_chain(n, path):
    subprocess.run([sys.executable, str(ROOT / "decks" / "gen_chain.py"), str(n), "--joint",
                    "revolute", "-o", str(path)], check=True)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_sigkill_mid_solve_keeps_previous_results_intact(tmp_path):
    out = tmp_path / "res.h5"
    small = ROOT / "decks" / "pendulum_multiturn.xml"
    r = subprocess.run([POISE, "solve", str(small), "-o", str(out), "-q"], capture_output=True)
    assert r.returncode == 0
    before = out.read_bytes()
    big = tmp_path / "chain.xml"
    _gen_chain(8000, big)
    p = subprocess.Popen([POISE, "solve", str(big), "-o", str(out), "-q"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    assert p.poll() is None, "the solve finished before it could be killed; use a bigger deck"
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    assert p.returncode == -signal.SIGKILL
    # the previous results are untouched and still a valid poise results file
    assert out.read_bytes() == before
    with h5py.File(out) as f:
        assert f.attrs["format"] == "poise-results"
        assert f.attrs["status"] == "converged"
    # nothing else carries the final name; a temp file (if any) is hidden and named as such
    others = [q.name for q in tmp_path.iterdir() if q.name not in ("res.h5", "chain.xml")]
    assert all(n.startswith(".res.h5.tmp-") for n in others), others


def test_sigkill_mid_solve_leaves_no_results_file(tmp_path):
    out = tmp_path / "new.h5"
    big = tmp_path / "chain.xml"
    _gen_chain(8000, big)
    p = subprocess.Popen([POISE, "solve", str(big), "-o", str(out), "-q"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    assert p.poll() is None
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    assert not out.exists()
