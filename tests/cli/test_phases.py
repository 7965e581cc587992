"""Every run records the wall time of its solver phases (each results file shows what its
accuracy cost), and ``poise show`` prints them as parts of the solve time."""
import subprocess
import sys
from pathlib import Path

from poise.app.api import run_deck

from support.paths import ROOT


POISE = str(Path(sys.executable).parent / "poise")


def test_phase_times_are_parts_of_the_solve_time():
    res = run_deck(str(ROOT / "decks" / "fourbar_spring.xml"))
    t = res.timings
    phases = [t["solve_evaluate"], t["solve_assemble"], t["solve_factorise"]]
    assert all(v > 0.0 for v in phases)                    # Newton evaluated, assembled, solved
    assert sum(phases) <= t["solve"]
    assert res.counts["factorizations"] >= 1


def test_show_prints_phases_and_total(tmp_path):
    out = tmp_path / "r.h5"
    subprocess.run([POISE, "solve", str(ROOT / "decks" / "fourbar_spring.xml"), "-o", str(out),
                    "--quiet"], check=True)
    text = subprocess.run([POISE, "show", str(out)], check=True, capture_output=True,
                          text=True).stdout
    line = next(ln for ln in text.splitlines() if ln.startswith("timings [s]:"))
    assert "solve " in line and "(assemble " in line and "evaluate " in line
    assert "factorise " in line and "other " in line and "; total " in line
    parse = float(line.split("parse ")[1].split(",")[0])
    total = float(line.split("; total ")[1])
    assert 0.0 < parse < total
