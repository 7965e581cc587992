"""Expression decks (decks/expr_*.xml) against independent references (closed form or a 1-D root
solved here with scipy, never poise output), quadratic Newton convergence, requests, and the CLI
exit codes of the syntax-error and evaluation-error decks."""
from __future__ import annotations

import re
import subprocess
import sys

import h5py
import numpy as np
import pytest
from scipy.interpolate import Akima1DInterpolator
from scipy.optimize import brentq

from poise.model.compile import compile_model
from poise.app.runner import run

from support.paths import DECKS


G = 9810.0                 # mm/s^2
M = 2.0                    # kg (point-mass decks)
W = M * G * 1e-3           # N


def _solve(name):
    res = run(str(DECKS / name))
    ar = res.analyses[0]
    assert ar.status == "converged", ar.message
    return ar.datasets


def test_nonlinear_spring_closed_form_and_quadratic_convergence():
    k, k3, L0 = 0.05, 2.0e-4, 100.0
    x = brentq(lambda x: k * x + k3 * x ** 3 - W, 0.0, 1e3, xtol=1e-14)
    d = _solve("expr_nonlinear_spring.xml")
    np.testing.assert_allclose(d["bodies/position"][0, 0], [0.0, -(L0 + x), 0.0], atol=1e-9)
    # spring force output: f u with f = -W along -Y  -> (0, +W, 0) on I
    np.testing.assert_allclose(d["forces/force"][0, 0], [0.0, W, 0.0], atol=1e-9)
    e = np.asarray(d["iterations/imbalance"], float)
    e = e[e > 1e-14]
    assert len(e) >= 4
    for a, b in zip(e[-4:-1], e[-3:]):           # last iterations: e_{k+1} <= C e_k^2
        assert b <= 0.1 * a ** 2, e


def test_gravity_expression_is_time_dependent():
    m = compile_model(__import__("poise.deck.parser", fromlist=["load_deck"])
                      .load_deck(str(DECKS / "expr_nonlinear_spring.xml")))
    grav = next(f for f in m.families if f.name == "gravity")    # elements/gravity.py
    assert grav.batch is not None and m.depends_on_time()
    np.testing.assert_allclose(grav.acceleration(0.0)[0], [0.0, -9810.0, 0.0])
    np.testing.assert_allclose(grav.acceleration(2.0)[0], [0.0, -8810.0, 0.0])


def test_spline_spring_vs_scipy_akima():
    xs = np.array([80.0, 90, 100, 110, 120, 130, 140])
    ys = np.array([30.0, 15, 0, -12, -28, -50, -80])
    f = Akima1DInterpolator(xs, ys)
    L = brentq(lambda L: float(f(L)) + W, 100.0, 140.0, xtol=1e-14)
    assert 110 < L < 120
    d = _solve("expr_spline_spring.xml")
    np.testing.assert_allclose(d["bodies/position"][0, 0], [0.0, -L, 0.0], atol=1e-8)


def _follower_theta():
    kt, ell = 4000.0, 200.0

    def g(th):
        fx = -0.1 * ell * np.sin(th)
        fy = 30.0 * (1 + 0.5 * th)
        return -kt * th + ell * np.cos(th) * fy - ell * np.sin(th) * fx
    return brentq(g, 0.0, np.pi / 2, xtol=1e-15)


def test_follower_load_and_requests():
    th = _follower_theta()
    ell = 200.0
    d = _solve("expr_follower_load.xml")
    c, s = np.cos(th), np.sin(th)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    np.testing.assert_allclose(d["bodies/orientation"][0, 0], Rz, atol=1e-9)
    np.testing.assert_allclose(d["bodies/position"][0, 0], [100 * c, 100 * s, 0], atol=1e-8)
    fx, fy = -0.1 * ell * s, 30.0 * (1 + 0.5 * th)
    F = np.array([-fx, -fy, 0.0])            # hinge reaction on the bar (statics: sum F = 0)
    np.testing.assert_allclose(d["joints/force"][0, 0], F, atol=1e-8)
    assert list(d["requests/id"]) == [1, 2, 3]
    v = d["requests/values"]
    assert v.shape == (1, 3, 8)
    r1 = v[0, 0]
    np.testing.assert_allclose(r1[[0, 1, 2, 3]], [np.hypot(fx, fy), F[0], F[1], -F[1]], atol=1e-8)
    assert np.isnan(r1[4])                    # NULL channel
    np.testing.assert_allclose(r1[5], fx, atol=1e-8)                      # VFORCE(3,0,2,0)
    np.testing.assert_allclose(r1[6], np.degrees(th), atol=1e-8)
    np.testing.assert_allclose(r1[7], F @ Rz[:, 1], atol=1e-8)          # in the tip's axes
    r2 = v[0, 1]                                                          # MARKER_DISPLACEMENT
    np.testing.assert_allclose(r2[[0, 1, 2, 3]], [ell, ell * c, ell * s, 0.0], atol=1e-8)
    np.testing.assert_allclose(r2[5:], [th, 0.0, 0.0], atol=1e-9)
    r3 = v[0, 2]                              # MARKER_FORCE at the hinge: joint + spring
    tz = -4000.0 * th
    np.testing.assert_allclose(r3, [np.hypot(fx, fy), F[0], F[1], 0, abs(tz), 0, 0, tz],
                               atol=1e-7)


def _cli(args, cwd):
    return subprocess.run([sys.executable, "-c", "from poise_cli.main import cli; "
                           "cli(prog_name='poise')", *args], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


def test_syntax_error_deck_exit_3_with_column(tmp_path):
    r = _cli(["solve", str(DECKS / "invalid" / "expr_syntax.xml"), "-o",
              str(tmp_path / "o.h5")], tmp_path)
    assert r.returncode == 3, r.stderr
    assert re.search(r"expr_syntax\.xml:\d+: <Force_Scalar_TwoBody id=1> val_expression col 24: "
                     r"expected '\)'", r.stderr), r.stderr
    assert not (tmp_path / "o.h5").exists()


def test_evaluation_error_deck_exit_1_file_written(tmp_path):
    out = tmp_path / "o.h5"
    r = _cli(["solve", str(DECKS / "expr_eval_error.xml"), "-o", str(out)], tmp_path)
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr
    assert re.search(r"expr_eval_error\.xml:\d+: <Force_Scalar_TwoBody id=1> val_expression: "
                     r"division by zero", r.stderr + r.stdout), r.stderr
    assert out.exists()
    with h5py.File(out) as f:
        assert not bool(f["analysis_000/frames/converged"][0])


@pytest.mark.parametrize("name", ["expr_nonlinear_spring", "expr_spline_spring",
                                  "expr_follower_load"])
def test_expr_decks_cli(name, tmp_path):
    r = _cli(["solve", str(DECKS / f"{name}.xml"), "-o", str(tmp_path / "o.h5")], tmp_path)
    assert r.returncode == 0, r.stderr
