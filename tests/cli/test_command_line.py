"""One command line: the same option names and flags on every command, counted nouns, the frame
count of ``poise check``, ``poise bench --json``, shortened texts marked as shortened."""
from __future__ import annotations

import importlib
import json
import subprocess
import sys

import click
import pytest
from click.testing import CliRunner

from poise.app.runner import run
from poise.core.wording import ELLIPSIS, plural, shorten
from poise_cli.main import COMMANDS, cli

from support.paths import DECKS, ROOT


def _command(name: str) -> click.Command:
    return getattr(importlib.import_module(COMMANDS[name][0]), name)


def _option(cmd: click.Command, name: str) -> click.Option | None:
    return next((p for p in cmd.params if isinstance(p, click.Option) and name in p.opts), None)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_has_debug(name):
    opt = _option(_command(name), "--debug")
    assert opt is not None and opt.is_flag, name


def test_batch_and_sweep_name_their_workers_alike():
    a, b = _option(_command("batch"), "--workers"), _option(_command("sweep"), "--workers")
    assert a is not None and b is not None
    for opt in (a, b):
        assert opt.opts == ["-j", "--workers"] and opt.default == 0
        assert opt.type.min == 0               # 0 = number of CPUs on both
    assert a.help == b.help


def _strict(text: str):
    """json.loads that refuses NaN / Infinity (strict JSON)."""
    def no(c):
        raise ValueError(f"non-strict JSON constant {c}")
    return json.loads(text, parse_constant=no)


def test_batch_jobs_alias_and_sweep_workers_reach_the_engine(tmp_path, monkeypatch):
    import poise.app.batch as batch_mod
    import poise.app.sweep as sweep_mod
    seen = {}

    def fake_batch(decks, out_dir, jobs=0, **kw):
        (tmp_path / "b").mkdir(exist_ok=True)
        seen.setdefault("batch", []).append(jobs)
        return []

    def fake_sweep(deck, sets, workers=None, **kw):
        seen.setdefault("sweep", []).append(workers)
        return sweep_mod.SweepOutcome("sweep.h5", "index.csv", 2, {"converged": 2}, 0, 0)

    monkeypatch.setattr(batch_mod, "run_batch", fake_batch)
    monkeypatch.setattr(sweep_mod, "run_sweep", fake_sweep)
    deck = str(DECKS / "pendulum_multiturn.xml")
    runner = CliRunner()
    for args in (["-j", "3"], ["--workers", "2"], ["--jobs", "5"], []):
        r = runner.invoke(cli, ["batch", deck, "--out-dir", str(tmp_path / "b"), "-q", *args])
        assert r.exit_code == 0, r.output
    for args in (["-j", "3"], ["--workers", "2"], []):
        r = runner.invoke(cli, ["sweep", deck, "--set", "Force_SpringDamper[1].stiffness=1,2",
                                "--out-dir", str(tmp_path / "s"), "-q", *args])
        assert r.exit_code == 0, r.output
    assert seen == {"batch": [3, 2, 5, 0], "sweep": [3, 2, None]}   # None: number of CPUs


MULTI = '''<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Force_Gravity grav_x="0" grav_y="-9.81" grav_z="0"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="10"/>
    <Reference_Marker id="10" body_id="1"/>
    <Reference_Marker id="11" body_id="1" pos_y="-1" a00="0" a10="0" a20="1" a01="1" a11="0" a21="0" a02="0" a12="1" a22="0"/>
    <Body_Rigid id="2" cg_id="20" mass="2.0" inertia_xx="1." inertia_yy="1." inertia_zz="1."/>
    <Reference_Marker id="20" body_id="2" pos_y="-1"/>
    <Reference_Marker id="21" body_id="2" pos_y="-1" a00="0" a10="0" a20="1" a01="1" a11="0" a21="0" a02="0" a12="1" a22="0"/>
    <Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="21" j_marker_id="11"/>
    <Force_SpringDamper id="1" type="TRANSLATIONAL" i_marker_id="20" j_marker_id="10" stiffness="200." damping="0." length="1.0"/>
    <Force_Vector_OneBody id="2" type="FORCEONLY" marker_id="20" fx_expression="0" fy_expression="-TIME" fz_expression="0"/>
  </Model>
  <Command>
    <Simulate analysis_type="Static"/>
    <Simulate analysis_type="Static" end_time="1" print_interval="0.25"/>
    <Simulate analysis_type="Quasistatic" duration="0.5" num_steps="2"/>
    <Simulate analysis_type="Static"/>
    <Simulate analysis_type="Static" end_time="1.7" print_interval="0.1"/>
  </Command>
</MotionSolve>
'''


def test_check_prints_the_frame_count_the_solve_writes(tmp_path):
    deck = tmp_path / "multi.xml"
    deck.write_text(MULTI)
    solved = [a.n_frames for a in run(str(deck)).analyses]
    assert solved == [1, 5, 3, 1, 3]        # 1.5 -> 1.7 by 0.1: 1.5, 1.6, 1.7
    r = CliRunner().invoke(cli, ["check", str(deck), "--json"])
    assert r.exit_code == 0, r.output
    assert [a["n_frames"] for a in _strict(r.output)["analyses"]] == solved
    text = CliRunner().invoke(cli, ["check", str(deck)]).output
    lines = [ln.strip() for ln in text.splitlines() if ln.startswith("  ") and ": " in ln
             and ln.strip()[0].isdigit()]
    assert lines == ["0: static FIM_S, 1 frame", "1: quasistatic FIM_S, 5 frames",
                     "2: quasistatic FIM_S, 3 frames", "3: static FIM_S, 1 frame",
                     "4: quasistatic FIM_S, 3 frames"]
    assert "(frame(s)" not in text and "frame(s)" not in text


