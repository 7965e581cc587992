"""Fuzzing of the deck reader: random mutations of the valid decks in decks/*.xml.

In-process (fast): ``parse_deck_bytes`` + ``compile_model`` must either succeed or raise a
``DeckError`` (located problems, exit 3); any other exception is a bug. A smaller end-to-end set
runs the real CLI and checks the exit code is 0, 1 or 3 and that no traceback is printed.

Mutation kinds: deleted / duplicated elements, wrong-typed, huge and non-finite numbers in
attributes, and in expressions (``1e309``, ``*1e308``, ``**1e308``, ``/0``), deeply nested and
very long expressions (1000 parentheses, 1000-term sums), and user scripts that exit at import.
Each must end with exit 0, 1 (results written) or 3 (located), never 4, a traceback or a hang.

Deterministic (``derandomize=True`` / fixed seeds). Longer runs (also ``-m slow``)::

    POISE_FUZZ_EXAMPLES=200000 POISE_FUZZ_CLI=500 .venv/bin/pytest tests/regression/test_fuzz_deck.py
"""
import copy
import json
import os
import random
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from lxml import etree

from poise.deck.parser import parse_deck_bytes
from poise.core.errors import DeckError
from poise.model.compile import compile_model

from support.fuzz import damage
from support.paths import ROOT


NAMES = ("bushing_block chain_10 chain_10_spherical contact_ball_between_spheres contact_box_plane "
         "contact_sphere_plane double_pendulum expr_eval_error expr_follower_load "
         "expr_nonlinear_spring expr_spline_spring fourbar_spring mkeam_inverted_pendulum "
         "mkeam_pendulum_multiturn pendulum_multiturn qs_pendulum_ramp qs_slider_crank_11b "
         "qs_slider_crank_rev qs_spring_ramp slider_crank_load").split()
DECKS = [ROOT / "decks" / f"{n}.xml" for n in NAMES]
SOURCES = [p.read_bytes() for p in DECKS]
N_EXAMPLES = int(os.environ.get("POISE_FUZZ_EXAMPLES", "2000"))
N_CLI = int(os.environ.get("POISE_FUZZ_CLI", "16"))
N_EXPR = int(os.environ.get("POISE_FUZZ_EXPR", "150"))            # in-process, expression kinds
N_CLI_EXPR = int(os.environ.get("POISE_FUZZ_CLI_EXPR", "10"))     # CLI, expression kinds
EXPR_NAMES = ("expr_nonlinear_spring expr_follower_load expr_spline_spring qs_pendulum_ramp "
              "qs_spring_ramp elem_diff_integrator elem_diff_integrator_qs elem_ptcv_parabola "
              "elem_cvcv_cam_qs elem_cvsf_disk_plane mkeam_pendulum_multiturn "
              "elem_var_implicit").split()
EXPR_SOURCES = [(ROOT / "decks" / f"{n}.xml").read_bytes() for n in EXPR_NAMES]
TIMEOUT = 60            # generous "does not hang" bound per CLI run
POISE = str(Path(sys.executable).parent / "poise")

VALUES = ["", "abc", "1e308", "-1e308", "1e309", "inf", "-inf", "nan", "NaN", "+INF", "1e-320",
          "0", "-0", "-1", "-1e-300", "TRUE", "FALSE", "1,5", "0x10", "1.5.2", "9" * 400,
          "☃ünïcødé", "\u202e", "𝔘", "DX(1,2)", "SQRT(-1)", "1/0", "((((", "2147483648",
          "-2147483649", "99999999999999999999999", " 1 ", "1 2 3", "&amp;", "1e", "e5"]
HUGE = ["1e308", "-1e308", "1.7976931348623157e308", "1e309", "-1e309", "inf", "nan", "1e300",
        "-1e300", "1e-320", "4.9e-324", "1e200"]


def _nest(t, r):
    n = r.choice([50, 200, 1000])
    return "(" * n + t + ")" * n


def _long_sum(t, r):
    return "+".join([f"0*({t})"] * r.choice([100, 1000])) + f"+({t})"


EXPR_MUTATIONS = [
    _nest, _long_sum,
    lambda t, r: f"{t}+1e309",
    lambda t, r: f"({t})*1e308",
    lambda t, r: f"({t})**1e308",
    lambda t, r: f"1e308+{t}",
    lambda t, r: f"({t})/0",
    lambda t, r: f"({t})/(({t})-({t}))",
    lambda t, r: "-" * r.choice([2, 201]) + f"({t})",
    lambda t, r: "ABS(" * 300 + t + ")" * 300,
    lambda t, r: f"EXP(1000*({t}))",
    lambda t, r: f"SQRT(-1-ABS({t}))",
    lambda t, r: f"{r.choice(HUGE[:6])}*({t})",
]


def _is_expr_attr(name):
    return name.endswith("expression") or name in ("expr", "grav_x", "grav_y", "grav_z")


