"""``poise bench`` checks what it was asked before it solves anything: ``--out``/``--plot`` that
is the deck (also through a link) or cannot be written, a ``--plot`` format matplotlib cannot
write, tolerances that are not finite numbers >= 1e-100 are usage errors (exit 2) naming the
option, with the deck untouched and nothing left behind; ``--out`` is written atomically."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from poise_cli.main import cli

from support.paths import DECKS
from support.tmpfs import tmpfs

POISE = Path(sys.executable).with_name("poise")


@pytest.fixture
def deck(tmp_path):
    d = tmp_path / "d.xml"
    shutil.copy(DECKS / "pendulum_multiturn.xml", d)
    return d


def _bench(*args):
    return CliRunner().invoke(cli, ["bench", *map(str, args)])


def _refused_before_solving(r):
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.stderr
    assert "method" not in r.stdout and "converged" not in r.stdout     # no table row, no solve


@pytest.mark.parametrize("via_link", [False, True])
def test_out_that_is_the_deck_is_refused(deck, via_link):
    before = deck.read_bytes()
    target = deck
    if via_link:
        target = deck.with_name("link.xml")
        target.symlink_to(deck.name)
    r = _bench(deck, "--tolerances", "1e-4", "--repeat", 1, "--out", target)
    _refused_before_solving(r)
    assert "is the input deck" in r.stderr
    assert deck.read_bytes() == before
    r = _bench(deck, "--tolerances", "1e-4", "--repeat", 1, "--plot", target)
    _refused_before_solving(r)
    assert "is the input deck" in r.stderr and deck.read_bytes() == before


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "1e400", "1e-300", "1e-2,inf", "abc", ","])
def test_tolerances_outside_the_valid_range_name_the_option(deck, bad):
    r = _bench(deck, "--tolerances", bad)
    _refused_before_solving(r)
    assert "--tolerances" in r.stderr


def test_a_plot_format_matplotlib_cannot_write_is_refused_before_solving(deck, tmp_path):
    pytest.importorskip("matplotlib")
    r = _bench(deck, "--tolerances", "1e-4", "--plot", tmp_path / "wp.txt")
    _refused_before_solving(r)
    assert "--plot" in r.stderr and "'txt' is not supported" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.xml"]


def test_out_into_a_missing_directory_is_refused_before_solving(deck, tmp_path):
    r = _bench(deck, "--tolerances", "1e-4", "--out", tmp_path / "nodir" / "b.jsonl")
    _refused_before_solving(r)
    assert "cannot write" in r.stderr and "does not exist" in r.stderr


def test_out_is_written_atomically_as_json_lines(deck, tmp_path):
    out = tmp_path / "b.jsonl"
    r = _bench(deck, "--tolerances", "1e-3,1e-6", "--repeat", 1, "--out", out, "--quiet")
    assert r.exit_code == 0, r.output
    rows = [json.loads(ln) for ln in out.read_text().splitlines()]
    assert [row["tol"] for row in rows] == [1e-3, 1e-6]
    assert all(row["status"] == "converged" for row in rows)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.jsonl", "d.xml"]


def test_out_into_a_read_only_or_full_directory_is_exit_2_and_leaves_nothing(deck, tmp_path):
    with tmpfs(tmp_path / "ro", "ro,size=64k") as ro:
        r = _bench(deck, "--tolerances", "1e-4", "--repeat", 1, "--out", ro / "b.jsonl")
        _refused_before_solving(r)
        assert "cannot write" in r.stderr and "not writable" in r.stderr
        assert os.listdir(ro) == []
    with tmpfs(tmp_path / "full", "size=64k") as full:
        (full / "filler").write_bytes(b"\1" * (64 * 1024 - 100))      # no room for the rows
        p = subprocess.run([str(POISE), "bench", str(deck), "--tolerances", "1e-3,1e-6",
                            "--repeat", "1", "--out", str(full / "b.jsonl")],
                           capture_output=True, text=True, timeout=300)
        assert p.returncode == 2, p.stderr
        assert "cannot write" in p.stderr and "No space left on device" in p.stderr
        assert "Traceback" not in p.stderr
        assert os.listdir(full) == ["filler"]
