"""CLI tests: every command, every exit code, --json, atomic writes, light imports.

Most tests monkeypatch ``poise.app.api.run_deck`` / ``check_deck`` with hand-built results so the CLI
is tested independently of the numerical core; ``test_invalid_decks_subprocess`` runs the real
CLI on every ``decks/invalid/*.xml``.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from importlib.util import find_spec
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import poise
import poise.app.api
from poise.app.api import CheckReport
from poise.core.errors import DeckError, Problem, SourceLoc
from poise.results import hdf5
from poise.results.data import AnalysisResult, RunResult
from poise_cli.main import cli

from support.paths import ROOT


POISE = Path(sys.executable).with_name("poise")
LINE_RE = re.compile(r"^analysis \d+: \w+ \w+ (converged in|failed after) \d+ iterations?")
# the numbers of a summary line, parsed back (compared as numbers, never as formatted text)
NUM_LINE = re.compile(r"^analysis (\d+): (\w+) (\w+) (converged|failed) (?:in|after) (\d+) "
                      r"iterations?(?: \((\d+) frames\))?, imbalance (\S+?)"
                      r"(?: at frame (\d+) \(t=(\S+)\))?, (\S+) s\b")


def parsed_line(lines, index):
    """(analysis_type, method, status, iterations, frames, imbalance, frame, seconds) of the
    summary line of analysis ``index``."""
    for x in lines:
        m = NUM_LINE.match(x)
        if m and int(m.group(1)) == index:
            return (m.group(2), m.group(3), m.group(4), int(m.group(5)),
                    int(m.group(6) or 1), float(m.group(7)),
                    None if m.group(8) is None else int(m.group(8)), float(m.group(10)))
    raise AssertionError(f"no summary line for analysis {index}: {lines}")


def make_result(statuses=("converged",), warnings=()) -> RunResult:
    analyses = []
    for i, st in enumerate(statuses):
        ok = st == "converged"
        analyses.append(AnalysisResult(
            index=i, analysis_type="static", method="FIM_S", status=st,
            message="converged" if ok else "imbalance 1.2e+01 > max_imbalance after 25 iterations",
            settings={"method": "FIM_S"},
            datasets={
                "time": np.array([0.0]),
                "bodies/id": np.array([2]),
                "bodies/label": np.array(["link"]),
                "bodies/position": np.zeros((1, 1, 3)),
                "frames/converged": np.array([ok]),
                "frames/iterations": np.array([5 if ok else 25]),
                "frames/imbalance": np.array([3.2e-9 if ok else 12.0]),
                "frames/error": np.array([1e-10]),
                "frames/stability": np.array(["unknown"]),
            },
            attrs={"reactions_unique": True},
        ))
    return RunResult(deck="d.xml", deck_sha256="0" * 64, units="length=MILLIMETER",
                     active_effects=["gravity"], command="poise solve d.xml",
                     analyses=analyses, timings={"parse": 0.001, "analysis_000": 0.012},
                     counts={"residuals": 7}, warnings=list(warnings))


@pytest.fixture
def deck(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "pendulum.xml"
    p.write_text("<MotionSolve/>\n")
    return p


@pytest.fixture
def fake_run(monkeypatch):
    """Install a fake run_deck; returns the list of recorded calls."""
    calls = []

    def install(result=None, exc=None, progress_lines=()):
        def run_deck(path, overrides=None, command="", progress=None, quiet=False,
                     allow_user_code=False):
            calls.append({"path": path, "overrides": overrides, "command": command,
                          "quiet": quiet, "allow_user_code": allow_user_code})
            for line in progress_lines:
                progress(line)
            if exc is not None:
                raise exc
            return result
        monkeypatch.setattr(poise.app.api, "run_deck", run_deck)
        return calls
    return install


def invoke(*args):
    return CliRunner().invoke(cli, list(args), prog_name="poise")


def deck_error():
    return DeckError([
        Problem(SourceLoc("d.xml", 12, "Part", 3), "mass must be > 0", "mass"),
        Problem(SourceLoc("d.xml", 20, "Constraint_Joint", 7), "unknown marker id 99"),
    ])


# ---- help / version / light import ------------------------------------------------------------

def test_help():
    r = invoke("--help")
    assert r.exit_code == 0
    for cmd in ("solve", "check", "show"):
        assert cmd in r.output
    for cmd in ("solve", "check", "show"):
        r = invoke(cmd, "--help")
        assert r.exit_code == 0, r.output


def test_version():
    r = invoke("--version")
    assert r.exit_code == 0
    assert r.output.strip() == f"poise {poise.__version__}"


def test_import_is_light():
    code = ("import sys, poise_cli.main; "
            "print(','.join(m for m in ('numpy', 'scipy', 'h5py', 'lxml') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


@pytest.mark.skipif(not POISE.exists(), reason="console script not installed in this env")
def test_console_script_help():
    r = subprocess.run([str(POISE), "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "solve" in r.stdout


# ---- solve ------------------------------------------------------------------------------------

def test_solve_converged(deck, fake_run):
    calls = fake_run(make_result())
    r = invoke("solve", str(deck))
    assert r.exit_code == 0, r.output
    out = Path.cwd() / "pendulum.h5"
    assert out.exists()
    assert calls[0]["overrides"] == {}
    assert calls[0]["path"] == str(deck)
    lines = r.stderr.splitlines()
    assert any(LINE_RE.match(x) for x in lines), r.stderr
    got = parsed_line(lines, 0)
    assert got[:5] == ("static", "FIM_S", "converged", 5, 1) and got[6] is None
    assert got[5] == pytest.approx(3.2e-9, rel=1e-2) and got[7] == pytest.approx(0.012, rel=1e-2)
    assert f"wrote {out}" in lines
    assert r.stdout == ""
    assert "\x1b[" not in r.stderr  # no colours when stderr is not a TTY


def test_solve_overrides_only_given(deck, fake_run):
    calls = fake_run(make_result())
    r = invoke("solve", str(deck), "-o", "x.h5", "--method", "fim_d", "--max-num-iter", "50",
               "--max-imbalance", "1e-6", "--stability", "0.001")
    assert r.exit_code == 0, r.output
    assert calls[0]["overrides"] == {"method": "FIM_D", "max_num_iter": 50,
                                     "max_imbalance": 1e-6, "stability": 0.001}
    assert calls[0]["command"].startswith("poise ")
    assert Path("x.h5").exists()


def test_solve_failed_exit_1_file_written(deck, fake_run):
    fake_run(make_result(("converged", "failed")))
    r = invoke("solve", str(deck), "-o", "out.h5")
    assert r.exit_code == 1
    assert Path("out.h5").exists()
    assert "analysis 1: static FIM_S failed after 25 iterations" in r.stderr
    assert "1 of 2 analyses did not converge" in r.stderr
    s = hdf5.read_summary("out.h5")
    assert s["status"] == "failed"
    assert [a["status"] for a in s["analyses"]] == ["converged", "failed"]


def test_solve_json(deck, fake_run):
    fake_run(make_result(("converged", "failed")))
    r = invoke("solve", str(deck), "--json", "--quiet")
    assert r.exit_code == 1
    assert r.stderr == ""
    data = json.loads(r.stdout)
    for key in ("deck", "output", "status", "exit_code", "analyses", "timings"):
        assert key in data
    assert data["status"] == "failed" and data["exit_code"] == 1
    assert data["output"].endswith("pendulum.h5")
    a = data["analyses"][1]
    assert set(a) >= {"index", "analysis_type", "method", "status", "message", "frames",
                      "iterations", "imbalance"}
    assert (a["index"], a["frames"], a["iterations"], a["imbalance"]) == (1, 1, 25, 12.0)
    assert "write" in data["timings"]


def test_solve_quiet_and_warnings(deck, fake_run):
    w = "d.xml:4: <Part id=2>: unknown attribute 'colour' ignored"
    calls = fake_run(make_result(warnings=[w]))
    r = invoke("solve", str(deck))
    assert r.exit_code == 0
    assert f"warning: {w}" in r.stderr.splitlines()
    r = invoke("solve", str(deck), "-q")
    assert r.exit_code == 0 and r.stderr == ""
    # --quiet reaches the run (it silences the quasi-static progress bar)
    assert [c["quiet"] for c in calls] == [False, True]


def test_solve_runner_progress_not_duplicated(deck, fake_run):
    fake_run(make_result(), progress_lines=["analysis 0: static FIM_S converged (runner)"])
    r = invoke("solve", str(deck))
    assert r.exit_code == 0
    lines = [x for x in r.stderr.splitlines() if x.startswith("analysis 0:")]
    assert lines == ["analysis 0: static FIM_S converged (runner)"]


def test_solve_invalid_deck_exit_3(deck, fake_run):
    fake_run(exc=deck_error())
    r = invoke("solve", str(deck))
    assert r.exit_code == 3
    lines = r.stderr.splitlines()
    assert "d.xml:12: <Part id=3> mass: mass must be > 0" in lines
    assert "d.xml:20: <Constraint_Joint id=7>: unknown marker id 99" in lines
    assert "Traceback" not in r.stderr
    assert not Path("pendulum.h5").exists()


def test_solve_invalid_deck_json(deck, fake_run):
    fake_run(exc=deck_error())
    r = invoke("solve", str(deck), "--json")
    assert r.exit_code == 3
    data = json.loads(r.stdout)
    assert data["status"] == "invalid_deck" and data["exit_code"] == 3
    assert len(data["problems"]) == 2 and data["output"] is None


def test_solve_internal_error_exit_4(deck, fake_run):
    fake_run(exc=ZeroDivisionError("float division by zero"))
    r = invoke("solve", str(deck))
    assert r.exit_code == 4
    assert r.stderr.strip() == ("poise: internal error: ZeroDivisionError: float division by "
                                "zero; rerun with --debug for the traceback")
    r = invoke("solve", str(deck), "--debug")
    assert r.exit_code == 4
    assert "Traceback" in r.stderr and "ZeroDivisionError" in r.stderr


def test_solve_usage_errors_exit_2(deck, fake_run):
    fake_run(make_result())
    assert invoke("solve", "missing.xml").exit_code == 2
    assert invoke("solve", str(deck), "--method", "NEWTON").exit_code == 2
    assert invoke("solve", str(deck), "--max-num-iter", "0").exit_code == 2
    assert invoke("solve", str(deck), "--bogus").exit_code == 2
    assert invoke("solve", str(deck), "-o", "no/such/dir/out.h5").exit_code == 2
    assert invoke("frobnicate").exit_code == 2


def test_solve_atomic_write_failure(deck, fake_run, monkeypatch):
    fake_run(make_result(("converged", "converged")))
    real = hdf5._write_datasets

    def boom(group, datasets, where, *rest):
        if where.startswith("/analysis_001"):
            raise OSError(28, "No space left on device")
        return real(group, datasets, where, *rest)

    monkeypatch.setattr(hdf5, "_write_datasets", boom)
    r = invoke("solve", str(deck), "-o", "out.h5")
    assert r.exit_code == 2          # an I/O error naming the path (was exit 4, internal)
    assert "No space left on device" in r.stderr and "Traceback" not in r.stderr
    assert "out.h5" in r.stderr
    assert sorted(os.listdir(".")) == ["pendulum.xml"]  # no final file, no temp file


# ---- check ------------------------------------------------------------------------------------

def make_report(deck):
    return CheckReport(
        deck=str(deck),
        bodies=[{"id": 1, "label": "ground", "kind": "ground", "mass": 0.0},
                {"id": 2, "label": "link", "kind": "rigid", "mass": 1.5}],
        constraints=[{"tag": "Constraint_Joint", "id": 5, "type": "REVOLUTE",
                      "n_equations": 5, "line": 30}],
        forces=[{"tag": "Force_SpringDamper", "id": 9, "type": "TRANSLATION", "line": 40}],
        n_coordinates=6, n_equations=5, n_redundant=0, dof=1, redundant=[],
        active_effects=["gravity", "revolute"], warnings=["d.xml:2: <Units>: note"],
        analyses=[{"analysis_type": "static", "method": "FIM_D", "n_frames": 1}],
    )


def test_check(deck, monkeypatch):
    monkeypatch.setattr(poise.app.api, "check_deck", lambda path: make_report(path))
    r = invoke("check", str(deck))
    assert r.exit_code == 0, r.output
    out = r.stdout
    for needle in ("bodies: 2", "constraints: 1 (5 equations)", "degrees of freedom: 1",
                   "redundant equations: 0", "active effects: gravity, revolute", "REVOLUTE"):
        assert needle in out
    assert "warning: d.xml:2: <Units>: note" in r.stderr
    r = invoke("check", str(deck), "--json")
    assert r.exit_code == 0
    data = json.loads(r.stdout)
    assert data["dof"] == 1 and data["bodies"][1]["label"] == "link"
    assert data["status"] == "valid"


def test_check_invalid_deck(deck, monkeypatch):
    def bad(path):
        raise deck_error()
    monkeypatch.setattr(poise.app.api, "check_deck", bad)
    r = invoke("check", str(deck))
    assert r.exit_code == 3
    assert "d.xml:12: <Part id=3> mass: mass must be > 0" in r.stderr
    assert "Traceback" not in r.stderr


def test_check_internal_error(deck, monkeypatch):
    def bad(path):
        raise KeyError("oops")
    monkeypatch.setattr(poise.app.api, "check_deck", bad)
    r = invoke("check", str(deck))
    assert r.exit_code == 4
    assert "rerun with --debug" in r.stderr and "Traceback" not in r.stderr


# ---- show -------------------------------------------------------------------------------------

def test_show(tmp_path):
    path = tmp_path / "r.h5"
    res = make_result(("converged", "failed"))
    res.analyses[1].datasets["time"] = np.arange(3.0)
    res.analyses[1].datasets["frames/iterations"] = np.array([3, 4, 25])
    res.analyses[1].datasets["frames/imbalance"] = np.array([1e-9, 1e-9, 12.0])
    res.analyses[1].datasets["frames/stability"] = np.array(["stable", "stable", "unknown"])
    res.analyses[1].datasets["frames/converged"] = np.array([True, True, False])
    res.analyses[1].datasets["frames/error"] = np.full(3, 1e-10)
    res.analyses[1].datasets["bodies/position"] = np.zeros((3, 1, 3))
    hdf5.write_results(res, str(path))
    r = invoke("show", str(path))
    assert r.exit_code == 0, r.output
    out = r.stdout
    assert "status: failed" in out
    got = parsed_line(out.splitlines(), 0)
    assert got[:5] == ("static", "FIM_S", "converged", 5, 1)
    assert got[5] == pytest.approx(3.2e-9, rel=1e-2) and got[7] == pytest.approx(0.012, rel=1e-2)
    assert "analysis 1: static FIM_S failed after 32 iterations (3 frames)" in out
    assert "stability: stable x2, unknown x1" in out
    assert "timings [s]:" in out and "counts: residuals 7" in out
    r = invoke("show", str(path), "--json")
    data = json.loads(r.stdout)
    assert data["status"] == "failed"
    assert data["analyses"][1]["stability"] == ["stable", "stable", "unknown"]


def test_show_after_solve(deck, fake_run):
    fake_run(make_result())
    assert invoke("solve", str(deck), "-q").exit_code == 0
    r = invoke("show", "pendulum.h5")
    assert r.exit_code == 0 and "status: converged" in r.stdout


def test_show_not_results(tmp_path):
    p = tmp_path / "x.h5"
    p.write_text("not hdf5")
    r = invoke("show", str(p))
    assert r.exit_code == 2
    assert "not an HDF5 file" in r.stderr and "Traceback" not in r.stderr
    assert invoke("show", str(tmp_path / "missing.h5")).exit_code == 2


# ---- the real CLI on invalid decks ------------------------------------------------------------

INVALID_DECKS = sorted((ROOT / "decks" / "invalid").glob("*.xml"))
HAVE_RUNNER = find_spec("poise.app.runner") is not None
HAVE_PARSER = find_spec("poise.deck.parser") is not None

# Until poise.app.runner exists, run the real CLI in a subprocess with run_deck/check_deck replaced by
# the real deck parser (which raises the DeckError); once the runner exists, nothing is replaced.
_SHIM = """
import poise.app.api as api
from poise.deck.parser import load_deck
def _parse_only(path, *args, **kwargs):
    load_deck(path)
    raise SystemExit("deck unexpectedly parsed without error")
