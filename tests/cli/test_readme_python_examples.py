"""The README's examples run as written: the Quick start commands (through ``python -m poise``)
and then every Python block, in order, in one fresh interpreter in a scratch directory holding
the example decks (the Dask sweep included: the blocks guard it with ``__main__``)."""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys

from support.paths import ROOT


def _blocks(lang: str) -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    return re.findall(rf"^```{lang}\n(.*?)^```", text, flags=re.S | re.M)


def _quick_start() -> list[list[str]]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Quick start", 1)[1]
    block = re.search(r"^```sh\n(.*?)^```", section, flags=re.S | re.M).group(1)
    cmds = []
    for line in block.splitlines():
        words = shlex.split(line.split("#", 1)[0])
        if words and words[0].endswith("/poise"):
            cmds.append([sys.executable, "-m", "poise", *words[1:]])
    return cmds


def test_readme_examples_run(tmp_path):
    os.symlink(ROOT / "decks", tmp_path / "decks")
    env = {**os.environ, "MPLBACKEND": "Agg", "POISE_QUIET": "1"}
    cmds = _quick_start()
    assert any("slider.h5" in c for c in cmds)
    for cmd in cmds:
        p = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                           timeout=300)
        assert p.returncode == 0, (cmd, p.stderr)
    code = "\n\n".join(_blocks("python"))
    assert "open_datatree" in code and 'sel(label="Wrist pin")' in code
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "<RunResult 'decks/pendulum_multiturn.xml': converged" in p.stdout
    assert (tmp_path / "wrist.png").stat().st_size > 1000
    assert (tmp_path / "sw" / "index.csv").exists()
