"""Decks run code only when the user allows it.

* Python user routines (``script_name``) run only with ``--allow-user-code`` /
  ``allow_user_code=True``; without it the deck is a located deck error (exit 3) naming the flag
  and the script is never imported; ``poise check`` never imports it.
* Scripts resolve only inside the deck's directory tree (absolute, ``..``, symlinks out:
  refused, also with the flag).
* Anything a script raises at import (``SystemExit(0)`` too) is a located error (exit 3); a
  routine raising during the solve fails it cleanly (exit 1, results written).
* ``poise batch`` isolates such a deck and its up-to-date check covers the scripts.

The model: a point body (mass m) under gravity -g Y held by a user GFOSUB pulling it towards
(0, y0, 0) with stiffness k: the equilibrium is (0, y0 - m g / k, 0) in closed form.
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from support.paths import DECKS


RELIABILITY = Path("/work/shared/reliability/decks")
POISE = [sys.executable, "-m", "poise_cli"]
G, M, K, Y0 = 9.81, 2.0, 50.0, 1.0

DECK = """<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Force_Gravity grav_x="0" grav_y="-{g}" grav_z="0"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="10"/>
    <Reference_Marker id="10" body_id="1"/>
    <Body_Point id="2" cg_id="20" mass="{m}"/>
    <Reference_Marker id="20" body_id="2" pos_x="0.1" pos_y="-0.2" pos_z="0.05"/>
    <Force_Vector_OneBody id="7" type="FORCEONLY" marker_id="20"
      usrsub_param_string="USER(20, {k}, {y0})" usrsub_fnc_name="{fn}" script_name="{script}"
      interpreter="PYTHON"/>
  </Model>
  <Command>
    <Simulate analysis_type="Static" end_time="0.0"/>
    <Stop/>
  </Command>
</MotionSolve>
"""

ROUTINE = """
def gfosub_pull(id, time, par, q):
    i, k, y0 = int(par[0]), par[1], par[2]
    p = q.P(i)
    return [-k * p[0], -k * (p[1] - y0), -k * p[2]]
