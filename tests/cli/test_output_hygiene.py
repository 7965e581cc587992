"""stdout carries only the command's output (strict JSON under --json) and numerical warnings
never print as raw Python warnings: text a native library or a worker writes to fd 1 during a
solve goes to stderr (nowhere under --quiet); numpy RuntimeWarnings become run warnings (printed
once as ``warning: ...`` and recorded), nothing under --quiet."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from click.testing import CliRunner

import poise.app.api
from poise_cli.main import cli

from support.paths import ROOT
from support.results import make_result


DECK = ROOT / "decks" / "pendulum_multiturn.xml"


@pytest.mark.parametrize("quiet", [False, True])
def test_native_prints_never_reach_stdout(quiet):
    script = textwrap.dedent(f"""
        import ctypes, os, sys
        from poise_cli.streams import guarded_stdout
        libc = ctypes.CDLL(None)
        with guarded_stdout({quiet}):
            libc.printf(b"[IDAHandleFailure, Error: -4] native\\n")   # C stdio, buffered
            os.write(1, b"raw fd write\\n")
            print("python print")
        print("after", flush=True)
    """)
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stderr
    assert p.stdout == "after\n"
    for text in ("IDAHandleFailure", "raw fd write", "python print"):
        assert (text in p.stderr) is (not quiet)


def _warning_run(*a, **k):
    with np.errstate(over="warn", invalid="warn"):
        x = np.array([1e308]) * 10.0            # RuntimeWarning: overflow
        np.array([1e308]) * 10.0                # the same warning again (another line): once
        np.sqrt(np.array([-1.0]))               # RuntimeWarning: invalid value
    assert not np.isfinite(x[0])
    return make_result()


def test_numpy_warnings_are_run_warnings(tmp_path, monkeypatch):
    monkeypatch.setattr(poise.app.api, "run_deck", _warning_run)
    r = CliRunner().invoke(cli, ["solve", str(DECK), "-o", str(tmp_path / "o.h5"), "--json"])
    assert r.exit_code == 1, r.output         # make_result(): one failed analysis
    lines = [ln for ln in r.stderr.splitlines() if "RuntimeWarning" in ln]
    assert len(lines) == 2 and all(ln.startswith("warning: RuntimeWarning: ") for ln in lines)
    assert any("overflow" in ln for ln in lines) and any("invalid value" in ln for ln in lines)
    summary = json.loads(r.stdout)
    assert sum("RuntimeWarning" in w for w in summary["warnings"]) == 2
    from poise.results.hdf5 import read_results
    saved = read_results(str(tmp_path / "o.h5")).warnings
    assert sum("RuntimeWarning" in w for w in saved) == 2


def test_numpy_warnings_are_silent_under_quiet(tmp_path, monkeypatch):
    monkeypatch.setattr(poise.app.api, "run_deck", _warning_run)
    r = CliRunner().invoke(cli, ["solve", str(DECK), "-o", str(tmp_path / "o.h5"), "-q"])
    assert r.exit_code == 1
    assert r.stderr == ""


def test_json_stdout_is_strict_even_with_nan_values(tmp_path, monkeypatch):
    res = make_result()
    res.analyses[0].datasets["frames/imbalance"] = np.array([np.nan])
    res.timings["parse"] = float("inf")
    monkeypatch.setattr(poise.app.api, "run_deck", lambda *a, **k: res)
    r = CliRunner().invoke(cli, ["solve", str(DECK), "-o", str(tmp_path / "o.h5"), "--json"])

    def bad(token):
        raise ValueError(token)
    summary = json.loads(r.stdout, parse_constant=bad)
    assert summary["analyses"][0]["imbalance"] is None