def test_plural_and_shorten():
    assert [plural(n, "iteration") for n in (0, 1, 2)] == ["0 iterations", "1 iteration",
                                                          "2 iterations"]
    assert plural(1, "analysis", "analyses") == "1 analysis"
    assert plural(3, "analysis", "analyses") == "3 analyses"
    assert shorten("a  b\nc", 10) == "a b c"
    s = shorten("x" * 50, 20)
    assert len(s) == 20 and s.endswith(ELLIPSIS)


def test_batch_line_says_one_iteration_and_table_marks_shortened_messages(capsys):
    from poise_cli.batch import _line, _print_table
    row = dict(deck="d.xml", status="failed", iterations=1, time=0.01, imbalance=1.0,
               skipped=False, message="m" * 300, stability_class=None)
    assert ", 1 iteration," in _line(row)
    _print_table([row])
    out = capsys.readouterr().out
    cell = out.splitlines()[1].split()[-1]
    assert cell.endswith(ELLIPSIS) and len(cell) == 100


def test_show_marks_the_shortened_hash(tmp_path):
    out = tmp_path / "p.h5"
    r = CliRunner().invoke(cli, ["solve", str(DECKS / "pendulum_multiturn.xml"), "-o", str(out),
                                 "--method", "FIM_S", "-q"])
    assert r.exit_code == 0, r.output
    line = next(ln for ln in CliRunner().invoke(cli, ["show", str(out)]).output.splitlines()
                if ln.startswith("deck:"))
    assert line.endswith(f"{ELLIPSIS})")


def test_bench_json_is_strict_and_complete(tmp_path):
    deck = DECKS / "pendulum_multiturn.xml"
    r = subprocess.run([sys.executable, "-m", "poise_cli", "bench", str(deck), "--json",
                        "--methods", "FIM_S,MKEAM", "--tolerances", "1e-4,1e-8", "--repeat", "1",
                        "--out", str(tmp_path / "rows.jsonl")],
                       capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    doc = _strict(r.stdout)                   # stdout is the JSON object and nothing else
    assert doc["command"] == "bench" and doc["exit_code"] == 0 and doc["status"] == "completed"
    assert doc["methods"] == ["FIM_S", "MKEAM"] and doc["tolerances"] == [1e-4, 1e-8]
    assert doc["reference"] == {"method": "FIM_S", "tol": 1e-12, "status": "converged"}
    assert doc["length_unit"] == "mm" and doc["length_scale"] > 0
    assert [(x["method"], x["tol"]) for x in doc["rows"]] == [
        ("FIM_S", 1e-4), ("FIM_S", 1e-8), ("MKEAM", 1e-4), ("MKEAM", 1e-8)]
    file_rows = [json.loads(x) for x in (tmp_path / "rows.jsonl").read_text().splitlines()]
    assert [x["error_abs"] for x in file_rows] == pytest.approx(
        [x["error_abs"] for x in doc["rows"]])
    for x in doc["rows"]:
        assert x["status"] == "converged" and x["error_abs"] < 1e-2 * doc["length_scale"]
    assert "method" in r.stderr and "rung" in r.stderr     # the table went to stderr


def test_bench_json_on_an_invalid_deck(tmp_path):
    r = subprocess.run([sys.executable, "-m", "poise_cli", "bench",
                        str(DECKS / "invalid" / "bad_method.xml"), "--json", "--repeat", "1"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 3
    doc = _strict(r.stdout)
    assert doc["status"] == "invalid_deck" and doc["exit_code"] == 3 and doc["problems"]
    assert "Traceback" not in r.stderr


def test_no_counted_noun_with_parenthesised_plural():
    """``frame(s)`` style plurals are gone from what the commands print."""
    import re
    pat = re.compile(r"[a-z]\(s\)")
    for d in ("cli/poise_cli", "src/poise"):
        for p in (ROOT / d).rglob("*.py"):
            for k, line in enumerate(p.read_text().splitlines(), 1):
                if ('f"' in line or "f'" in line) and pat.search(line):
                    pytest.fail(f"{p.relative_to(ROOT)}:{k}: {line.strip()}")


def test_one_declaration_of_the_methods_and_settings():
    """The equilibrium methods are the deck schema's ``Param_Static method`` choices: the CLI
    offers them (it does not import the schema at start-up, so it lists them) and the driver's
    one ``METHODS`` table dispatches each for both analysis kinds; the settings' defaults and
    bounds are the schema row's."""
    from poise_cli.options import METHODS as CLI_METHODS
    from poise.solvers.driver import METHODS
    from poise.solvers.settings import PARAM_STATIC, StaticSettings
    choices = PARAM_STATIC["method"].choices
    assert sorted(CLI_METHODS) == sorted(choices)
    assert set(METHODS) == {(k, m) for k in ("static", "quasistatic") for m in choices}
    s = StaticSettings()
    for name, a in PARAM_STATIC.items():
        if a.default is not None and hasattr(s, name):
            assert getattr(s, name) == a.default, name
    with pytest.raises(ValueError, match=r"> 0"):
        StaticSettings(compliance_delta=0.0)