"""


def _deck(d: Path, script="routine.py", fn="gfosub_pull", name="pull.xml", m=M, k=K) -> Path:
    p = d / name
    p.write_text(DECK.format(g=G, m=m, k=k, y0=Y0, fn=fn, script=script))
    return p


def _script(path: Path, marker: Path | None = None, extra: str = "", k_scale=None) -> Path:
    """A user script; ``marker``: it creates that file when imported (proof that it ran)."""
    head = f"open({str(marker)!r}, 'w').close()\n" if marker else ""
    body = ROUTINE if k_scale is None else ROUTINE.replace("k, y0 = int(par[0]), par[1]",
                                                           f"k, y0 = int(par[0]), {k_scale} * par[1]")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(head + body + extra)
    return path


def _poise(*args, cwd=None):
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return subprocess.run([*POISE, *map(str, args)], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=120)


def _located(stderr: str, deck: Path) -> list[str]:
    """Every problem line starts ``FILE:LINE: <Tag id=N>``; returns them (at least one)."""
    lines = [ln for ln in stderr.splitlines() if ln and not ln.startswith("poise:")]
    assert lines, stderr
    for ln in lines:
        assert ln.startswith(f"{deck}:"), ln
        assert ln.split(":", 2)[1].isdigit(), ln
        assert "<Force_Vector_OneBody id=7>" in ln, ln
    assert "Traceback" not in stderr
    return lines


def _y_expected(m=M, k=K):
    return Y0 - m * G / k


def _position(h5: Path) -> np.ndarray:
    from poise.results.hdf5 import read_results
    res = read_results(str(h5))
    return np.asarray(res.analyses[-1].datasets["bodies/position"])[-1, 0]


# ------------------------------------------------------------------------- opt-in
def test_solve_refuses_user_code_without_the_flag(tmp_path):
    marker = tmp_path / "RAN"
    _script(tmp_path / "routine.py", marker)
    deck = _deck(tmp_path)
    out = tmp_path / "o.h5"
    r = _poise("solve", deck, "-o", out, "--json")
    assert r.returncode == 3, r.stderr
    (line,) = _located(r.stderr, deck)
    assert "--allow-user-code" in line and "gfosub_pull" in line and "routine.py" in line
    doc = json.loads(r.stdout)                  # strict JSON on stdout
    assert doc["exit_code"] == 3 and doc["status"] == "invalid_deck"
    assert not marker.exists(), "the script ran without --allow-user-code"
    assert not out.exists()


def test_solve_with_the_flag_runs_the_routine(tmp_path):
    marker = tmp_path / "RAN"
    script = _script(tmp_path / "routine.py", marker, extra="\nprint('user text on stdout')\n")
    deck = _deck(tmp_path)
    out = tmp_path / "o.h5"
    r = _poise("solve", deck, "-o", out, "--allow-user-code", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)          # the script's print went to stderr, stdout is JSON
    assert doc["exit_code"] == 0
    assert "user text on stdout" in r.stderr
    assert marker.exists()
    np.testing.assert_allclose(_position(out), [0.0, _y_expected(), 0.0], atol=1e-9)
    import h5py
    with h5py.File(out, "r") as f:
        files = json.loads(f.attrs["input_files"])
    assert files == {str(script.resolve()): hashlib.sha256(script.read_bytes()).hexdigest()}


def test_python_api_opt_in(tmp_path):
    import poise
    from poise.app.api import run_deck
    from poise.core.errors import DeckError
    from poise.app.runner import run_spec
    marker = tmp_path / "RAN"
    _script(tmp_path / "routine.py", marker)
    deck = _deck(tmp_path)
    for call in (lambda: poise.solve(deck), lambda: run_deck(str(deck)),
                 lambda: run_spec(poise.load_deck(str(deck))),
                 lambda: poise.solve(poise.load_deck(str(deck)))):
        with pytest.raises(DeckError, match="allow_user_code=True"):
            call()
    assert not marker.exists()
    for res in (poise.solve(deck, allow_user_code=True),
                run_deck(str(deck), allow_user_code=True),
                poise.solve(poise.load_deck(str(deck)), allow_user_code=True, method="FIM_S")):
        p = np.asarray(res.analyses[0].datasets["bodies/position"])[-1, 0]
        np.testing.assert_allclose(p, [0.0, _y_expected(), 0.0], atol=1e-9)
    assert marker.exists()


def test_check_never_runs_user_code(tmp_path):
    marker = tmp_path / "RAN"
    _script(tmp_path / "routine.py", marker, extra="\nraise SystemExit(0)\n")
    deck = _deck(tmp_path)
    r = _poise("check", deck, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert not marker.exists()
    assert doc["user_routines"] == [dict(tag="Force_Vector_OneBody", id=7, script="routine.py",
                                         function="gfosub_pull", line=10)]
    assert doc["n_coordinates"] == 3 and doc["dof"] == 3      # a point body, no constraints
    r = _poise("check", deck)
    assert r.returncode == 0 and "gfosub_pull" in r.stdout and "not run" in r.stdout


def test_check_user_constraints_dof_unknown(tmp_path):
    """Constraint rows of a user constraint are known only by calling it: dof is reported as
    unknown, with the count without them (6 rigid + 3 point coordinates, no other
    constraints)."""
    deck = tmp_path / "uc.xml"
    deck.write_text((DECKS / "elem_user_constraint.xml").read_text())
    marker = tmp_path / "RAN"
    _script(tmp_path / "elem_user_routines.py", marker)
    r = _poise("check", deck, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["dof"] is None and doc["dof_without_user_constraints"] == 9
    assert [u["function"] for u in doc["user_routines"]] == ["ucosub_spherical",
                                                            "ucosub_inplane"]
    assert not marker.exists()
    r = _poise("check", deck)
    assert r.returncode == 0 and "degrees of freedom: unknown" in r.stdout


# ------------------------------------------------------------------------- confinement
def _escapes(tmp_path):
    """(deck dir, script_name) pairs whose script lies outside the deck's directory."""
    outside = tmp_path / "outside"
    deckdir = tmp_path / "decks"
    deckdir.mkdir()
    evil = _script(outside / "evil.py", tmp_path / "RAN")
    (deckdir / "link.py").symlink_to(evil)
    (deckdir / "sub").mkdir()
    (deckdir / "sub" / "evil.py").write_text(evil.read_text())
    return deckdir, ["../outside/evil.py", str(evil), "link.py", "sub/../sub/evil.py",
                     "./../decks/../outside/evil.py"]


