"""The README's command-line examples run as written.

Every fenced ```sh block of README.md runs in bash (``set -eo pipefail``) in a fresh directory
that has what a clone has where the examples look: ``decks/`` and ``.venv/bin/poise`` (here a
shim to this interpreter's ``python -m poise_cli``, also first on PATH as ``poise``). ``make``
lines are checked with ``make -n`` in the repository (the targets exist and would run; running
them here would recurse into the suite). A block whose first line is ``# not run`` is skipped
(an example that needs what a test cannot have, e.g. a Dask scheduler at some address). What
the examples write is then checked. The README's Python blocks are run by their own test (same
block parser: support.readme).
"""
from __future__ import annotations

import csv
import os
import stat
import subprocess
import sys

import pytest

from support.paths import ROOT
from support.readme import code_blocks

BLOCKS = code_blocks("sh")
#: commands whose examples take tens of seconds (a Dask cluster, a tolerance ladder): slow tests
LONG = ("sweep", "batch", "bench")


def _sandbox(tmp_path):
    (tmp_path / "decks").symlink_to(ROOT / "decks", target_is_directory=True)
    bindir = tmp_path / ".venv" / "bin"
    bindir.mkdir(parents=True)
    shim = bindir / "poise"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m poise_cli "$@"\n')
    shim.chmod(shim.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}",
               CI="1", NO_COLOR="1")
    env.pop("POISE_QUIET", None)
    return env


def _split(text: str) -> tuple[list[str], str]:
    """``make`` lines (targets to dry-run) and the rest of the block (a shell script)."""
    make, rest = [], []
    for line in text.splitlines():
        if line.strip().startswith("make "):
            make.append(line.split("#", 1)[0].split()[1])
        else:
            rest.append(line)
    return make, "\n".join(rest) + "\n"


def test_the_readme_has_command_line_examples():
    text = "".join(t for _, t in BLOCKS)
    for what in ("poise check", "poise solve", "poise show", "poise bench", "poise sweep"):
        assert what in text, what


@pytest.mark.parametrize("line,block", [
    pytest.param(line, block, id=f"README.md:{line}",
                 marks=[pytest.mark.slow] if any(f"poise {c}" in block for c in LONG) else [])
    for line, block in BLOCKS])
def test_readme_block_runs_as_written(line, block, tmp_path):
    if block.lstrip().startswith("# not run"):      # e.g. needs a scheduler at an address
        pytest.skip(f"README.md:{line}: marked '# not run'")
    env = _sandbox(tmp_path)
    targets, script = _split(block)
    for target in targets:
        r = subprocess.run(["make", "-n", "-C", str(ROOT), target], capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 0, f"README.md:{line}: make {target}: {r.stderr}"
    if not script.strip():
        return
    r = subprocess.run(["bash", "-c", "set -eo pipefail\n" + script], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, f"README.md:{line}: exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    assert "Traceback" not in r.stderr, f"README.md:{line}: {r.stderr}"
    _check_outputs(tmp_path, block, r.stdout)


def _check_outputs(d, block: str, stdout: str) -> None:
    """What the README's examples promise, read back from what they wrote: every results file
    converged, every picture a real image, every sweep index complete and converged."""
    import poise
    h5 = sorted(d.glob("*.h5"))
    if "poise solve" in block:
        assert h5, "poise solve wrote no results file"
    for f in h5:
        res = poise.read_results(str(f))
        assert res.status == "converged", f.name
        assert all(a.status == "converged" for a in res.analyses)
    if "status:" in stdout:                           # poise show printed a file's status
        assert "status: converged" in stdout
    pngs = sorted(d.glob("*.png"))
    if "--plot" in block or "poise plot" in block:
        assert pngs, "no picture written"
    import matplotlib.image as mpimg
    for f in pngs:
        img = mpimg.imread(str(f))
        assert img.ndim == 3 and img.shape[0] >= 300 and img.shape[1] >= 400, f.name
    indexes = sorted(d.glob("*/index.csv"))
    if "poise sweep" in block:
        assert indexes, "poise sweep wrote no index"
    for f in indexes:
        with open(f, newline="") as fh:
            rows = list(csv.DictReader(fh))
        assert rows and all(r["status"] == "converged" for r in rows), f
        if "stiffness=10000:30000:1000" in block and "FIM_S,MKEAM" in block:
            ks = sorted({float(r["Force_SpringDamper[1].stiffness"]) for r in rows})
            assert ks == [10000.0 + 1000.0 * i for i in range(21)] and len(rows) == 42
