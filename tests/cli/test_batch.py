"""poise batch: parallel local processes, summary rows, exit codes, up-to-date skipping."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

from click.testing import CliRunner

from poise.app.batch import BATCH_KEYS, output_paths, worst_exit_code
from poise_cli.main import cli

from support.paths import DECKS


GOOD = DECKS / "pendulum_multiturn.xml"
GOOD2 = DECKS / "double_pendulum.xml"
FAILING = DECKS / "expr_eval_error.xml"          # evaluation error: analysis fails, exit 1
INVALID = DECKS / "invalid" / "bad_method.xml"   # exit 3


def _batch(*args):
    r = CliRunner().invoke(cli, ["batch", *map(str, args)])
    return r


def test_worst_exit_code_and_stems(tmp_path):
    assert worst_exit_code([0, 1, 0]) == 1
    assert worst_exit_code([1, 3, 0]) == 3
    assert worst_exit_code([3, 4]) == 4
    assert worst_exit_code([]) == 0
    outs = output_paths(["a/x.xml", "b/x.xml", "c/y.xml", "d/X.xml"], "o")
    assert [Path(p).name for p in outs] == ["x.h5", "x-2.h5", "y.h5", "X-3.h5"]


def test_batch_mixture_rows_exit_codes_and_skip(tmp_path):
    other = tmp_path / "sub"
    other.mkdir()
    shutil.copy(GOOD2, other / GOOD.name)        # same stem as GOOD, different deck
    out = tmp_path / "out"
    r = _batch(GOOD, other / GOOD.name, FAILING, INVALID, "-j", "2", "--out-dir", out, "--json")
    assert r.exit_code == 3, r.output
    js = json.loads(r.stdout)
    assert js["batch_version"] == 1 and js["exit_code"] == 3
    rows = js["rows"]
    assert [row["deck"] for row in rows] == [str(GOOD), str(other / GOOD.name), str(FAILING),
                                             str(INVALID)]
    for row in rows:
        assert set(BATCH_KEYS) <= set(row)
    good, good2, failing, invalid = rows
    assert good["status"] == "converged" and good["exit_code"] == 0 and good["iterations"] > 0
    assert Path(good["output"]).name == "pendulum_multiturn.h5"
    assert Path(good2["output"]).name == "pendulum_multiturn-2.h5"
    assert failing["status"] == "failed" and failing["exit_code"] == 1
    assert Path(failing["output"]).is_file() and failing["message"]
    assert invalid["status"] == "invalid_deck" and invalid["exit_code"] == 3
    assert invalid["output"] is None
    assert "bad_method.xml:" in invalid["message"]      # located message
    assert not any(row["skipped"] for row in rows)
    with open(out / "summary.csv") as f:
        table = list(csv.DictReader(f))
    assert [t["status"] for t in table] == ["converged", "converged", "failed", "invalid_deck"]
    assert list(table[0]) == list(BATCH_KEYS)
    assert json.loads((out / "summary.json").read_text())["rows"][0]["deck"] == str(GOOD)

    # re-run: results up to date -> skipped (the invalid deck is checked again)
    mtime = (out / "pendulum_multiturn.h5").stat().st_mtime_ns
    r = _batch(GOOD, FAILING, INVALID, "--out-dir", out, "--json")
    assert r.exit_code == 3
    rows = json.loads(r.stdout)["rows"]
    assert [row["skipped"] for row in rows] == [True, True, False]
    assert rows[0]["message"] == "skipped (up to date)" and rows[0]["status"] == "converged"
    assert rows[1]["exit_code"] == 1
    assert (out / "pendulum_multiturn.h5").stat().st_mtime_ns == mtime

    # different settings -> solved again; --force -> solved again
    r = _batch(GOOD, "--out-dir", out, "--json", "--method", "FIM_S", "--max-num-iter", "50")
    assert r.exit_code == 0 and json.loads(r.stdout)["rows"][0]["skipped"] is False
    r = _batch(GOOD, "--out-dir", out, "--json", "--method", "FIM_S", "--max-num-iter", "50")
    assert json.loads(r.stdout)["rows"][0]["skipped"] is True
    r = _batch(GOOD, "--out-dir", out, "--json", "--method", "FIM_S", "--max-num-iter", "50",
               "--force")
    assert json.loads(r.stdout)["rows"][0]["skipped"] is False

    # a changed deck is solved again
    deck = tmp_path / "p.xml"
    shutil.copy(GOOD, deck)
    assert _batch(deck, "--out-dir", out, "--json").exit_code == 0
    deck.write_text(deck.read_text().replace('stiffness="20000.0"', 'stiffness="25000.0"'))
    r = _batch(deck, "--out-dir", out, "--json")
    assert json.loads(r.stdout)["rows"][0]["skipped"] is False


def test_batch_human_table(tmp_path):
    r = _batch(GOOD, "--out-dir", tmp_path, "-j", "1")
    assert r.exit_code == 0
    assert r.stdout.splitlines()[0].split()[:3] == ["deck", "status", "iterations"]
    assert "\x1b[" not in r.output            # no colours when not a terminal


def test_a_deck_that_kills_its_worker_takes_only_itself_down(tmp_path):
    """A deck whose user routine SIGKILLs its process (as the OOM killer would): the other decks
    still get their results files, the batch exits 4 with the summary written, and the dead
    deck's row says what happened."""
    import signal
    src = (DECKS / "elem_user_forces.xml").read_text()
    (tmp_path / "routines.py").write_text(
        (DECKS / "elem_user_routines.py").read_text()
        + "\n\ndef sfosub_die(id, time, par, q):\n    import os\n"
        + f"    os.kill(os.getpid(), {int(signal.SIGKILL)})\n")
    killer = tmp_path / "killer.xml"
    killer.write_text(src.replace('usrsub_fnc_name="sfosub_spring"', 'usrsub_fnc_name="sfosub_die"')
                      .replace("elem_user_routines.py", "routines.py"))
    good = [tmp_path / f"good{k}.xml" for k in range(9)]
    for g in good:
        shutil.copy(GOOD, g)
    out = tmp_path / "out"
    for jobs in ("1", "2"):
        r = _batch(good[0], killer, *good[1:], "-j", jobs, "--out-dir", out, "--force",
                   "--json", "--allow-user-code")   # more decks than the suspects re-solved
        assert r.exit_code == 4, r.output
        doc = json.loads(r.stdout)
        rows = {Path(x["deck"]).name: x for x in doc["rows"]}
        assert rows["killer.xml"]["status"] == "internal_error"
        assert "worker process solving this deck died" in rows["killer.xml"]["message"]
        assert rows["killer.xml"]["output"] is None and not (out / "killer.h5").exists()
        for g in good:
            row = rows[g.name]
            assert row["status"] == "converged" and row["exit_code"] == 0, row
            assert Path(row["output"]).exists()
        assert (out / "summary.json").exists() and (out / "summary.csv").exists()