@pytest.mark.parametrize("flag", [[], ["--allow-user-code"]])
def test_scripts_outside_the_deck_directory_are_refused(tmp_path, flag):
    deckdir, names = _escapes(tmp_path)
    marker = tmp_path / "RAN"
    for k, name in enumerate(names):
        deck = _deck(deckdir, script=name, name=f"d{k}.xml")
        for cmd in (["solve", deck, "-o", tmp_path / "o.h5", *flag], ["check", deck]):
            r = _poise(*cmd)
            assert r.returncode == 3, (name, cmd, r.stderr)
            (line,) = _located(r.stderr, deck)
            assert "script_name" in line and ("leaves the deck's directory" in line
                                              or "outside the deck's directory" in line), line
            assert not marker.exists(), f"{name}: the script ran"
    assert not (tmp_path / "o.h5").exists()


def test_script_in_a_subdirectory_is_allowed(tmp_path):
    _script(tmp_path / "lib" / "routine.py")
    deck = _deck(tmp_path, script="lib/routine.py")
    r = _poise("solve", deck, "-o", tmp_path / "o.h5", "--allow-user-code")
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(_position(tmp_path / "o.h5"), [0, _y_expected(), 0], atol=1e-9)


# ------------------------------------------------------------------------- raising scripts
@pytest.mark.parametrize("stmt,what", [("raise SystemExit(0)", "SystemExit(0)"),
                                       ("raise SystemExit(3)", "SystemExit(3)"),
                                       ("import sys; sys.exit()", "SystemExit(None)"),
                                       ("raise KeyboardInterrupt", "KeyboardInterrupt"),
                                       ("1 / 0", "ZeroDivisionError")])
def test_script_raising_at_import_is_a_located_error(tmp_path, stmt, what):
    _script(tmp_path / "routine.py", extra=f"\n{stmt}\n")
    deck = _deck(tmp_path)
    out = tmp_path / "o.h5"
    r = _poise("solve", deck, "-o", out, "--allow-user-code")
    assert r.returncode == 3, (r.returncode, r.stderr)
    (line,) = _located(r.stderr, deck)
    assert what in line and "routine.py" in line and "gfosub_pull" in line, line
    assert not out.exists()


@pytest.mark.parametrize("stmt,what", [("raise SystemExit(0)", "SystemExit(0)"),
                                       ("raise KeyboardInterrupt", "KeyboardInterrupt")])
def test_routine_raising_during_the_solve_fails_it_cleanly(tmp_path, stmt, what):
    """The first call (at compile) succeeds; a later call raises: exit 1, results written,
    the message names the routine and the script."""
    extra = f"""
_n = [0]
def gfosub_late(id, time, par, q):
    _n[0] += 1
    if _n[0] > 2:
        {stmt}
    return gfosub_pull(id, time, par, q)
"""
    _script(tmp_path / "routine.py", extra=extra)
    deck = _deck(tmp_path, fn="gfosub_late")
    out = tmp_path / "o.h5"
    r = _poise("solve", deck, "-o", out, "--allow-user-code", "--json", "--no-fallback")
    assert r.returncode == 1, (r.returncode, r.stderr)
    doc = json.loads(r.stdout)
    msg = doc["analyses"][0]["message"]
    assert what in msg and "gfosub_late" in msg and "routine.py" in msg, msg
    assert out.exists()


# ------------------------------------------------------------------------- batch
def _batch(*args):
    return _poise("batch", *args)


