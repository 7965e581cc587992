"""Absurd numbers end as located deck errors or usage errors, never as internal errors.

Non-finite or overflowing attributes (``inertia_yy="1e400"``, ``"inf"``) are one located problem
each (no cascaded inertia problem); tolerances below ``TOL_MIN`` are refused, naming the option
or the attribute.
"""
from __future__ import annotations

import re

import pytest
from click.testing import CliRunner

from poise.deck.parser import parse_deck_bytes
from poise.core.errors import DeckError, UsageError
from poise_cli.main import cli

from support.paths import ROOT


DECK = ROOT / "decks" / "double_pendulum.xml"


def _with(attr: str, value: str) -> bytes:
    text = DECK.read_text()
    new, n = re.subn(rf'{attr}="[^"]*"', f'{attr}="{value}"', text, count=1)
    assert n == 1
    return new.encode()


@pytest.mark.parametrize("value", ["1e400", "-1e400", "inf", "-inf", "nan", "Infinity"])
def test_non_finite_inertia_is_one_located_problem(value):
    with pytest.raises(DeckError) as e:
        parse_deck_bytes(_with("inertia_yy", value), "d.xml")
    probs = [str(p) for p in e.value.problems]
    assert len(probs) == 1, probs
    assert re.match(r"^d\.xml:\d+: <Body_Rigid id=2>: attribute 'inertia_yy' is not a finite "
                    r"number; expected a real number", probs[0]), probs


@pytest.mark.parametrize("attr", ["mass", "inertia_xy"])
def test_non_finite_mass_or_product_is_one_located_problem(attr):
    with pytest.raises(DeckError) as e:
        parse_deck_bytes(_with(attr, "1e999"), "d.xml")
    probs = [str(p) for p in e.value.problems]
    assert len(probs) == 1 and f"'{attr}' is not a finite number" in probs[0], probs


def test_huge_finite_inertia_is_a_located_problem_not_a_lapack_error():
    # eigenvalues 18.75, 11259.375 and 1e308: positive but 1e-306 apart, numerically singular
    with pytest.raises(DeckError) as e:
        parse_deck_bytes(_with("inertia_yy", "1.0e308"), "d.xml")
    (p,) = e.value.problems
    assert str(p).startswith("d.xml:") and "<Body_Rigid id=2>" in str(p)
    assert "numerically singular" in str(p)


def test_tolerance_floor_in_deck_is_a_located_problem():
    with pytest.raises(DeckError) as e:
        parse_deck_bytes(_with("max_imbalance", "1e-300"), "d.xml")
    (p,) = e.value.problems
    assert "<Param_Static>" in str(p) and "'max_imbalance' out of range" in str(p)
    assert ">= 1e-100" in str(p)


@pytest.mark.parametrize("opt", ["--max-imbalance", "--max-error"])
def test_absurd_tolerance_option_is_a_usage_error(tmp_path, opt):
    out = tmp_path / "o.h5"
    r = CliRunner().invoke(cli, ["solve", str(DECK), opt, "1e-300", "-o", str(out)])
    assert r.exit_code == 2 and opt in r.output
    assert not out.exists()


def test_absurd_tolerance_override_is_a_usage_error():
    from poise.app.api import run_deck
    with pytest.raises(UsageError, match="max_imbalance must be a finite number >= 1e-100"):
        run_deck(str(DECK), {"max_imbalance": 1e-300})


def test_huge_marker_coordinate_is_a_located_problem():
    # a marker at x = -3.3e299 made the multiplier solve singular (LinAlgError, exit 4)
    text = DECK.read_text()
    new, n = re.subn(r'(<Reference_Marker id="\d+"[^>]*?) pos_x="[^"]*"', r'\1 pos_x="-3.3e299"',
                     text, count=1)
    assert n == 1
    with pytest.raises(DeckError) as e:
        parse_deck_bytes(new.encode(), "d.xml")
    (p,) = e.value.problems
    assert "<Reference_Marker id=" in str(p) and "'pos_x' out of range" in str(p)
    assert "<= 1e+100" in str(p)


def test_problem_lines_escape_newlines_and_control_characters():
    from poise.core.errors import Problem, SourceLoc
    p = Problem(SourceLoc("d.xml", 7, "Body_Rigid", 2), "got 'a\nb\x00c'", "label")
    assert str(p) == "d.xml:7: <Body_Rigid id=2> label: got 'a\\nb\\x00c'"


def test_malformed_xml_message_is_one_located_line():
    # lxml's message for a NUL byte spans two lines ("...range\n, line 8, column 170")
    text = DECK.read_text().replace('id="2"', 'id="2\x00"', 1)
    with pytest.raises(DeckError) as e:
        parse_deck_bytes(text.encode(), "d.xml")
    (p,) = e.value.problems
    assert "\n" not in str(p) and re.match(r"^d\.xml:\d+: malformed XML: ", str(p))


@pytest.mark.parametrize("old,new,what", [
    ('print_interval="0.05"', 'print_interval="1e-320"', "inf output frames"),
    ('end_time="1.0"', 'end_time="1e300"', "output frames"),
    ('print_interval="0.05"', 'num_steps="1000000000000"', "num_steps asks for 1e+12"),
])
def test_absurd_frame_counts_are_located_problems(tmp_path, old, new, what):
    # (end - start) / print_interval overflowing int() was exit 4; 1e300 frames a MemoryError
    deck = tmp_path / "d.xml"
    text = (ROOT / "decks" / "qs_spring_ramp.xml").read_text()
    assert old in text
    deck.write_text(text.replace(old, new, 1))
    r = CliRunner().invoke(cli, ["solve", str(deck), "-o", str(tmp_path / "o.h5"), "-q"])
    assert r.exit_code == 3, r.output
    (line,) = [ln for ln in r.stderr.splitlines() if not ln.startswith("poise:")]
    assert line.startswith(f"{deck}:") and "<Simulate>" in line and what in line
    assert "at most 1000000" in line