api.run_deck = api.check_deck = _parse_only
"""
_ENTRY = "from poise_cli.main import cli; cli(prog_name='poise')"


def run_cli(args, cwd):
    code = _ENTRY if HAVE_RUNNER else _SHIM + _ENTRY
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


@pytest.mark.skipif(not (HAVE_RUNNER or HAVE_PARSER), reason="no deck parser yet")
@pytest.mark.parametrize("deck_path", INVALID_DECKS, ids=lambda p: p.name)
def test_invalid_decks_subprocess(deck_path, tmp_path):
    r = run_cli(["solve", str(deck_path), "-o", str(tmp_path / "out.h5")], tmp_path)
    assert r.returncode == 3, r.stderr
    assert re.search(re.escape(deck_path.name) + r":\d+:", r.stderr), r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out.h5").exists()
    assert os.listdir(tmp_path) == []


@pytest.mark.skipif(not (HAVE_RUNNER or HAVE_PARSER), reason="no deck parser yet")
@pytest.mark.skipif(not (ROOT / "decks/invalid/several_errors.xml").exists(),
                    reason="decks/invalid/several_errors.xml not present")
def test_invalid_deck_all_problems_check_json(tmp_path):
    deck_path = ROOT / "decks/invalid/several_errors.xml"
    r = run_cli(["check", str(deck_path), "--json"], tmp_path)
    assert r.returncode == 3, r.stderr
    located = [x for x in r.stderr.splitlines() if re.match(r".*several_errors\.xml:\d+: ", x)]
    assert len(located) >= 2, r.stderr  # every problem reported, not just the first
    data = json.loads(r.stdout)
    assert data["exit_code"] == 3 and data["status"] == "invalid_deck"
    assert len(data["problems"]) == len(located)
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("module", ["poise_cli", "poise_cli.main"])
def test_python_dash_m(module):
    r = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == f"poise {poise.__version__}"


@pytest.mark.parametrize("opt,val", [("--max-imbalance", "nan"), ("--max-error", "inf"),
                                     ("--stability", "nan"), ("--max-imbalance", "-1")])
def test_non_finite_solver_options_are_usage_errors(tmp_path, opt, val):
    r = CliRunner().invoke(cli, ["solve", str(ROOT / "decks" / "pendulum_multiturn.xml"), opt, val,
                                 "-o", str(tmp_path / "o.h5")])
    assert r.exit_code == 2 and opt in r.output
    assert not (tmp_path / "o.h5").exists()


def test_non_finite_api_override_is_a_usage_error():
    from poise.app.api import run_deck
    from poise.core.errors import UsageError
    with pytest.raises(UsageError, match="max_error must be a finite number >= 1e-100, got nan"):
        run_deck(str(ROOT / "decks" / "pendulum_multiturn.xml"), {"max_error": float("nan")})