def test_batch_isolates_a_script_that_exits(tmp_path):
    bad_dir, good_dir = tmp_path / "bad", tmp_path / "good"
    _script(bad_dir / "routine.py", extra="\nraise SystemExit(0)\n")
    _script(good_dir / "routine.py")
    bad, good = _deck(bad_dir, name="bad.xml"), _deck(good_dir, name="good.xml")
    plain = DECKS / "pendulum_multiturn.xml"
    out = tmp_path / "out"
    r = _batch(bad, good, plain, "-j", "1", "--out-dir", out, "--allow-user-code", "--json")
    assert r.returncode == 3, r.stderr
    doc = json.loads(r.stdout)
    rows = {Path(x["deck"]).name: x for x in doc["rows"]}
    assert rows["bad.xml"]["status"] == "invalid_deck" and rows["bad.xml"]["exit_code"] == 3
    assert "SystemExit(0)" in rows["bad.xml"]["message"]
    assert str(bad) in rows["bad.xml"]["message"]
    assert rows["good.xml"]["status"] == "converged"
    assert rows["pendulum_multiturn.xml"]["status"] == "converged"
    np.testing.assert_allclose(_position(out / "good.h5"), [0, _y_expected(), 0], atol=1e-9)
    assert "poise batch: 3 decks" in r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert [Path(x["deck"]).name for x in summary["rows"]] == ["bad.xml", "good.xml",
                                                               "pendulum_multiturn.xml"]


def test_batch_without_the_flag_refuses_user_decks_only(tmp_path):
    marker = tmp_path / "RAN"
    _script(tmp_path / "routine.py", marker)
    deck = _deck(tmp_path)
    out = tmp_path / "out"
    r = _batch(deck, DECKS / "pendulum_multiturn.xml", "-j", "1", "--out-dir", out, "--json")
    assert r.returncode == 3, r.stderr
    rows = {Path(x["deck"]).name: x for x in json.loads(r.stdout)["rows"]}
    assert rows["pull.xml"]["status"] == "invalid_deck"
    assert "--allow-user-code" in rows["pull.xml"]["message"]
    assert rows["pendulum_multiturn.xml"]["status"] == "converged"
    assert not marker.exists()


def test_batch_results_go_stale_when_a_script_changes(tmp_path):
    script = _script(tmp_path / "routine.py")
    deck = _deck(tmp_path)
    out = tmp_path / "out"

    def run(*extra):
        r = _batch(deck, "-j", "1", "--out-dir", out, "--json", *extra)
        return r.returncode, json.loads(r.stdout)["rows"][0]

    code, row = run("--allow-user-code")
    assert code == 0 and row["skipped"] is False
    code, row = run("--allow-user-code")
    assert code == 0 and row["skipped"] is True
    # the routine now pulls twice as hard: the deck bytes are unchanged, its results are stale
    _script(script, k_scale=2.0)
    code, row = run("--allow-user-code")
    assert code == 0 and row["skipped"] is False
    np.testing.assert_allclose(_position(out / "pull.h5"), [0, _y_expected(k=2 * K), 0],
                               atol=1e-9)
    code, row = run("--allow-user-code")
    assert row["skipped"] is True
    # results made by running deck code are not "up to date" for a run that does not allow it
    code, row = run()
    assert code == 3 and row["skipped"] is False and row["status"] == "invalid_deck"


def test_inputs_fresh_rules(tmp_path):
    from poise.app.batch import inputs_fresh
    f = tmp_path / "s.py"
    f.write_text("x = 1\n")
    rec = json.dumps({str(f): hashlib.sha256(b"x = 1\n").hexdigest()})
    assert inputs_fresh({}, False) and inputs_fresh({"input_files": "{}"}, False)
    assert inputs_fresh({"input_files": rec}, True)
    assert not inputs_fresh({"input_files": rec}, False)
    f.write_text("x = 2\n")
    assert not inputs_fresh({"input_files": rec}, True)
    f.unlink()
    assert not inputs_fresh({"input_files": rec}, True)


