"""The README's Python examples run as written: after the Quick start commands (through
``python -m poise``: they write the files the examples read), every Python block, in order, in
one fresh interpreter in a scratch directory holding the example decks (the Dask sweep
included: the blocks guard it with ``__main__``). Same block parser as the command-line
examples' test (support.readme)."""
from __future__ import annotations

import os
import shlex
import subprocess
import sys

import pytest

from support.paths import ROOT
from support.readme import code_blocks


def _quick_start() -> list[list[str]]:
    """The ``poise`` commands of the Quick start block (the first ``sh`` block solving a
    deck), through ``python -m poise``."""
    block = next(text for _, text in code_blocks("sh") if "poise show" in text)
    cmds = []
    for line in block.splitlines():
        words = shlex.split(line.split("#", 1)[0])
        if words and words[0].endswith("/poise"):
            cmds.append([sys.executable, "-m", "poise", *words[1:]])
    return cmds


@pytest.mark.parametrize("dask", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_readme_python_examples_run(tmp_path, dask):
    """``dask=False``: every block but the one starting a Dask cluster (tens of seconds: that
    run is a slow test, as the command-line sweep examples are)."""
    os.symlink(ROOT / "decks", tmp_path / "decks")
    env = {**os.environ, "MPLBACKEND": "Agg", "POISE_QUIET": "1"}
    cmds = _quick_start()
    assert any("slider.h5" in c for c in cmds)
    for cmd in cmds:
        p = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                           timeout=300)
        assert p.returncode == 0, (cmd, p.stderr)
    blocks = [text for _, text in code_blocks("python") if dask or "poise.sweep(" not in text]
    code = "\n\n".join(blocks)
    assert "open_datatree" in code and 'sel(label="Wrist pin")' in code
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "<RunResult 'decks/pendulum_multiturn.xml': converged" in p.stdout
    assert (tmp_path / "wrist.png").stat().st_size > 1000
    assert (tmp_path / "sw" / "index.csv").exists() == dask