def mutate_numbers_and_expressions(data: bytes, rnd: random.Random) -> bytes:
    """1-2 mutations of the new kinds: an expression made huge / deep / long / non-finite, a huge
    or non-finite number in a numeric attribute, or a deleted element."""
    root = etree.fromstring(data, etree.XMLParser(remove_comments=True))
    for _ in range(rnd.randint(1, 2)):
        els = _elements(root)
        exprs = [(e, k) for e in els for k in sorted(e.attrib) if _is_expr_attr(k)]
        nums = [(e, k) for e in els for k in sorted(e.attrib)
                if re.fullmatch(r"[-+]?[\d.]+([eEdD][-+]?\d+)?", e.get(k) or "")]
        r = rnd.random()
        if r < 0.6 and exprs:
            e, k = rnd.choice(exprs)
            e.set(k, rnd.choice(EXPR_MUTATIONS)(e.get(k), rnd))
        elif r < 0.9 and nums:
            e, k = rnd.choice(nums)
            e.set(k, rnd.choice(HUGE))
        else:
            e = rnd.choice(els)
            if e.getparent() is not None:
                e.getparent().remove(e)
    return etree.tostring(root, encoding="utf-8", xml_declaration=True)


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
        op = rnd.randrange(9)
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
        elif op == 7 and e.attrib:                             # huge / non-finite number
            e.set(rnd.choice(sorted(e.attrib)), rnd.choice(HUGE))
        elif op == 8:                                          # expression: deep/long/huge
            ks = [k for k in sorted(e.attrib) if _is_expr_attr(k)]
            if ks:
                k = rnd.choice(ks)
                e.set(k, rnd.choice(EXPR_MUTATIONS)(e.get(k), rnd))
    out = etree.tostring(root, encoding="utf-8", xml_declaration=True)
    return damage(out, rnd, truncate=0.15, noise=0.10)     # truncation or random byte noise


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


@settings(max_examples=N_EXPR, derandomize=True, deadline=None, database=None,
          suppress_health_check=list(HealthCheck))
@given(src=st.integers(0, len(EXPR_SOURCES) - 1), rnd=st.randoms(use_true_random=False))
def test_fuzz_expressions_and_numbers_compile(src, rnd):
    """Huge/deep/long/non-finite expressions and numbers: compiled, or a located DeckError."""
    _check_in_process(mutate_numbers_and_expressions(EXPR_SOURCES[src], rnd))


def _strict_json(s):
    raise ValueError(f"non-strict JSON constant {s}")


def _run_cli_checked(deck, out, *extra):
    """Run ``poise solve --json``; assert the outcome is clean (see the module docstring)."""
    r = subprocess.run([POISE, "solve", str(deck), "-o", str(out), "--json", *extra],
                       capture_output=True, text=True, timeout=TIMEOUT)
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    assert r.returncode != 4, r.stderr[-2000:]
    json.loads(r.stdout, parse_constant=_strict_json)       # strict JSON, nothing else
    if r.returncode in (0, 1):
        assert out.exists() and out.stat().st_size > 0, r.stderr[-2000:]
    return r


def _cli_expression_cases(seed, n, tmp_path):
    rnd = random.Random(seed)
    for i in range(n):
        k = rnd.randrange(len(EXPR_SOURCES))
        deck = tmp_path / f"fx_{i}_{EXPR_NAMES[k]}.xml"
        deck.write_bytes(mutate_numbers_and_expressions(EXPR_SOURCES[k], rnd))
        yield deck


def _check_expression_case(deck, *extra):
    r = _run_cli_checked(deck, deck.with_suffix(".h5"), *extra)
    assert r.returncode in (0, 1, 3), (deck.name, r.returncode, r.stderr[-2000:])
    if r.returncode == 3:      # every problem line located (an element's, or the deck's own)
        lines = [ln for ln in r.stderr.splitlines() if ln and not ln.startswith("poise: ")]
        assert lines and all(re.match(r"^.+:\d+: ", ln) for ln in lines), \
            (deck.name, r.stderr[-2000:])


def test_fuzz_cli_expressions_and_numbers(tmp_path):
    """End to end, the new kinds (with the fallback chain off to keep the default run short)."""
    cases = list(_cli_expression_cases(20260101, N_CLI_EXPR, tmp_path))
    with ThreadPoolExecutor(max_workers=2) as ex:
        list(ex.map(lambda d: _check_expression_case(d, "--max-num-iter", "30",
                                                     "--no-fallback"), cases))


@pytest.mark.slow
@pytest.mark.parametrize("chunk", range(4))
def test_fuzz_cli_expressions_and_numbers_slow(tmp_path, chunk):
    """Larger run of the new kinds with the default fallback chain."""
    cases = list(_cli_expression_cases(20270000 + chunk, 50, tmp_path))
    with ThreadPoolExecutor(max_workers=2) as ex:
        list(ex.map(_check_expression_case, cases))


@pytest.mark.slow
@pytest.mark.parametrize("chunk", range(1, 5))
def test_fuzz_cli_end_to_end_slow(tmp_path, chunk):
    """More of the general mutations, end to end."""
    test_fuzz_cli_end_to_end(tmp_path, chunk)


def _user_code_flag():
    r = subprocess.run([POISE, "solve", "--help"], capture_output=True, text=True, timeout=60)
    return "--allow-user-code" in r.stdout


@pytest.mark.parametrize("body", ["raise SystemExit(0)", "raise SystemExit(3)",
                                  "raise SystemExit", "import sys; sys.exit('bye')"])
def test_fuzz_user_script_exits_at_import(tmp_path, body):
    """A user script that exits at import: never exit 0 with nothing written, never exit 4 or
    a traceback (the located-error wording belongs to the user-code opt-in)."""
    if not _user_code_flag():
        pytest.skip("this poise has no --allow-user-code opt-in yet")
    src = (ROOT / "decks" / "elem_user_forces.xml").read_text()
    (tmp_path / "exits.py").write_text(body + "\n")
    deck = tmp_path / "exits.xml"
    deck.write_text(src.replace('script_name="elem_user_routines.py"', 'script_name="exits.py"'))
    out = tmp_path / "exits.h5"
    r = subprocess.run([POISE, "solve", str(deck), "-o", str(out), "--json",
                        "--allow-user-code"], capture_output=True, text=True, timeout=TIMEOUT)
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    assert r.returncode != 4, r.stderr[-2000:]
    assert not (r.returncode == 0 and not out.exists()), r.stderr[-2000:]
    assert r.returncode != 0, "a deck whose user script exits cannot have solved"
