"""Run a :class:`poise.gen.deck.Deck` in-process or through the CLI (the ``runner`` fixture of
``tests/conftest.py``), and open its results file."""
import json
import subprocess
import sys
from pathlib import Path

import h5py

from poise.app.api import run_deck

POISE = str(Path(sys.executable).parent / "poise")


class Runner:
    def __init__(self, tmp_path):
        self.tmp = tmp_path

    def api(self, deck, name="deck.xml", **overrides):
        """Solve in-process; returns the first analysis (an AnalysisResult)."""
        path = deck.write(self.tmp / name)
        return run_deck(path, overrides=overrides).analyses[0]

    def cli(self, deck, name="deck.xml", *args):
        """``poise solve`` subprocess; returns (CompletedProcess, json summary, h5 path)."""
        path = deck.write(self.tmp / name)
        out = self.tmp / (Path(name).stem + ".h5")
        r = subprocess.run([POISE, "solve", path, "-o", str(out), "--json", *args],
                           capture_output=True, text=True, timeout=300)
        assert "Traceback" not in r.stderr, r.stderr
        summary = json.loads(r.stdout) if r.stdout.strip() else {}
        return r, summary, out


def h5(path):
    return h5py.File(path, "r")
