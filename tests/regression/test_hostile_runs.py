"""Runs a hostile user asks for end as documented (the 2026-11-26 reliability rows): a body of
1e-12 kg under MKEAM converges; a million output frames or the compliance matrix of a
2000-link chain is refused before solving with the memory it would need; a user routine
returning a malformed derivative fails the run naming the routine; an edited DeckSpec is
validated before it reaches numpy; a batch never writes over one of its input decks."""
from __future__ import annotations

import math
import runpy
import shutil

import pytest
from click.testing import CliRunner

import poise
from poise.app import budget
from poise.core.errors import DeckError
from poise.gen.chain import build_chain_deck
from poise.results.hdf5 import read_results
from poise_cli.main import cli

from support.paths import DATA, DECKS

RELIABILITY = DATA / "reliability" / "decks"


@pytest.fixture(autouse=True)
def _no_memory_override(monkeypatch):
    monkeypatch.delenv(budget.ENV, raising=False)


def _inv(*args):
    return CliRunner().invoke(cli, [*map(str, args)])


def test_mkeam_with_a_body_of_1e_12_kg_converges(tmp_path):
    """mkeam_tiny_mass.xml (was exit 4, SingularMatrix): the torsion spring (k = 20000 N mm/rad,
    free angle L0) against gravity on 1e-12 kg at 200 mm: k (theta - L0) = -m g l cos(theta)."""
    out = tmp_path / "o.h5"
    r = _inv("solve", RELIABILITY / "mkeam_tiny_mass.xml", "-o", out, "--method", "MKEAM")
    assert r.exit_code == 0, r.output
    k, L0, mgl = 20000.0, 19.84955592153876, 1e-12 * 9810.0 * 200.0
    theta = L0
    for _ in range(5):
        theta = L0 - mgl * math.cos(theta) / k
    a = read_results(str(out)).analyses[0]
    assert a.method == "MKEAM" and a.status == "converged"
    got = float(a.datasets["bodies/rotation_from_input"][-1][0][2])
    assert abs(got - theta) < 1e-7


def test_a_million_output_frames_are_refused_with_the_memory_they_need(tmp_path):
    r = _inv("solve", RELIABILITY / "qs_million_frames.xml", "-o", tmp_path / "o.h5")
    assert r.exit_code == 3, r.output
    line = r.stderr.splitlines()[0]
    assert "qs_million_frames.xml:17: <Simulate>: 1000001 output frames need about" in line
    assert " GB of memory" in line and "a larger print_interval" in line
    assert not (tmp_path / "o.h5").exists()


def test_the_memory_budget_follows_poise_max_memory(tmp_path, monkeypatch):
    deck = tmp_path / "q.xml"
    deck.write_text((RELIABILITY / "qs_million_frames.xml").read_text()
                    .replace('print_interval="1e-6"', 'print_interval="1e-3"'))
    monkeypatch.setenv(budget.ENV, "10M")                # 1001 frames x 25.5 kB = 25.5 MB
    r = _inv("solve", deck, "-o", tmp_path / "o.h5", "--method", "FIM_S")
    assert r.exit_code == 3 and "1001 output frames" in r.stderr and "POISE_MAX_MEMORY" in \
        r.stderr, r.output
    monkeypatch.setenv(budget.ENV, "1GiB")
    r = _inv("solve", deck, "-o", tmp_path / "o.h5", "--method", "FIM_S")
    assert r.exit_code == 0, r.output
    monkeypatch.setenv(budget.ENV, "lots")
    r = _inv("solve", deck, "-o", tmp_path / "o.h5")
    assert r.exit_code == 2 and "POISE_MAX_MEMORY='lots'" in r.stderr


def test_the_compliance_of_2000_links_is_refused_with_its_size(tmp_path, monkeypatch):
    # the budget is the memory available; capped here so the refusal does not depend on the
    # machine (the estimate, about 5.4 GB, is above the cap)
    monkeypatch.setenv("POISE_MAX_MEMORY", "4G")
    deck = tmp_path / "c.xml"
    deck.write_text(build_chain_deck(2000, "revolute"))
    r = _inv("solve", deck, "-o", tmp_path / "o.h5", "--compliance-markers", "all",
             "--method", "FIM_S")
    assert r.exit_code == 2, r.output
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("poise: error: --compliance-markers: the compliance matrix of 2000 "
                           "markers (12000 x 12000) needs about "), line
    assert "name fewer markers" in line
    assert not (tmp_path / "o.h5").exists()


def test_a_malformed_derivative_fails_the_run_naming_the_routine(tmp_path):
    for name in ("user_bad_derivative_key.xml", "bad_derivative_key.py"):
        shutil.copy(RELIABILITY / name, tmp_path / name)
    out = tmp_path / "o.h5"
    r = _inv("solve", tmp_path / "user_bad_derivative_key.xml", "-o", out, "--allow-user-code")
    assert r.exit_code == 1, r.output
    assert "user function bad_fn in" in r.stderr and "returned a derivative keyed 5; expected " \
        "(marker_id, 'P' | 'x' | 'y' | 'z')" in r.stderr
    assert "<Force_Scalar_TwoBody id=1>" in r.stderr and "Traceback" not in r.stderr
    assert read_results(str(out)).analyses[0].status == "failed"


def test_an_edited_deck_spec_is_validated_before_the_solve(monkeypatch):
    monkeypatch.chdir(DECKS.parent)        # the script loads decks/pendulum_multiturn.xml
    with pytest.raises(DeckError) as e:
        runpy.run_path(str(RELIABILITY / "api_spec_list_value.py"), run_name="__main__")
    msg = str(e.value)
    assert "pendulum_multiturn.xml:" in msg and "<Force_SpringDamper id=1>" in msg
    assert "attribute 'stiffness' is a list; expected a real number, got [1, 2]" in msg
    spec = poise.load_deck(str(DECKS / "pendulum_multiturn.xml"))     # a valid edit still runs
    spec.by_id("Force_SpringDamper")[1].attrs["stiffness"] = 25000
    assert poise.solve(spec).analyses[0].status == "converged"


def test_batch_never_writes_over_an_input_deck(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copy(DECKS / "pendulum_multiturn.xml", "p.xml")
    shutil.copy("p.xml", "p.h5")                           # a deck named like a results file
    before = (tmp_path / "p.h5").read_bytes()
    r = _inv("batch", "p.xml", "p.h5", "--out-dir", ".", "--json")
    assert r.exit_code == 2, r.output
    assert "is the input deck 'p.h5'" in r.stderr
    assert (tmp_path / "p.h5").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.h5", "p.xml"]
