"""Expressions and curves that cannot be evaluated end cleanly through the CLI: a located deck
error (exit 3) when the problem is visible at compile time (a number literal that overflows, a
constant sub-expression that always fails, a curve undefined where it is sampled), otherwise a
non-convergence with the results file written (exit 1) — in every method — never an internal
error (exit 4), a traceback, or a hang. Decks are the repository's decks with one mutation (the
fuzz findings of the reliability report)."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from support.paths import DECKS


POISE = str(Path(sys.executable).parent / "poise")
TIMEOUT = 60            # generous "does not hang" bound (the report asks for 20 s)


def _strict(s):
    raise ValueError(f"non-strict JSON constant {s}")


def _mutant(tmp_path, name, old, new, count=1):
    text = (DECKS / name).read_text()
    assert text.count(old) >= 1, old
    p = tmp_path / name
    p.write_text(text.replace(old, new, count))
    return p


def _solve(deck, *extra):
    out = deck.with_suffix(".h5")
    r = subprocess.run([POISE, "solve", str(deck), "-o", str(out), "--json", *extra],
                       capture_output=True, text=True, timeout=TIMEOUT)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode in (0, 1, 3), (r.returncode, r.stderr)
    summary = json.loads(r.stdout, parse_constant=_strict)
    if r.returncode in (0, 1):
        assert out.exists() and out.stat().st_size > 0, r.stderr
    return r, summary


def _located(r, deck, line, *needles):
    """Exit 3 and a problem line ``FILE:LINE: <Tag id=N> ...`` holding every needle."""
    assert r.returncode == 3, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith(f"{deck}:{line}: <")]
    assert lines, r.stderr
    assert all(n in lines[0] for n in needles), lines[0]


# ----------------------------------------------------------------------------- compile time
def test_overflowing_literal_is_located(tmp_path):
    """s02263: '20*TIME+1e309' in a quasi-static run."""
    d = _mutant(tmp_path, "qs_pendulum_ramp.xml", 'fx_expression="20*TIME"',
                'fx_expression="20*TIME+1e309"')
    r, _ = _solve(d)
    _located(r, d, 15, "<Force_Vector_OneBody id=1> fx_expression col 9:", "1e309",
             "out of range")


@pytest.mark.parametrize("method", ["MKEAM", "FIM_S"])
def test_constant_division_by_zero_is_located(tmp_path, method):
    """mkeam_gravity_div0: grav_y='1/0' fails at every evaluation, whatever the method."""
    d = _mutant(tmp_path, "mkeam_pendulum_multiturn.xml", 'grav_y="-9810."', 'grav_y="1/0"')
    d.write_text(re.sub(r'method="\w+"', f'method="{method}"', d.read_text(), count=1))
    r, s = _solve(d)
    assert s["exit_code"] == 3
    line = next(i for i, ln in enumerate(d.read_text().splitlines(), 1) if "Force_Gravity" in ln)
    _located(r, d, line, "grav_y col 2:", "division by zero")


def test_curve_undefined_where_sampled_is_located(tmp_path):
    """ptcv_curve_div0: y = (0.5 U^2)^-1 on [-2, 2] is undefined at U = 0."""
    d = _mutant(tmp_path, "elem_ptcv_parabola.xml", 'y_expression="0.5*U**2"',
                'y_expression="(0.5*U**2)**-1"')
    r, _ = _solve(d)
    line = next(i for i, ln in enumerate(d.read_text().splitlines(), 1)
                if "<Reference_ParamCurve" in ln)
    _located(r, d, line, "<Reference_ParamCurve id=1> y_expression:", "division by zero",
             "'(0.5*U**2)**-1'", "at U = 0")


# ----------------------------------------------------------------------------- solve time
_RUNTIME_DIV0 = ('<Force_Scalar_TwoBody id="9" type="FORCE" i_marker_id="202" j_marker_id="100" '
                 'val_expression="1/(DX(202,100)-400)"/>\n  </Model>')


@pytest.mark.parametrize("method", [
    "FIM_S", "FIM_D",
    "MKEAM",
])
def test_state_dependent_division_by_zero_is_a_clean_failure(tmp_path, method):
    """1/(DX - 400) with DX = 400 in the input configuration: exit 1, results written, the
    status names the expression."""
    d = _mutant(tmp_path, "mkeam_pendulum_multiturn.xml", "</Model>", _RUNTIME_DIV0)
    d.write_text(re.sub(r'method="\w+"', f'method="{method}"', d.read_text(), count=1))
    r, s = _solve(d)
    assert r.returncode == 1, r.stderr
    msg = " ".join(a.get("message") or "" for a in s["analyses"])
    assert "division by zero" in msg and "val_expression" in msg, msg


def test_state_dependent_division_by_zero_quasi_static(tmp_path):
    """The same in a FIM_D quasi-static run (TIME-dependent, fails at t = 0)."""
    d = _mutant(tmp_path, "qs_pendulum_ramp.xml", 'fx_expression="20*TIME"',
                'fx_expression="20*TIME/(DX(20,10)-DX(20,10))"')
    r, s = _solve(d)
    assert r.returncode == 1, r.stderr
    assert "division by zero" in " ".join(a.get("message") or "" for a in s["analyses"])


def test_power_overflow_of_a_state(tmp_path):
    """s01903: '500*DIF(1)**1e308' in a quasi-static Control_Diff deck."""
    d = _mutant(tmp_path, "elem_diff_integrator_qs.xml", 'fx_expression="500*DIF(1)"',
                'fx_expression="500*DIF(1)**1e308"')
    r, _ = _solve(d)
    assert r.returncode in (1, 3), r.stderr


def test_huge_curve_parameter_range(tmp_path):
    """s01690: u_end = 1.68e300 on a cam curve (was OverflowError in the curve's FD step)."""
    text = (DECKS / "elem_cvcv_cam_qs.xml").read_text()
    m = re.search(r'(<Reference_ParamCurve id="2"[^>]*?u_end=")([^"]*)"', text, re.S)
    assert m, "deck layout changed"
    d = tmp_path / "cam.xml"
    d.write_text(text[:m.start(2)] + "1.6839309208271404e+300" + text[m.end(2):])
    _solve(d)


def test_non_finite_curve_parameter_range_is_located(tmp_path):
    d = _mutant(tmp_path, "elem_ptcv_parabola.xml", 'u_end="2.0"', 'u_end="1e308"')
    d.write_text(d.read_text().replace('u_start="-2.0"', 'u_start="-1e308"'))
    r, _ = _solve(d)
    _located(r, d, next(i for i, ln in enumerate(d.read_text().splitlines(), 1)
                        if "<Reference_ParamCurve" in ln), "parameter range")


@pytest.mark.parametrize("fallback", [
    False,
    True,
])
def test_large_curve_amplitude(tmp_path, fallback):
    """s03245: x = 99999*COS(U) on the CVSF disk (was IndexError naming the singular row)."""
    d = _mutant(tmp_path, "elem_cvsf_disk_plane.xml", 'x_expression="0.2*COS(U)"',
                'x_expression="99999*COS(U)"')
    r, _ = _solve(d, *([] if fallback else ["--no-fallback"]))
    assert r.returncode in (0, 1, 3)


@pytest.mark.parametrize("fallback", [
    False,
    True,
])
def test_huge_constant_in_control_diff(tmp_path, fallback):
    """s00096: Control_Diff '1e308 + 0.1*TIME - DX(20,10)': finite but overflowing residual."""
    d = _mutant(tmp_path, "elem_diff_integrator.xml", 'expr="0.4 + 0.1*TIME - DX(20,10)"',
                'expr="1e308 + 0.1*TIME - DX(20,10)"')
    r, _ = _solve(d, *([] if fallback else ["--no-fallback"]))
    assert r.returncode == 1, r.stderr


# ----------------------------------------------------------------------------- in process
def test_curve_evaluation_error_names_the_parameter():
    """A curve evaluated where it is undefined (as Newton may do during a solve) raises the
    located EvaluationError that every solver turns into exit 1 — with the deck text and U —
    never ZeroDivisionError / OverflowError; finite points keep exact derivatives."""
    import numpy as np

    from poise.deck.spec import Expr
    from poise.core.errors import EvaluationError, SourceLoc
    from poise.elements.curve_data import AnalyticCurve
    loc = SourceLoc("c.xml", 14, "Reference_ParamCurve", 1)
    c = AnalyticCurve(None, [Expr("U", loc, "x_expression"), Expr("1/(U-3)", loc, "y_expression"),
                             0.0], -2.0, 2.0, False)
    d = c.derivs(np.array([1.0, 2.0]), 1)
    np.testing.assert_allclose(d[0][:, 1], [-0.5, -1.0], rtol=1e-15)
    np.testing.assert_allclose(d[1][:, 1], [-0.25, -1.0], rtol=1e-15)     # -1/(u-3)^2 exact
    with pytest.raises(EvaluationError) as ei:
        c.derivs(np.array([0.0, 3.0]), 2)
    msg = str(ei.value)
    assert msg.startswith("c.xml:14: <Reference_ParamCurve id=1> y_expression:"), msg
    assert "division by zero in '1/(U-3)' at U = 3" in msg, msg
    big = AnalyticCurve(None, [Expr("U", loc, "x_expression"), 0.0, 0.0], 0.0, 1.68e300, False)
    assert np.all(np.isfinite(big.derivs(np.array([1.0]), 3)[:2]))     # no OverflowError
