"""Newton on a classic linkage: a slider-crank started with the crank at 90 degrees.

Crank O-A 100 mm (0.5 kg), rod A-B 300 mm (1 kg), slider 2 kg at B on global X, gravity -Y, a
torsion spring on the crank pivot (5000 N mm/rad, free at 90 deg - 3 rad) and 50 N pushing the
slider towards the crank. The residual norm along the linkage has a valley short of the toggle
(|dV/dphi| falls to 7.1e3 N mm at 40 deg and rises to 8.4e3 at -30 deg before it vanishes at
-119.2 deg): plain Newton's first step put the slider past r + l, where the loop cannot close,
and its line search stalled there for 98 iterations. The reference is the 1-DOF potential
written here (brentq on its derivative); the equilibrium is its only root.
"""
import numpy as np
import pytest
from scipy.optimize import brentq

from poise.app.api import run_deck
from poise.gen.deck import Deck, rot_y, rot_z

R_CRANK, L_ROD, K, REF, LOAD = 100.0, 300.0, 5000.0, -3.0, -50.0
MG = (0.5 + 1.0) * 9.81 * R_CRANK / 2      # N mm: crank and rod weights, CG heights r/2 sin


def slider_x(phi):
    return R_CRANK * np.cos(phi) + np.sqrt(L_ROD ** 2 - (R_CRANK * np.sin(phi)) ** 2)


def potential(phi):
    """Spring, slider load and gravity [N mm] as functions of the crank angle."""
    return 0.5 * K * (phi - np.pi / 2 - REF) ** 2 - LOAD * slider_x(phi) + MG * np.sin(phi)


def equilibrium():
    dV = lambda p, h=1e-6: (potential(p + h) - potential(p - h)) / (2 * h)   # noqa: E731
    return brentq(dV, -2.5, -1.5, xtol=1e-14)


def slider_crank(phi0=np.pi / 2, units="mm"):
    """The linkage at crank angle ``phi0`` (lengths in mm, scaled to ``units`` by the
    builder)."""
    d = Deck(units=units)
    d.ground()
    A = R_CRANK * np.array([np.cos(phi0), np.sin(phi0), 0.0])
    B = np.array([slider_x(phi0), 0.0, 0.0])
    along = rot_y(np.pi / 2)                              # z along global X
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, B, along)
    d.body(2, 20, A / 2, rot_z(phi0), mass=0.5, inertia=(6.25, 420, 420))
    d.marker(21, 2, (0, 0, 0))
    d.marker(22, 2, A)
    d.body(3, 30, (A + B) / 2, rot_z(np.arctan2(B[1] - A[1], B[0] - A[0])), mass=1.0,
           inertia=(12.5, 7500, 7500))
    d.marker(31, 3, A)
    d.marker(32, 3, B)
    d.body(4, 40, B, mass=2.0, inertia=(500, 500, 500))
    d.marker(41, 4, B)
    d.marker(42, 4, B, along)
    d.joint(1, "REVOLUTE", 21, 101)
    d.joint(2, "REVOLUTE", 31, 22)
    d.joint(3, "REVOLUTE", 32, 41)
    d.joint(4, "TRANSLATIONAL", 42, 102)
    d.spring(1, 21, 101, K, REF, rotational=True)        # AZ = phi - 90 deg
    d.force(1, 40, (LOAD, 0.0, 0.0))
    return d


def test_the_reference_has_one_equilibrium_and_a_valley():
    phi = np.linspace(-np.pi, np.pi, 20001)
    dv = np.gradient(potential(phi), phi)
    assert np.count_nonzero(np.diff(np.sign(dv))) == 1       # one root over the turn
    # the valley of |dV/dphi| between the start and the root that is not a root
    a = (phi > np.radians(-30)) & (phi < np.radians(90))
    assert dv[a].min() > 7000.0


def test_slider_crank_at_90_degrees_converges_in_15_iterations(tmp_path):
    a = run_deck(slider_crank().write(tmp_path / "sc.xml")).analyses[0]
    assert a.converged, a.message
    assert a.datasets["frames/strategy"][0] == "plain"
    assert a.datasets["frames/iterations"][0] <= 15
    phi = equilibrium()
    R = a.datasets["bodies/orientation"][0, 0]
    assert np.arctan2(R[1, 0], R[0, 0]) == pytest.approx(phi, abs=1e-8)
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 2], [slider_x(phi), 0, 0],
                               atol=1e-6)
    # the stalled line search switched to projected trials and steps down the potential;
    # from then on every iterate closes the loop (no slider beyond r + l)
    ev = [str(e) for e in a.datasets["iterations/event"]]
    assert "newton-downhill" in ev
    k = next(i for i, e in enumerate(ev) if e != "newton")
    x = a.datasets["iterations/position"][k + 1:, 2, 0]
    assert np.all(x <= R_CRANK + L_ROD + 1e-6)
    assert a.datasets["frames/stability"][0] == "stable"


def test_the_same_linkage_in_metres_takes_the_same_path(tmp_path):
    """Scale-aware steps: the deck in m converges in the same iterations to the same angle."""
    mm = run_deck(slider_crank().write(tmp_path / "mm.xml")).analyses[0]
    m = run_deck(slider_crank(units="m").write(tmp_path / "m.xml")).analyses[0]
    assert m.converged, m.message
    assert m.datasets["frames/iterations"][0] == mm.datasets["frames/iterations"][0]
    R = m.datasets["bodies/orientation"][0, 0]
    assert np.arctan2(R[1, 0], R[0, 0]) == pytest.approx(equilibrium(), abs=1e-8)


def test_a_smooth_start_keeps_plain_newton(tmp_path):
    """Started 0.3 rad from the equilibrium nothing stalls: plain Newton rows only, converging
    quadratically."""
    a = run_deck(slider_crank(equilibrium() + 0.3).write(tmp_path / "near.xml")).analyses[0]
    assert a.converged, a.message
    ev = a.datasets["iterations/event"]
    assert set(str(e) for e in ev) == {"newton"}
    e = a.datasets["iterations/imbalance"]
    assert len(e) <= 8
    # the last two steps before the converged row: e_{k+1} / e_k^2 bounded (quadratic), the
    # imbalance falling by orders of magnitude each time
    r = [e[-3] / e[-4] ** 2, e[-2] / e[-3] ** 2]
    assert max(r) < 10.0 / float(np.max(e)), e
    assert e[-2] < 1e-4 * e[-3] < 1e-4 * e[-4], e


def test_a_bar_on_a_string_started_upside_down_hangs(tmp_path):
    """chrono's Adams validation model Distance_Case02 rebuilt: a 1 kg bar (thin along X:
    spinning about its own axis is a direction of no stiffness) tied at P, 2 m from its mass
    centre, by a 2 m distance constraint to a ground point G, started with the string and the
    bar horizontal and square to each other. Newton's steps there are all spin; steps down the potential (a
    shifted, pseudo-time step) bring it to hang straight down (Adams' answer), P 2 m and the
    mass centre 4 m below G. A spin about a neutral axis is no runaway (it turned many times
    while the potential hardly fell)."""
    d = Deck(units="m")
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 20, (-2000, 0, 2000), mass=1.0, inertia=(4e4, 1e5, 1e5))
    d.marker(21, 2, (0, 0, 2000))
    d.add("Constraint_General", id=1, expr="DM(21, 101) - 2", i_marker_id=21)
    a = run_deck(d.write(tmp_path / "string.xml")).analyses[0]
    assert a.converged, a.message
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], [0, -4, 0], atol=1e-9)
    assert a.datasets["frames/stability"][0] == "neutral"