# ------------------------------------------------------------------------- sweep (Dask)
def test_sweep_passes_the_opt_in_to_the_workers(tmp_path):
    from poise.app.sweep import run_sweep
    _script(tmp_path / "routine.py")
    deck = _deck(tmp_path)
    rows = run_sweep(str(deck), {"Body_Point[2].mass": [1.0, 3.0]}, out_dir=str(tmp_path / "s"),
                     workers=1, outputs=["bodies[2].position"], progress=False, rows=True).rows
    assert [r["status"] for r in rows] == ["invalid_deck", "invalid_deck"]
    assert all("allow_user_code=True" in r["message"] for r in rows)
    r = _poise("sweep", deck, "--set", "Body_Point[2].mass=1.0,3.0", "--workers", "1",
               "--out-dir", tmp_path / "s", "--output", "bodies[2].position",
               "--allow-user-code", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["counts"] == {"converged": 2}     # cases rerun: now allowed
    rows = json.loads((tmp_path / "s" / "index.json").read_text())["rows"]
    assert [r["status"] for r in rows] == ["converged", "converged"]
    for r, m in zip(rows, (1.0, 3.0)):
        assert r["bodies[2].position[1]"] == pytest.approx(_y_expected(m=m), abs=1e-9)


# ------------------------------------------------------------------------- reliability decks
@pytest.mark.skipif(not RELIABILITY.is_dir(), reason="reliability decks not on this machine")
@pytest.mark.parametrize("name", ["user_traversal_exec", "user_sysexit0_import",
                                  "user_sysexit3_import", "user_routine_k200_internal_error"])
def test_reliability_user_decks_refused_without_the_flag(tmp_path, name):
    deck = RELIABILITY / f"{name}.xml"
    for cmd in (["solve", deck, "-o", tmp_path / "o.h5", "--json"], ["check", deck]):
        r = _poise(*cmd)
        if cmd[0] == "check" and name != "user_traversal_exec":
            assert r.returncode == 0, r.stderr        # check lists the routine, runs nothing
        else:
            assert r.returncode == 3, (cmd, r.stderr)
            lines = [ln for ln in r.stderr.splitlines() if not ln.startswith("poise:")]
            assert lines and all(ln.startswith(f"{deck}:") for ln in lines), r.stderr
        assert "ARBITRARY CODE RAN" not in r.stderr + r.stdout
    assert not (tmp_path / "o.h5").exists()


@pytest.mark.skipif(not RELIABILITY.is_dir(), reason="reliability decks not on this machine")
@pytest.mark.parametrize("name,what", [("user_traversal_exec", "leaves the deck's directory"),
                                       ("user_sysexit0_import", "SystemExit(0)"),
                                       ("user_sysexit3_import", "SystemExit(3)")])
def test_reliability_user_decks_with_the_flag(tmp_path, name, what):
    deck = RELIABILITY / f"{name}.xml"
    r = _poise("solve", deck, "-o", tmp_path / "o.h5", "--allow-user-code")
    assert r.returncode == 3, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if not ln.startswith("poise:")]
    assert len(lines) == 1 and lines[0].startswith(f"{deck}:20:") and what in lines[0], r.stderr
    assert "ARBITRARY CODE RAN" not in r.stderr


# ------------------------------------------------------------------------- bench
def test_bench_needs_the_flag_too(tmp_path):
    marker = tmp_path / "RAN"
    _script(tmp_path / "routine.py", marker)
    deck = _deck(tmp_path)
    r = _poise("bench", deck, "--repeat", "1", "--tolerances", "1e-8")
    assert r.returncode == 3, r.stderr
    (line,) = _located(r.stderr, deck)                 # located in the user's deck
    assert "--allow-user-code" in line and not marker.exists()
    out = tmp_path / "b.jsonl"
    r = _poise("bench", deck, "--repeat", "1", "--tolerances", "1e-8", "--out", out,
               "--allow-user-code")
    assert r.returncode == 0, r.stderr
    (row,) = [json.loads(x) for x in out.read_text().splitlines()]
    assert row["status"] == "converged" and row["imbalance"] <= 1e-8
    assert marker.exists()
