"""Decks that broke poise (tests/data/reliability/, copied from the reliability study) end cleanly.

Each deck runs as ``poise solve DECK -o OUT --json`` in a subprocess with a 20 s timeout and must
end with a correct answer (exit 0), a clean non-convergence (exit 1, results file written) or a
located deck error (exit 3, every problem line ``FILE:LINE: ...``): never an internal error, a
hang or a traceback, with strict JSON on stdout (no NaN/Infinity, nothing else). Decks naming a
user script need an explicit opt-in: without it they are invalid (exit 3) and the script never
runs. The decks run two at a time in threads (the processes do the work).
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from support.paths import DATA


DECKS = DATA / "reliability" / "decks"
POISE = Path(sys.executable).with_name("poise")
TIMEOUT = 20.0
NAMES = sorted(p.name for p in DECKS.glob("*.xml"))
LOCATED = re.compile(r"^[^\s:][^:]*:\d+: \S")
SIDE_EFFECT = "ARBITRARY CODE RAN"          # what evil_import.py prints when it is imported


def _strict_json(text: str):
    def bad(token):
        raise ValueError(f"non-strict JSON constant {token!r}")
    return json.loads(text, parse_constant=bad)


def _run(name: str, tmp: Path) -> dict:
    out = tmp / (Path(name).stem + ".h5")
    cmd = [str(POISE), "solve", str(DECKS / name), "-o", str(out), "--json"]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT, cwd=tmp,
                           errors="replace")
    except subprocess.TimeoutExpired:
        return {"timeout": True, "out": out}
    return {"timeout": False, "code": p.returncode, "stdout": p.stdout, "stderr": p.stderr,
            "out": out}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every deck's run, two subprocesses at a time (started on first use)."""
    tmp = tmp_path_factory.mktemp("reliability")
    pool = ThreadPoolExecutor(max_workers=2)
    futs = {}
    for n in NAMES:
        d = tmp / Path(n).stem
        d.mkdir()
        futs[n] = pool.submit(_run, n, d)
    yield futs
    pool.shutdown(wait=True, cancel_futures=True)


def test_all_decks_copied():
    assert len(NAMES) >= 30
    for name in ("evil_import.py", "elem_user_routines.py", "sysexit0_import.py",
                 "sysexit3_import.py"):
        assert (DECKS / name).is_file()


@pytest.mark.parametrize("name", NAMES)
def test_reliability_deck_ends_cleanly(runs, name):
    r = runs[name].result()
    assert not r["timeout"], f"{name}: no result within {TIMEOUT} s"
    code, stdout, stderr = r["code"], r["stdout"], r["stderr"]
    where = f"{name}: exit {code}\nstderr:\n{stderr[-3000:]}\nstdout:\n{stdout[-2000:]}"
    assert code in (0, 1, 3), where
    assert "Traceback" not in stderr, where
    summary = _strict_json(stdout)                    # the whole of stdout is one JSON value
    assert isinstance(summary, dict) and summary.get("exit_code") == code, where
    assert SIDE_EFFECT not in stderr + stdout, where
    if code == 3:
        problems = [ln for ln in stderr.splitlines()
                    if ln.strip() and not ln.startswith(("poise: ", "warning: "))]
        assert problems, where
        for ln in problems:
            assert LOCATED.match(ln), f"unlocated problem line {ln!r}\n{where}"
    if code == 1:
        assert r["out"].is_file(), where
    if name.startswith("user_"):
        assert code == 3, f"a user script ran without an opt-in\n{where}"
    if name == "mkeam_converged_wrong_answer.xml" and code == 0:
        # body 3 (1 kg, on a translational joint along x) carries 1e-6 N through a 1e-9 N/mm
        # spring of free length 50 mm hung from body 2, which a 1e12 N/mm spring keeps at
        # x = 100 mm (+1e-9): the spring stretches 1e-6/1e-9 = 1000 mm, so x3 = 100 + 50 + 1000.
        from poise.results.hdf5 import read_results
        res = read_results(str(r["out"]))
        a = res.analyses[-1]
        ids = list(a.datasets.get("bodies/id", res.model_datasets.get("bodies/id")))
        x3 = float(a.datasets["bodies/position"][-1][ids.index(3)][0])
        assert abs(x3 - 1150.0) < 1e-3 * 1150.0, f"converged to the wrong answer x3={x3}"
