"""Stable equilibria: ``--require-stable`` (FIM_S leaves an unstable equilibrium downhill),
``--allow-neutral``, and MKEAM, checked against closed forms written here.

Reference: the discrete catenary. N equal rigid links (length a, weight w each, CG at
mid-length) hang between pins at (0,0) and (S,0). Each link is a rigid bar loaded by its
weight at its centre and by pin forces at its ends; moment equilibrium about its centre says
the mean of the two end forces, i.e. the internal force at the link's centre, is along the
link. That force has the constant horizontal component H and the vertical component
``V0 - w (i - 1/2)`` (V0: the left support's vertical reaction), so the angle of link i is
``tan th_i = (w (i - 1/2) - V0) / H``. Symmetry gives V0 = N w / 2; H is the one root of
``a sum cos th_i = S`` (scipy brentq).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest
from scipy.optimize import brentq

from poise.gen.chain import build_chain_deck
from poise.solvers.settings import StaticSettings

from support.paths import ROOT


A = 100.0           # link length [mm] (build_chain_deck default)


def catenary_cgs(n, a=A, span=None):
    """Link CG positions (n, 2) of the discrete catenary (module docstring)."""
    span = 0.8 * n * a if span is None else span
    i = np.arange(1, n + 1)

    def tan_th(H):                      # w = 1: H in units of the link weight
        return (i - 0.5 - n / 2) / H

    H = brentq(lambda H: a * np.sum(1.0 / np.sqrt(1.0 + tan_th(H) ** 2)) - span,
               1e-9, 1e9, xtol=1e-14, rtol=1e-15)
    th = np.arctan(tan_th(H))
    nodes = np.vstack([[0.0, 0.0], np.cumsum(a * np.c_[np.cos(th), np.sin(th)], axis=0)])
    return 0.5 * (nodes[:-1] + nodes[1:])


def _deck(tmp_path, n, start="v", joint="revolute", name=None):
    p = tmp_path / (name or f"chain_{n}_{start}.xml")
    p.write_text(build_chain_deck(n, joint=joint, start=start))
    return p


def _cg_deviation(ar, n):
    ids = np.asarray(ar.datasets["bodies/id"])
    pos = np.asarray(ar.datasets["bodies/position"])[0][np.argsort(ids)][:, :2]
    return float(np.max(np.abs(pos - catenary_cgs(n)))) / (n * A)


def _solve(path, **over):
    import poise
    return poise.solve(str(path), **over).analyses[0]


def test_catenary_reference_is_an_equilibrium_shape():
    """The closed form itself: links of length a, ends on the pins, symmetric."""
    c = catenary_cgs(20)
    assert c.shape == (20, 2)
    assert np.allclose(c[:, 0] + c[::-1, 0], 0.8 * 20 * A, atol=1e-9)
    assert np.allclose(c[:, 1], c[::-1, 1], atol=1e-9)
    assert np.all(c[:, 1] < 0)


def test_v_start_deck_satisfies_the_joints():
    from poise.gen.chain import v_nodes
    pts = np.array(v_nodes(21, A, 0.8 * 21 * A))
    assert np.allclose(np.linalg.norm(np.diff(pts, axis=0), axis=1), A, rtol=1e-12)
    assert np.allclose(pts[0], 0) and np.allclose(pts[-1], [0.8 * 21 * A, 0])


@pytest.mark.parametrize("n", [20, 200])
def test_require_stable_reaches_the_catenary_from_a_v(tmp_path, n):
    ar = _solve(_deck(tmp_path, n), method="FIM_S", require_stable=True)
    assert ar.status == "converged", ar.message
    assert str(ar.datasets["frames/stability"][0]) == "stable"
    assert _cg_deviation(ar, n) <= 1e-6


def test_plain_fim_s_lands_on_an_unstable_equilibrium_and_says_so(tmp_path):
    ar = _solve(_deck(tmp_path, 200), method="FIM_S")
    assert ar.status == "converged"               # an equilibrium, labelled unstable
    assert str(ar.datasets["frames/stability"][0]) == "unstable"
    assert int(ar.datasets["frames/n_negative"][0]) > 0
    assert _cg_deviation(ar, 200) > 1e-3          # not the catenary


def test_require_stable_history_records_the_path(tmp_path):
    """Newton's kinked V is unstable: the descent from the input (the V) reaches the
    catenary; the path is in the history and the message."""
    ar = _solve(_deck(tmp_path, 200), method="FIM_S", require_stable=True)
    ev = [str(e) for e in ar.datasets["iterations/event"]]
    assert any(e.startswith("stable: Newton's equilibrium is unstable") and
               e.endswith("descent from the input") for e in ev)
    assert any(e.startswith("stable-descent") for e in ev)
    assert not any(e.startswith("stable: escape") for e in ev)
    assert "descended from the input" in ar.message
    assert _cg_deviation(ar, 200) <= 1e-6


def _upright_pendulum(tmp_path):
    """decks/mkeam_inverted_pendulum.xml standing exactly upright, its torsion spring free
    there: the input IS the unstable equilibrium (V = k/2 phi^2 + m g l cos phi, k = 2000
    N mm/rad < m g l = 3924 N mm), so the descent from the input cannot leave it."""
    text = (ROOT / "decks" / "mkeam_inverted_pendulum.xml").read_text()
    text = text.replace('pos_x="-19.966683329365637" pos_y="199.00083305560514" pos_z="0." '
                        'a00="-0.09983341664682818" a10="0.9950041652780257" a20="0." '
                        'a01="-0.9950041652780257" a11="-0.09983341664682818"',
                        'pos_x="0." pos_y="200." pos_z="0." a00="0." a10="1." a20="0." '
                        'a01="-1." a11="0."').replace('length="-0.1"', 'length="0."')
    assert 'pos_y="200."' in text
    p = tmp_path / "upright.xml"
    p.write_text(text)
    return p


def test_require_stable_escapes_when_the_input_is_the_unstable_point(tmp_path):
    """The descent from the input ends where it started (unstable): Newton's point is left
    along its unstable mode; the answer is the closed-form rest angle k phi = m g l sin phi."""
    ar = _solve(_upright_pendulum(tmp_path), method="FIM_S", require_stable=True)
    assert ar.status == "converged", ar.message
    assert str(ar.datasets["frames/stability"][0]) == "stable"
    ev = [str(e) for e in ar.datasets["iterations/event"]]
    assert any(e.startswith("stable: the descent from the input did not end") for e in ev)
    assert any(e.startswith("stable: escape 1: unstable (1 negative mode)") for e in ev)
    k, mgl = 2000.0, 2.0 * 9.81 * 200.0            # N mm/rad, N mm (g = 9810 mm/s^2)
    phi = brentq(lambda f: k * f - mgl * np.sin(f), 0.5, 3.0, xtol=1e-14)
    ids = list(np.asarray(ar.datasets["bodies/id"]))
    cg = np.asarray(ar.datasets["bodies/position"])[0][ids.index(2)]
    tilt = np.arctan2(-cg[0], cg[1])               # from +Y, positive towards -X
    assert abs(abs(tilt) - phi) <= 1e-6


def test_mkeam_reaches_the_catenary_from_a_v(tmp_path):
    ar = _solve(_deck(tmp_path, 20), method="MKEAM")
    assert ar.status == "converged", ar.message
    assert str(ar.datasets["frames/stability"][0]) == "stable"
    assert _cg_deviation(ar, 20) <= 1e-6


def _cli(args, cwd):
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "poise_cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def test_require_stable_out_of_budget_exit_1_results_written(tmp_path):
    """The upright pendulum: Newton is done at once (the input is an equilibrium); the
    descent's budget (2 x max_num_iter = 6 steps) is too small to fall from upright to rest:
    exit 1, the file is written, the status says why."""
    deck = _upright_pendulum(tmp_path)
    out = tmp_path / "r.h5"
    p = _cli(["solve", str(deck), "--method", "FIM_S", "--require-stable", "--max-num-iter",
              "3", "-o", str(out), "--json"], tmp_path)
    assert p.returncode == 1, p.stderr
    assert out.exists()
    s = json.loads(p.stdout)
    a = s["analyses"][0]
    assert a["status"] == "failed"
    assert "no stable equilibrium reached (--require-stable)" in a["message"]
    with h5py.File(out) as f:
        assert f["analysis_000/frames/status"][0].decode() == "unstable"
        assert not bool(f["analysis_000/frames/converged"][0])


def test_allow_neutral_semantics(tmp_path):
    """The spherical chain: every link spins freely about its own axis (neutral)."""
    deck = ROOT / "decks" / "chain_10_spherical.xml"
    a = _solve(deck, method="FIM_S", require_stable=True)            # neutral allowed
    assert a.status == "converged"
    assert str(a.datasets["frames/stability"][0]) == "neutral"
    b = _solve(deck, method="FIM_S", require_stable=True, allow_neutral=False)
    assert b.status == "failed"
    assert "neutral" in b.message and "--require-stable" in b.message
    assert str(b.datasets["frames/status"][0]) == "unstable"
    # the same point either way: refusing the label does not move the answer
    assert np.allclose(a.datasets["bodies/position"], b.datasets["bodies/position"], atol=1e-6)
    c = _solve(deck, method="FIM_S", allow_neutral=False)             # no --require-stable
    assert c.status == "converged"


def test_cli_allow_neutral_flag_exit_codes(tmp_path):
    deck = ROOT / "decks" / "chain_10_spherical.xml"
    p = _cli(["solve", str(deck), "--method", "FIM_S", "--require-stable", "--no-allow-neutral",
              "-o", str(tmp_path / "n.h5"), "--json"], tmp_path)
    assert p.returncode == 1
    assert "neutral" in json.loads(p.stdout)["analyses"][0]["message"]
    p = _cli(["solve", str(deck), "--method", "FIM_S", "--require-stable",
              "-o", str(tmp_path / "y.h5"), "--json"], tmp_path)
    assert p.returncode == 0


def test_settings_validation():
    assert StaticSettings().require_stable is False and StaticSettings().allow_neutral is True
    s = StaticSettings().updated({"require_stable": "true", "allow_neutral": "no"})
    assert s.require_stable is True and s.allow_neutral is False
    with pytest.raises(ValueError):
        StaticSettings().updated({"require_stable": "maybe"})
    with pytest.raises(ValueError):
        StaticSettings(require_stable=0.5)


# --------------------------------------------------------------------------- four-bar
def _fourbar_deck(tmp_path, phi):
    """decks/fourbar_spring.xml with the linkage placed at crank angle ``phi`` (exact loop
    closure from the closed-form positions of tests/support/reference.py)."""
    import re
    from support import reference as R
    st = R.fourbar_state(phi)
    P, cg, O = st["points"], st["cg"], st["orientation"]
    place = {200: (cg["crank"], O["crank"]), 201: (P["A"], O["crank"]), 202: (P["B"], O["crank"]),
             300: (cg["coupler"], O["coupler"]), 301: (P["B"], O["coupler"]),
             302: (P["C"], O["coupler"]),
             400: (cg["rocker"], O["rocker"]), 401: (P["C"], O["rocker"]),
             402: (P["D"], O["rocker"])}
    text = (ROOT / "decks" / "fourbar_spring.xml").read_text()

    def sub(m):
        mid = int(m.group(1))
        if mid not in place:
            return m.group(0)
        x, R3 = place[mid]
        attrs = {"pos_x": x[0], "pos_y": x[1], "pos_z": x[2]}
        attrs.update({f"a{i}{j}": R3[i, j] for i in range(3) for j in range(3)})
        out = m.group(0)
        for k, v in attrs.items():
            out = re.sub(rf'\b{k}="[^"]*"', f'{k}="{float(v)!r}"', out)
        return out

    text = re.sub(r'<Reference_Marker id="(\d+)"[^>]*/>', sub, text, flags=re.S)
    p = tmp_path / "fourbar_start.xml"
    p.write_text(text)
    return p, R


def test_fourbar_from_60_deg_require_stable_and_mkeam(tmp_path):
    """decks/fourbar_spring.xml started at crank angle 60 deg (from 90 deg Newton happens to
    reach the minimum on this linkage): Newton lands on the nearer equilibrium, the potential's
    maximum at 0.533 rad (unstable); --require-stable and MKEAM reach its only minimum. Both found here by a
    1-DOF scan of dV/dphi (reference.py, complex-step derivative, brentq)."""
    import math
    deck, R = _fourbar_deck(tmp_path, math.radians(60.0))
    mins = R._minima_on_circle(R.fourbar_dV)
    assert len(mins) == 1
    ref = R.fourbar_state(mins[0])

    def crank_angle(ar):
        ids = list(np.asarray(ar.datasets["bodies/id"]))
        Rc = np.asarray(ar.datasets["bodies/orientation"])[0][ids.index(2)]
        return math.atan2(Rc[1, 0], Rc[0, 0])

    plain = _solve(deck, method="FIM_S")
    assert plain.status == "converged"
    assert str(plain.datasets["frames/stability"][0]) == "unstable"
    for over in (dict(method="FIM_S", require_stable=True), dict(method="MKEAM")):
        ar = _solve(deck, **over)
        assert ar.status == "converged", (over, ar.message)
        assert str(ar.datasets["frames/stability"][0]) == "stable"
        d = (crank_angle(ar) - ref["phi"] + math.pi) % (2 * math.pi) - math.pi
        assert abs(d) <= 1e-6, over
