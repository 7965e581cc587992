"""``poise check`` is linear in the deck size: a 20 000-link chain deck (26 MB) is checked within a
generous subprocess timeout (it took minutes while each constraint row scanned the whole model for
its element), and the structure it reports is the chain's closed form."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from poise.gen.chain import build_chain_deck

POISE = Path(sys.executable).with_name("poise")


def test_check_large_chain_is_linear(tmp_path):
    n = 20_000
    deck = tmp_path / "chain.xml"
    deck.write_text(build_chain_deck(n, "revolute"))
    p = subprocess.run([str(POISE), "check", str(deck), "--json"], capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 0, p.stderr[-2000:]
    rep = json.loads(p.stdout)
    # N links (6 coordinates each), N+1 revolutes (5 equations each), a planar closed loop:
    # 3 out-of-plane equations redundant, N-2 degrees of freedom.
    assert len(rep["bodies"]) == n
    assert len(rep["constraints"]) == n + 1
    assert all(c["n_equations"] == 5 and c["tag"] == "Constraint_Joint"
               for c in rep["constraints"])
    assert [c["id"] for c in rep["constraints"]] == list(range(1, n + 2))
    assert rep["n_coordinates"] == 6 * n
    assert rep["n_equations"] == 5 * (n + 1)
    assert rep["n_redundant"] == 3
    assert rep["dof"] == n - 2
