"""Start-up lightness, checked by what a fresh process imports (no timing).

Whole-process time of a small deck is the interpreter, numpy, h5py and lxml (the import floor in
docs/performance.md) plus what poise adds; these tests keep the additions from creeping back:
the small-deck path imports no scipy (dense systems are numpy-only), no matplotlib / dask /
SUNDIALS, and ``poise solve`` imports only its own command module. ``poise --help`` imports none
of the command modules and no numpy / h5py / lxml.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

import poise

from support.paths import ROOT


# never on the small FIM_S path (scipy: only sparse systems, > 120 unknowns dense, splines,
# MKEAM, FIM_D via scikit-sundae)
HEAVY = ("scipy", "matplotlib", "dask", "distributed", "sksundae", "numpy.polynomial",
         "numpy.ma",        # numpy.ma: pulled in by np.unique (~15 ms)
         "threadpoolctl")   # only when numpy was loaded before poise (poise.core.blas)
OTHER_COMMANDS = ("poise_cli.plot", "poise_cli.animate", "poise_cli.batch", "poise_cli.sweep",
                  "poise_cli.bench", "poise_cli.check", "poise_cli.show")


def _modules_after(code: str, cwd: Path) -> tuple[int, set[str]]:
    """Run ``code`` (which sets ``rc``) in a fresh interpreter; its return code and the names
    in ``sys.modules`` afterwards."""
    full = code + "\nimport json, sys\nprint(json.dumps([rc, sorted(sys.modules)]))\n"
    r = subprocess.run([sys.executable, "-c", full], capture_output=True, text=True, cwd=cwd,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    rc, mods = json.loads(r.stdout.strip().splitlines()[-1])
    return rc, set(mods)


def _loaded(mods: set[str], prefixes) -> list[str]:
    return sorted(m for m in mods if any(m == p or m.startswith(p + ".") for p in prefixes))


@pytest.mark.parametrize("deck", [
    "decks/bench/pendulum_multiturn.xml",   # the whole-process benchmark deck
    "decks/bench/fourbar_spring.xml",       # redundant constraints: minimum-norm reactions
    "decks/bench/slider_crank_qs.xml",      # quasi-static (FIM_S), expressions of TIME
    "decks/expr_nonlinear_spring.xml",      # expression forces, no splines
])
def test_small_deck_solve_stays_light(deck, tmp_path):
    out = tmp_path / "o.h5"
    code = ("from poise_cli.main import cli\n"
            f"rc = cli.main(['solve', {str(ROOT / deck)!r}, '-o', {str(out)!r}, '--quiet'], "
            "standalone_mode=False)")
    rc, mods = _modules_after(code, tmp_path)
    assert rc == 0 and out.exists()
    assert {"numpy", "h5py", "lxml.etree", "poise_cli.solve"} <= mods   # the check sees imports
    assert _loaded(mods, HEAVY) == []
    assert _loaded(mods, OTHER_COMMANDS) == []


def test_help_imports_no_command_and_no_numpy(tmp_path):
    rc, mods = _modules_after("from poise_cli.main import cli\n"
                              "rc = cli.main(['--help'], standalone_mode=False)", tmp_path)
    assert rc == 0
    assert _loaded(mods, ("numpy", "h5py", "lxml", "poise.app.api", "poise_cli.solve",
                          *OTHER_COMMANDS)) == []


def test_help_table_matches_commands():
    """``poise --help`` lists the commands from poise_cli.main.COMMANDS without importing them;
    the table must say what each command's own short help says."""
    import importlib

    from poise_cli.main import COMMANDS, cli
    for name, (module, text) in COMMANDS.items():
        cmd = getattr(importlib.import_module(module), name)
        assert cmd.get_short_help_str(limit=1000) == text, name
        assert cli.get_command(None, name) is cmd
    assert cli.get_command(None, "no-such-command") is None


def test_fast_exit_runs_exit_handlers_and_keeps_the_code(tmp_path):
    """The console-script path ends with os._exit after atexit handlers and flushing."""
    code = ("import atexit; atexit.register(lambda: print('handler ran'))\n"
            "from poise_cli.main import cli; cli(prog_name='poise')")
    r = subprocess.run([sys.executable, "-c", code, "--version"], capture_output=True, text=True,
                       cwd=tmp_path, timeout=60)
    assert r.returncode == 0
    assert r.stdout.split() == ["poise", poise.__version__, "handler", "ran"]
    r = subprocess.run([sys.executable, "-c", code, "solve", "missing.xml"], capture_output=True,
                       text=True, cwd=tmp_path, timeout=60)
    assert r.returncode == 2 and "does not exist" in r.stderr and "handler ran" in r.stdout
