"""Fuzzing of the Adams dataset reader: random mutations of the datasets in decks/adm.

In-process: reading (``parse_deck_bytes``) and ``compile_model`` either succeed or raise a
``DeckError`` (located problems, exit 3); anything else is a bug. A smaller end-to-end set runs
the real CLI: exit 0, 1 or 3 only, never a traceback or a hang.

Mutations, line level: deleted, duplicated or swapped lines, a keyword's value replaced (wrong
type, huge, non-finite, empty, unicode), a keyword misspelled or cut short, separators lost
(``=``, ``,``, ``\\``), continuation lines broken, a statement name misspelled, ids repeated,
expressions made deep or long; byte level: truncation and noise. Deterministic (derandomized).
Longer runs: ``POISE_FUZZ_ADM=20000 POISE_FUZZ_ADM_CLI=200 .venv/bin/pytest
tests/regression/test_fuzz_adm.py``.
"""
from __future__ import annotations

import os
import random
import re
import subprocess
import sys
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from poise.core.errors import DeckError
from poise.deck.parser import parse_deck_bytes
from poise.model.compile import compile_model

from support.fuzz import damage
from support.paths import DECKS

NAMES = ("adm_joint_zoo adm_force_zoo elem_diff_integrator pendulum_multiturn double_pendulum "
         "slider_crank_load elem_field elem_beam_cantilever elem_coupler elem_gear_rack "
         "expr_spline_spring qs_slider_crank_11b bushing_block elem_point_springs").split()
SOURCES = [(DECKS / "adm" / f"{n}.adm").read_text() for n in NAMES]
N_EXAMPLES = int(os.environ.get("POISE_FUZZ_ADM", "1500"))
N_CLI = int(os.environ.get("POISE_FUZZ_ADM_CLI", "12"))
POISE = str(Path(sys.executable).with_name("poise"))

VALUES = ["", "abc", "1e308", "-1e308", "1e309", "inf", "nan", "-0", "0", "-1", "1,2", "1 2",
          "☃ünïcødé", "9" * 400, "90D", "1.5D0", "1.E-3", "(((", "1/0", "USER(1,2)", "DX(1,2)",
          "2147483648", "99999999999999999999999", "1e", ",", "=", "\\", "!", "'"]
KEYWORDS = ["I", "J", "QP", "REULER", "PART", "CM", "MASS", "IP", "FUNCTION", "K", "KT", "JFLOAT",
            "RM", "ZP", "XP", "USEXP", "FLOATING", "GROUND", "LENGTH", "ROTATION", "TRANS",
            "FX", "ID", "END", "STEPS", "KMATRIX", "X", "Y", "Z"]
STATEMENTS = ["PART", "MARKER", "JOINT", "JPRIM", "SFORCE", "VFORCE", "GFORCE", "BUSHING",
              "BEAM", "FIELD", "SPLINE", "ARRAY", "VARIABLE", "DIFF", "MOTION", "REQUEST",
              "ACCGRAV", "UNITS", "EQUILIBRIUM", "CONTACT", "GRAPHICS", "MARKR", "END", "SENSOR"]


def _mutate_line(line: str, rnd: random.Random) -> str:
    op = rnd.randrange(9)
    if op == 0:                                         # a value replaced
        return re.sub(r"=\s*[^,\\]*", lambda m: "= " + rnd.choice(VALUES), line, count=1)
    if op == 1:                                         # a keyword renamed or cut short
        return re.sub(r"\b([A-Z_]+)\s*=", lambda m: rnd.choice(
            [m.group(1)[:1], m.group(1)[:-1] or "Q", rnd.choice(KEYWORDS)]) + " =", line, count=1)
    if op == 2:                                         # separators lost
        return line.replace(rnd.choice(["=", ",", "\\", "/"]), "", 1)
    if op == 3:                                         # a continuation broken or made
        return line[1:] if line.startswith(",") else ", " + line
    if op == 4:                                         # another statement name
        return re.sub(r"^[A-Z_]+/", rnd.choice(STATEMENTS) + "/", line)
    if op == 5:                                         # a number made huge or odd
        return re.sub(r"-?\d+(\.\d*)?", lambda m: rnd.choice(
            ["1e308", "-1e309", "0", "1e-320", "7.5D", "nan", "00"]), line, count=1)
    if op == 6:                                         # an expression made deep or long
        n = rnd.choice([50, 400])
        return re.sub(r"FUNCTION\s*=\s*(.*)", lambda m: "FUNCTION = " + "(" * n + m.group(1)
                      + ")" * n, line) if "FUNCTION" in line else line + "+1" * n
    if op == 7:                                         # an id repeated
        return re.sub(r"/\d+", "/1", line, count=1)
    return line + rnd.choice([", ", ", GROUND", ", FLOATING", ", I = 9999", "!MS#, FIM_S"])


def mutate(text: str, rnd: random.Random) -> bytes:
    lines = text.splitlines()
    for _ in range(rnd.randint(1, 4)):
        k = rnd.randrange(1, len(lines))
        r = rnd.random()
        if r < 0.15:
            del lines[k]
        elif r < 0.25:
            lines.insert(k, lines[k])
        elif r < 0.32:
            j = rnd.randrange(1, len(lines))
            lines[k], lines[j] = lines[j], lines[k]
        else:
            lines[k] = _mutate_line(lines[k], rnd)
    return damage("\n".join(lines).encode("utf-8"), rnd, truncate=0.08, noise=0.06)


def _check_in_process(data: bytes):
    try:
        compile_model(parse_deck_bytes(data, "fuzz.adm"))
    except DeckError as e:
        assert e.problems and all(str(p).startswith("fuzz.adm:") for p in e.problems)


def test_fuzz_sources_are_valid():
    for n, text in zip(NAMES, SOURCES):
        compile_model(parse_deck_bytes(text.encode(), f"{n}.adm"))


@settings(max_examples=N_EXAMPLES, derandomize=True, deadline=None, database=None,
          suppress_health_check=list(HealthCheck))
@given(src=st.integers(0, len(SOURCES) - 1), rnd=st.randoms(use_true_random=False))
def test_fuzz_read_validate_compile(src, rnd):
    _check_in_process(mutate(SOURCES[src], rnd))


def test_fuzz_cli_exit_codes(tmp_path):
    rnd = random.Random(23)
    for i in range(N_CLI):
        p = tmp_path / f"fuzz_{i}.adm"
        p.write_bytes(mutate(SOURCES[i % len(SOURCES)], rnd))
        r = subprocess.run([POISE, "solve", str(p), "-o", str(tmp_path / f"f{i}.h5"), "-q",
                            "--max-num-iter", "20", "--no-fallback"],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode in (0, 1, 3), (p.read_text(errors="replace"), r.stderr)
        assert "Traceback" not in r.stderr and "internal error" not in r.stderr
