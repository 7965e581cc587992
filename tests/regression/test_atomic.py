"""Output files: the target is checked (regular file, never the deck) and written atomically."""
from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from click.testing import CliRunner

from poise.core.atomic import atomic_output, output_target
from poise.core.errors import UsageError
from poise_cli.main import cli

from support.paths import DECKS


DECK = DECKS / "pendulum_multiturn.xml"


def test_refuses_devices_directories_and_fifos(tmp_path):
    for p in ("/dev/null", str(tmp_path)):
        with pytest.raises(UsageError, match="not a regular file"):
            output_target(p)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(UsageError, match="not a regular file"):
        output_target(fifo)
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_refuses_the_deck_also_through_a_link(tmp_path):
    deck = tmp_path / "d.xml"
    deck.write_bytes(DECK.read_bytes())
    link = tmp_path / "out.h5"
    link.symlink_to(deck)
    for p in (deck, link, tmp_path / "." / "d.xml"):
        with pytest.raises(UsageError, match="is the input deck"):
            output_target(p, (str(deck),))
    assert output_target(tmp_path / "new.h5", (str(deck),)) == str((tmp_path / "new.h5").resolve())


def test_follows_links_and_cleans_up_on_error(tmp_path):
    target = tmp_path / "real" / "r.png"
    target.parent.mkdir()
    target.write_bytes(b"old")
    link = tmp_path / "r.png"
    link.symlink_to(target)
    with atomic_output(link, keep_suffix=True) as tmp:
        assert tmp.endswith(".png") and Path(tmp).parent == target.parent
        Path(tmp).write_bytes(b"new")
    assert link.is_symlink() and target.read_bytes() == b"new"
    with pytest.raises(RuntimeError):
        with atomic_output(target) as tmp:
            Path(tmp).write_bytes(b"partial")
            raise RuntimeError("boom")
    assert target.read_bytes() == b"new"
    assert sorted(p.name for p in target.parent.iterdir()) == ["r.png"]


@pytest.mark.parametrize("out", ["deck", "/dev/null", "dir"])
def test_solve_refuses_before_solving(tmp_path, out):
    deck = tmp_path / "d.xml"
    deck.write_bytes(DECK.read_bytes())
    target = {"deck": str(deck), "/dev/null": "/dev/null", "dir": str(tmp_path)}[out]
    r = CliRunner().invoke(cli, ["solve", str(deck), "-o", target, "--json"])
    assert r.exit_code == 2, r.output
    if out != "dir":              # a directory is refused by click's option parsing (no JSON)
        assert '"status": "usage_error"' in r.stdout
    assert "analysis 0" not in r.output                      # refused before the solve
    assert deck.read_bytes() == DECK.read_bytes()
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_plot_is_written_atomically_and_never_over_its_input(tmp_path):
    h5 = tmp_path / "r.h5"
    assert CliRunner().invoke(cli, ["solve", str(DECK), "-o", str(h5), "-q"]).exit_code == 0
    png = tmp_path / "p.png"
    r = CliRunner().invoke(cli, ["plot", str(h5), "-o", str(png)])
    assert r.exit_code == 0, r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png", "r.h5"]   # no temp left
    before = h5.read_bytes()
    r = CliRunner().invoke(cli, ["plot", str(h5), "-o", str(h5)])
    assert r.exit_code != 0 and h5.read_bytes() == before
