"""Fuzzing of the deck reader: random mutations of the valid decks in decks/*.xml.

In-process (fast): ``parse_deck_bytes`` + ``compile_model`` must either succeed or raise a
``DeckError`` (located problems, exit 3); any other exception is a bug. A smaller end-to-end set
runs the real CLI and checks the exit code is 0, 1 or 3 and that no traceback is printed.

Deterministic (``derandomize=True`` / fixed seeds). Longer runs::

    POISE_FUZZ_EXAMPLES=200000 POISE_FUZZ_CLI=500 .venv/bin/pytest tests/test_fuzz_deck.py
"""
import copy
import os
import random
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from lxml import etree

from poise.deck.parser import parse_deck_bytes
from poise.errors import DeckError
from poise.model.compile import compile_model

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("bushing_block chain_10 chain_10_spherical contact_ball_between_spheres contact_box_plane "
         "contact_sphere_plane double_pendulum expr_eval_error expr_follower_load "
         "expr_nonlinear_spring expr_spline_spring fourbar_spring mkeam_inverted_pendulum "
         "mkeam_pendulum_multiturn pendulum_multiturn qs_pendulum_ramp qs_slider_crank_11b "
         "qs_slider_crank_rev qs_spring_ramp slider_crank_load").split()
DECKS = [ROOT / "decks" / f"{n}.xml" for n in NAMES]
SOURCES = [p.read_bytes() for p in DECKS]
N_EXAMPLES = int(os.environ.get("POISE_FUZZ_EXAMPLES", "2000"))
N_CLI = int(os.environ.get("POISE_FUZZ_CLI", "16"))
POISE = str(Path(sys.executable).parent / "poise")

VALUES = ["", "abc", "1e308", "-1e308", "1e309", "inf", "-inf", "nan", "NaN", "+INF", "1e-320",
          "0", "-0", "-1", "-1e-300", "TRUE", "FALSE", "1,5", "0x10", "1.5.2", "9" * 400,
          "☃ünïcødé", "\u202e", "𝔘", "DX(1,2)", "SQRT(-1)", "1/0", "((((", "2147483648",
          "-2147483649", "99999999999999999999999", " 1 ", "1 2 3", "&amp;", "1e", "e5"]


def _elements(root):
    return [e for e in root.iter() if isinstance(e.tag, str) and e is not root]


def mutate(data: bytes, rnd: random.Random) -> bytes:
    """1-3 random mutations of a deck (element level), then maybe a byte-level one."""
    root = etree.fromstring(data, etree.XMLParser(remove_comments=True))
    for _ in range(rnd.randint(1, 3)):
        els = _elements(root)
        if not els:
            break
        e = rnd.choice(els)
        op = rnd.randrange(7)
        if op == 0 and e.getparent() is not None:              # delete an element
            e.getparent().remove(e)
        elif op == 1 and e.getparent() is not None:            # duplicate an element
            e.addnext(copy.deepcopy(e))
        elif op == 2 and e.attrib:                             # wrong type / huge / unicode
            k = rnd.choice(sorted(e.attrib))
            e.set(k, rnd.choice(VALUES))
        elif op == 3 and e.attrib:                             # delete an attribute
            del e.attrib[rnd.choice(sorted(e.attrib))]
        elif op == 4:                                          # swap ids of two elements
            withid = [x for x in els if "id" in x.attrib]
            if len(withid) >= 2:
                a, b = rnd.sample(withid, 2)
                ia, ib = a.get("id"), b.get("id")
                a.set("id", ib)
                b.set("id", ia)
        elif op == 5 and e.attrib:                             # numeric scaling of a value
            k = rnd.choice(sorted(e.attrib))
            e.set(k, repr(rnd.choice([1e300, -1e300, 1e-300, 0.0, -1.0, 3.0]) * rnd.random()))
        elif op == 6:                                          # unknown attribute / text
            e.set(rnd.choice(["mass", "id", "x_üñí", "stiffness", "type"]), rnd.choice(VALUES))
    out = etree.tostring(root, encoding="utf-8", xml_declaration=True)
    r = rnd.random()
    if r < 0.15:                                               # truncation at a random offset
        out = out[:rnd.randrange(len(out) + 1)]
    elif r < 0.25:                                             # random byte noise
        b = bytearray(out)
        for _ in range(rnd.randint(1, 4)):
            b[rnd.randrange(len(b))] = rnd.randrange(256)
        out = bytes(b)
    return out


def _check_in_process(data: bytes):
    try:
        spec = parse_deck_bytes(data, "fuzz.xml")
        compile_model(spec)
    except DeckError:
        pass


@settings(max_examples=N_EXAMPLES, derandomize=True, deadline=None, database=None,
          suppress_health_check=list(HealthCheck))
@given(src=st.integers(0, len(SOURCES) - 1), rnd=st.randoms(use_true_random=False))
def test_fuzz_parse_validate_compile(src, rnd):
    _check_in_process(mutate(SOURCES[src], rnd))


def test_fuzz_sources_are_valid():
    assert len(SOURCES) >= 15
    for p, data in zip(DECKS, SOURCES):
        compile_model(parse_deck_bytes(data, str(p)))


def _run_cli(args):
    i, data, tmp = args
    deck = tmp / f"fuzz_{i}.xml"
    deck.write_bytes(data)
    r = subprocess.run([POISE, "solve", str(deck), "-o", str(tmp / f"fuzz_{i}.h5"), "-q",
                        "--max-num-iter", "20", "--no-fallback"],
                       capture_output=True, text=True, timeout=300)
    return i, r.returncode, r.stderr


@pytest.mark.parametrize("chunk", [0])
def test_fuzz_cli_end_to_end(tmp_path, chunk):
    rnd = random.Random(20240611 + chunk)
    cases = [(i, mutate(SOURCES[rnd.randrange(len(SOURCES))], rnd), tmp_path) for i in range(N_CLI)]
    with ThreadPoolExecutor(max_workers=4) as ex:
        for i, code, err in ex.map(_run_cli, cases):
            assert code in (0, 1, 3), (i, code, err)
            assert "Traceback" not in err, (i, err)
