"""Exactly neutral directions get a definite, unit-independent verdict.

A free spin, a free slide, a mechanism's free motion under no load have a reduced stiffness of
exactly zero; the computed one is rounding error of either sign. The classification must say
``neutral`` with the right zero count whatever that sign, in mm, m and km, on the dense and the
sparse path, and an unused far marker must change nothing. Every expected value comes from a
closed form written here (positions, reactions, zero counts, mode directions).
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import poise.solvers.stability as stab
from support.paths import DECKS

from poise.gen.deck import I3, Deck, rot_x, rot_y, rot_z

POISE = str(Path(sys.executable).parent / "poise")
G = 9.81                      # m/s^2 (Deck scales the -9810 mm/s^2 of its gravity)
UNITS = ("mm", "m", "km")
S = {"mm": 1.0, "m": 1e-3, "km": 1e-6}          # deck length per mm


def _verdict(a):
    d = a.datasets
    return str(d["frames/stability"][0]), int(d["frames/n_negative"][0]), \
        int(d["frames/n_zero"][0])


def _modes(a):
    d = a.datasets
    return list(zip(d["modes/class"].tolist(), d["modes/kind"].tolist(),
                    [np.asarray(x) for x in d["modes/direction"]]))


# -- one body ---------------------------------------------------------------------------------
def spherical_pendulum(units, Rj=I3, Rb=I3, tilt=(0.3, -0.2), length=400.0,
                       mass=2.0, far=None):
    """A body on a SPHERICAL joint at the origin (joint markers with axes ``Rj``, body axes
    ``Rb``), CG ``length`` mm from the pivot, released ``tilt`` (rad about x, z) from hanging.
    ``far``: an unused ground marker at (far, 0, 0) mm."""
    d = Deck(units=units)
    d.ground()
    d.marker(101, 1, (0, 0, 0), Rj)
    p = rot_z(tilt[1]) @ rot_x(tilt[0]) @ np.array([0.0, -length, 0.0])
    d.body(2, 20, p, Rb, mass=mass, inertia=(9e4, 2e3, 8e4))
    d.marker(21, 2, (0, 0, 0), Rj)
    d.marker(22, 2, 2 * p)                                   # the tip (part of the body)
    d.joint(1, "SPHERICAL", 21, 101)
    if far is not None:
        d.marker(999, 1, (far, 0, 0))
    return d


def _check_hanging(a, units, length=400.0, mass=2.0):
    assert a.converged, a.message
    s = S[units]
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], [0, -length * s, 0],
                               rtol=0, atol=1e-9 * length * s)
    np.testing.assert_allclose(a.datasets["joints/force"][0, 0], [0, mass * G, 0], atol=1e-8)
    assert _verdict(a) == ("neutral", 0, 1)
    [(klass, kind, axis)] = _modes(a)
    assert (klass, kind) == ("neutral", "rotation")
    np.testing.assert_allclose(axis, [0, 1, 0], atol=1e-6)   # the spin about the vertical


@pytest.mark.parametrize("units", UNITS)
def test_spherical_pendulum_hanging_is_neutral(runner, units):
    _check_hanging(runner.api(spherical_pendulum(units)), units)


def test_spherical_pendulum_neutral_whatever_the_marker_axes(runner):
    """Random joint and body axes, lengths, masses and release angles, in mm and m: the old
    classification called 3 of these 24 UNSTABLE (the sign of a 1e-30 rounding error
    decided)."""
    rng = np.random.default_rng(3)
    for units in ("mm", "m"):
        for _ in range(12):
            Rj = rot_x(rng.uniform(-3, 3)) @ rot_y(rng.uniform(-3, 3))
            Rb = rot_z(rng.uniform(-3, 3)) @ rot_x(rng.uniform(-3, 3))
            length, mass = rng.uniform(50, 2000), rng.uniform(0.1, 10)
            a = runner.api(spherical_pendulum(units, Rj, Rb,
                                              tuple(rng.uniform(-0.5, 0.5, 2)), length, mass))
            _check_hanging(a, units, length, mass)


SLIDE = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])      # columns: x=-Z, y=Y, z=X


def horizontal_slider(units, mass=3.0, roll=0.0, Rb=I3, offset=(0, 0, 0), height=0.0):
    """A body on a TRANSLATIONAL joint along global X (joint z axes along X, rolled ``roll``
    about it) at ``height`` mm, its CG ``offset`` mm from the joint point, gravity -Y."""
    R = rot_x(roll) @ SLIDE
    p = np.array([120.0, height, 0.0])
    d = Deck(units=units)
    d.ground()
    d.marker(101, 1, (0, height, 0), R)
    d.body(2, 20, p + offset, Rb, mass=mass, inertia=(1e3, 2e3, 3e3))
    d.marker(21, 2, p, R)
    d.marker(22, 2, p + (100, 30, 0))
    d.joint(1, "TRANSLATIONAL", 21, 101)
    return d


def _check_slider(a, units, mass=3.0, offset=(0, 0, 0), height=0.0):
    """Closed form: nothing moves (gravity has no component along the slide); the joint
    carries the weight and its moment about the joint point; one zero mode, the slide."""
    assert a.converged, a.message
    s = S[units]
    off = np.asarray(offset, float)
    p = (np.array([120.0, height, 0.0]) + off) * s
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], p, rtol=0,
                               atol=1e-9 * np.abs(p).max())
    W = np.array([0, -mass * G, 0])
    np.testing.assert_allclose(a.datasets["joints/force"][0, 0], -W, atol=1e-8)
    np.testing.assert_allclose(a.datasets["joints/torque"][0, 0], -np.cross(off * s, W),
                               atol=1e-9 * max(np.abs(off).max(), 1.0) * s)
    assert _verdict(a) == ("neutral", 0, 1)
    [(klass, kind, axis)] = _modes(a)
    assert (klass, kind) == ("neutral", "translation")
    np.testing.assert_allclose(axis, [1, 0, 0], atol=1e-9)


@pytest.mark.parametrize("units", UNITS)
def test_horizontal_slider_is_neutral(runner, units):
    _check_slider(runner.api(horizontal_slider(units)), units)


def test_horizontal_slider_neutral_whatever_the_axes_and_lever(runner):
    """Random roll of the joint axes, body axes, CG lever, mass and height, in mm and m: the
    old classification called 17 of these 24 ``stable`` (n_zero 0) or ``unstable``."""
    rng = np.random.default_rng(0)
    for units in ("mm", "m"):
        for _ in range(12):
            roll = rng.uniform(-3, 3)
            Rb = rot_z(rng.uniform(-3, 3)) @ rot_x(rng.uniform(-3, 3))
            off, mass, h = rng.uniform(-300, 300, 3), rng.uniform(0.1, 10), rng.uniform(-500, 500)
            a = runner.api(horizontal_slider(units, mass, roll, Rb, off, h))
            _check_slider(a, units, mass, off, h)


def body_on_spring(units, k=2.0, free=400.0, mass=2.0):
    """A free body hung by its CG from a translational spring (k N/mm, free length mm) to a
    ground point at the origin, released off the vertical."""
    d = Deck(units=units)
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 20, (40, -450, 25), rot_y(0.4), mass=mass, inertia=(3e3, 5e3, 7e3))
    d.marker(21, 2, (60, -300, 0))
    d.spring(1, 20, 101, k, free)
    return d


@pytest.mark.parametrize("units", UNITS)
def test_free_body_on_a_spring_has_three_zero_modes(runner, units):
    """Closed form: the CG hangs below the anchor at free + m g / k; translations are held
    (axial k, lateral m g / length), the three rotations about the CG are free."""
    a = runner.api(body_on_spring(units))
    assert a.converged, a.message
    y = -(400.0 + 2.0 * G / 2.0) * S[units]
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], [0, y, 0], rtol=0,
                               atol=1e-9 * abs(y))
    assert _verdict(a) == ("neutral", 0, 3)
    assert [(c, k) for c, k, _ in _modes(a)] == [("neutral", "rotation")] * 3


# -- closed loops without load ------------------------------------------------------------------
def _frame(x, z):
    """Axes (columns) with x along ``x`` and z along ``z`` (orthogonal to x)."""
    x = np.asarray(x, float) / np.linalg.norm(x)
    z = np.asarray(z, float) / np.linalg.norm(z)
    return np.column_stack([x, np.cross(z, x), z])


DELTA = dict(Rb=200.0, Rp=50.0, La=300.0, Lf=800.0, w=60.0, bearing=40.0, P=(0, 0, -700.0),
             amp=(10.0, -6.0, 4.0))


def _delta_arm_angle(at, k, Rb, Rp, La, Lf, **_):
    """Inverse kinematics of leg k: arm angle below the horizontal, platform centre ``at``."""
    ph = 2 * np.pi * k / 3
    u, t, ez = np.array([np.cos(ph), np.sin(ph), 0]), np.array([-np.sin(ph), np.cos(ph), 0]), \
        np.array([0, 0, 1.0])
    Q = np.asarray(at) + Rp * u - Rb * u
    a, b, c = Q @ u, Q @ t, Q @ ez
    K = (La ** 2 + a * a + b * b + c * c - Lf ** 2) / (2 * La)
    return float(np.arccos(K / np.hypot(a, c)) - np.arctan2(c, a))


def _delta_platform(thetas, Rb, Rp, La, Lf, **_):
    """Forward kinematics (closed form): the platform centre P lies on the three spheres of
    radius Lf about C_k - Rp u_k (C_k the elbow centres); the lower intersection."""
    cs = []
    for k, th in enumerate(thetas):
        ph = 2 * np.pi * k / 3
        u = np.array([np.cos(ph), np.sin(ph), 0])
        cs.append((Rb + La * np.cos(th) - Rp) * u + np.array([0, 0, -La * np.sin(th)]))
    c0, c1, c2 = cs
    # |P - ci|^2 = Lf^2: differences are linear in P
    A = 2 * np.array([c1 - c0, c2 - c0])
    rhs = np.array([c1 @ c1 - c0 @ c0, c2 @ c2 - c0 @ c0])
    p0 = np.linalg.lstsq(A, rhs, rcond=None)[0]              # a point of the line
    n = np.cross(A[0], A[1])
    n /= np.linalg.norm(n)
    # |p0 + s n - c0|^2 = Lf^2
    e = p0 - c0
    s = np.roots([1.0, 2 * n @ e, e @ e - Lf ** 2]).real
    Ps = [p0 + si * n for si in s]
    return min(Ps, key=lambda p: p[2])


def delta_robot(units, method="FIM_S", end=1.0, dt=0.1):
    """A delta robot without gravity or load: three arms, each on two coaxial REVOLUTE bearings
    (redundant: 5 equations each) and driven by a Motion_Joint ``amp sin(2 pi t)`` degrees;
    parallelogram forearms of two rods with SPHERICAL joints at both ends; a platform. Left
    free: the six rod spins (exactly neutral)."""
    c = DELTA
    d = Deck(units=units, grav=(0, 0, 0), method=method)
    d.ground()
    P = np.asarray(c["P"], float)
    ez = np.array([0, 0, 1.0])
    d.body(30, 300, P, mass=0.5, inertia=(400, 400, 700))
    for k in range(3):
        ph = 2 * np.pi * k / 3
        u, t = np.array([np.cos(ph), np.sin(ph), 0]), np.array([-np.sin(ph), np.cos(ph), 0])
        B = c["Rb"] * u
        th = _delta_arm_angle(P, k, **c)
        C = B + c["La"] * (np.cos(th) * u - np.sin(th) * ez)
        D = P + c["Rp"] * u
        arm = 10 + k
        Ra = _frame(C - B, t)
        d.body(arm, 110 + 10 * k, (B + C) / 2, Ra, mass=0.3, inertia=(50, 2300, 2300))
        for j, sg in enumerate((-1, 1)):                      # two coaxial bearings
            m = 1000 + 10 * k + 2 * j
            d.marker(m, arm, B + sg * c["bearing"] * t, Ra)
            d.marker(m + 1, 1, B + sg * c["bearing"] * t, Ra)
            d.joint(1 + k + 3 * j, "REVOLUTE", m, m + 1)
        d.add("Motion_Joint", id=1 + k, joint_id=1 + k, joint_type="R", val_type="D",
              type="EXPRESSION", expr=f"{c['amp'][k]}D*SIN(360D*TIME)")
        for s, sg in enumerate((-1, 1)):
            top, bot = C + sg * c["w"] / 2 * t, D + sg * c["w"] / 2 * t
            rod, cg = 20 + 2 * k + s, 200 + 20 * k + 10 * s
            Rr = _frame(bot - top, t)
            d.body(rod, cg, (top + bot) / 2, Rr, mass=0.1, inertia=(5333, 5333, 2))
            d.marker(cg + 1, rod, top, Rr)
            d.marker(cg + 2, arm, top, Rr)
            d.marker(cg + 3, rod, bot, Rr)
            d.marker(cg + 4, 30, bot, Rr)
            d.joint(10 + 2 * k + s, "SPHERICAL", cg + 1, cg + 2)
            d.joint(20 + 2 * k + s, "SPHERICAL", cg + 3, cg + 4)
    d.commands = [f'<Simulate analysis_type="Static" end_time="{end}" print_interval="{dt}"/>',
                  "<Stop/>"]
    return d


@pytest.mark.parametrize("units,method", [("mm", "FIM_S"), ("mm", "FIM_D"), ("m", "FIM_S"),
                                          ("m", "FIM_D")])
def test_load_free_delta_robot_has_no_negative_mode_at_any_frame(runner, units, method):
    """The old classification reported 2-4 negative modes at every frame after the first. Each
    frame: neutral, exactly the six rod spins (each a rotation about its rod's own axis), and
    the platform where the closed-form forward kinematics puts it."""
    a = runner.api(delta_robot(units, method), f"delta_{units}.xml")
    assert a.converged, a.message
    d = a.datasets
    s = S[units]
    nf = len(d["time"])
    assert nf == 11
    assert d["redundant/id"].size == 15                      # 3 x 5 bearing equations
    th0 = [_delta_arm_angle(DELTA["P"], k, **DELTA) for k in range(3)]
    ids = d["bodies/id"].tolist()
    for f in range(nf):
        assert str(d["frames/stability"][f]) == "neutral"
        assert (d["frames/n_negative"][f], d["frames/n_zero"][f]) == (0, 6)
        t = float(d["time"][f])
        th = [th0[k] + np.radians(DELTA["amp"][k]) * np.sin(2 * np.pi * t) for k in range(3)]
        # FIM_S frames to 1e-6 mm; FIM_D's to 4e-5 mm: max_error = 1e-8 x L (L = 492 mm)
        # with a factor 8 for its interpolated frames' error estimate (seen 1.05e-5 mm where
        # 8e-9 L was reported: issue 22 section 7)
        np.testing.assert_allclose(d["bodies/position"][f, ids.index(30)],
                                   _delta_platform(th, **DELTA) * s, rtol=0,
                                   atol=(4e-5 if method == "FIM_D" else 1e-6) * s)
    # the described modes of every frame: each a rod's spin about its own axis (x). Any vector
    # of the six-fold zero eigenspace is a combination of rod spins, so this holds whichever
    # basis the eigensolver returns
    per = np.repeat(np.arange(nf), d["frames/n_modes"][:])
    for f in range(nf):
        sel = np.nonzero(per == f)[0]
        assert len(sel) == 6
        for j in sel:
            b = int(d["modes/body"][j])
            assert 20 <= b < 26 and str(d["modes/kind"][j]) == "rotation"
            R = d["bodies/orientation"][f, ids.index(b)]
            assert abs(abs(np.asarray(d["modes/direction"][j]) @ R[:, 0]) - 1) < 1e-6


def test_load_free_redundant_fourbar_is_neutral(runner, tmp_path):
    """The planar four-bar of decks/fourbar_spring.xml built from four 3-D revolutes (3
    redundant equations) with gravity and spring removed: one free motion, zero stiffness."""
    text = (DECKS / "fourbar_spring.xml").read_text()
    text = text.replace('grav_y="-9810."', 'grav_y="0."')
    a0 = text.index("<Force_SpringDamper")
    text = text[:a0] + text[text.index("/>", a0) + 2:]
    p = tmp_path / "fourbar_free.xml"
    p.write_text(text)
    from poise.app.api import run_deck
    for method in ("FIM_S", "MKEAM"):
        a = run_deck(str(p), overrides={"method": method}).analyses[0]
        assert a.converged, a.message
        assert _verdict(a) == ("neutral", 0, 1)
        assert a.datasets["redundant/id"].size == 3


# -- an unused far marker -----------------------------------------------------------------------
def test_unused_far_marker_changes_nothing(runner):
    """decks/pendulum_multiturn.xml and the same deck with an unused ground marker 1e14 mm away
    (the reliability deck far_ground_marker_1e14.xml): the same model size, the same solve,
    the same stable verdict."""
    from poise.app.api import run_deck
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    base = DECKS / "pendulum_multiturn.xml"
    text = base.read_text()
    far_text = text.replace("</Model>", '<Reference_Marker id="999" body_id="1" '
                            'pos_x="1e14" pos_y="0" pos_z="0"/>\n</Model>')
    far = runner.tmp / "far.xml"
    far.write_text(far_text)
    # L: the largest distance of the deck's five markers (all at z = 0 on the X axis: 0, 0, 0,
    # 200, 400 mm) from their centroid (120 mm): 280 mm, with or without the far marker
    assert compile_model(load_deck(str(far))).L == compile_model(load_deck(str(base))).L == 280.0
    a, b = run_deck(str(base)).analyses[0], run_deck(str(far)).analyses[0]
    assert a.converged and b.converged
    assert _verdict(a) == _verdict(b) == ("stable", 0, 0)
    for k in ("bodies/position", "bodies/orientation", "frames/imbalance",
              "frames/min_stiffness_eigenvalue", "iterations/imbalance"):
        np.testing.assert_array_equal(a.datasets[k], b.datasets[k])
    # closed form: theta = 19.72365702162824 rad (the deck's comment), CG 200 mm from the hinge
    th = 19.72365702162824
    np.testing.assert_allclose(b.datasets["bodies/position"][0, 0],
                               [200 * np.cos(th), 200 * np.sin(th), 0], atol=1e-7)


@pytest.mark.parametrize("far", [1e12, 1e14, 1e40, 1e99])
def test_far_marker_on_a_neutral_pendulum(runner, far):
    a = runner.api(spherical_pendulum("mm", far=far))
    _check_hanging(a, "mm")


def test_far_marker_only_a_request_reads_changes_nothing(runner):
    """A request measuring from a ground marker 1e14 mm away: the marker plays no part in the
    equilibrium: L, rotation scales and verdict are those of the deck without it."""
    d = spherical_pendulum("mm", far=1e14)
    d.add("Post_Request", id=1, type="MARKER_DISPLACEMENT", i_marker_id=20, j_marker_id=999)
    a = runner.api(d)
    _check_hanging(a, "mm")
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    near = spherical_pendulum("mm")
    assert compile_model(load_deck(d.write(runner.tmp / "r.xml"))).L == \
        compile_model(load_deck(near.write(runner.tmp / "n.xml"))).L


def test_far_marker_deck_require_stable(tmp_path):
    """The reliability deck far_ground_marker_1e14.xml (pendulum_multiturn + an unused ground
    marker at x = 1e14 mm; also 1e99): stable, exit 0, with and without --require-stable."""
    text = (DECKS / "pendulum_multiturn.xml").read_text()
    for far in ("1e14", "1e99"):
        p = tmp_path / f"far_{far}.xml"
        p.write_text(text.replace("</Model>", f'<Reference_Marker id="999" body_id="1" '
                                  f'pos_x="{far}" pos_y="0" pos_z="0"/>\n</Model>'))
        for args in ((), ("--require-stable",)):
            r = subprocess.run([POISE, "solve", str(p), "-o", str(p.with_suffix(".h5")),
                                "--json", *args], capture_output=True, text=True, timeout=300)
            assert r.returncode == 0, r.stderr
            js = json.loads(r.stdout)["analyses"][0]
            assert (js["stability_class"], js["n_negative"], js["n_zero"]) == ("stable", 0, 0)


# -- --require-stable and --allow-neutral on neutral equilibria -----------------------------------
def test_require_stable_accepts_neutral_by_default(runner):
    """``--allow-neutral`` is the default: a hanging spherical pendulum passes
    ``--require-stable`` (exit 0), and fails it with ``--no-allow-neutral`` (exit 1, the
    results written, the message naming the neutral spin)."""
    d = spherical_pendulum("mm")
    r, js, out = runner.cli(d, "sph.xml", "--require-stable")
    assert r.returncode == 0, r.stderr
    assert js["analyses"][0]["stability_class"] == "neutral"
    r, js, out = runner.cli(d, "sph.xml", "--require-stable", "--no-allow-neutral")
    assert r.returncode == 1
    assert out.exists()
    assert "neutral" in js["analyses"][0]["message"]
    assert "--no-allow-neutral" in js["analyses"][0]["message"]


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_no_allow_neutral_fails_every_static_method(runner, method):
    """A free spin (the reliability deck neutral_free_spin.xml: a pendulum on a revolute with
    no load): ``--require-stable --no-allow-neutral`` exits 1 with FIM_S and MKEAM alike."""
    d = Deck(units="mm", grav=(0, 0, 0))
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 20, (200, 0, 0), mass=2.0, inertia=(25, 26679, 26679))
    d.marker(21, 2, (0, 0, 0))
    d.joint(1, "REVOLUTE", 21, 101)
    r, js, _ = runner.cli(d, "spin.xml", "--require-stable", "--method", method)
    assert r.returncode == 0, r.stderr
    r, js, _ = runner.cli(d, "spin.xml", "--require-stable", "--no-allow-neutral",
                          "--method", method)
    assert r.returncode == 1, r.stderr
    an = js["analyses"][0]
    assert an["stability_class"] == "neutral"
    assert "--no-allow-neutral" in an["message"]


# -- the sparse path -------------------------------------------------------------------------
def slider_chain(n=60, a=50.0, mass=0.2):
    """A carriage on a horizontal TRANSLATIONAL joint (global X) and an ``n``-link revolute
    chain hanging from it (links of ``a`` mm, released 0.2 rad off the vertical): 6 (n + 1)
    coordinates > DENSE_LIMIT. One neutral direction: the whole sliding along X."""
    Rs = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    d = Deck(units="mm")
    d.ground()
    d.marker(101, 1, (0, 0, 0), Rs)
    d.body(2, 20, (0, 0, 0), Rs, mass=1.0, inertia=(100, 100, 100))
    d.marker(21, 2, (0, 0, 0), Rs)
    d.joint(1, "TRANSLATIONAL", 21, 101)
    top = np.zeros(3)
    prev = 22
    d.marker(prev, 2, top)
    for k in range(n):
        R = rot_z(-np.pi / 2 - 0.2)                         # x down the link, 0.2 rad off
        end = top + R @ [a, 0, 0]
        b, m = 3 + k, 1000 + 10 * k
        d.body(b, m, (top + end) / 2, R, mass=mass, inertia=(1, a * a * mass / 12,
                                                            a * a * mass / 12))
        d.marker(m + 1, b, top, R)
        d.marker(m + 2, b, end, R)
        d.joint(2 + k, "REVOLUTE", m + 1, prev)
        top, prev = end, m + 2
    return d


def test_sparse_path_neutral_slider_chain(runner, monkeypatch):
    """Closed form: every link hangs straight down below the carriage (whose place along X the
    statics leaves free: Newton's path decides). Sparse (nq > DENSE_LIMIT) and dense classification agree:
    neutral, n_zero 1 (a translation along X)."""
    n, a = 60, 50.0
    d = slider_chain(n, a)
    got = runner.api(d, "chain.xml")
    assert 6 * (n + 1) > stab.DENSE_LIMIT
    assert got.converged, got.message
    pos = got.datasets["bodies/position"][0]
    np.testing.assert_allclose(pos[0, 1:], [0, 0], atol=1e-9)
    want = np.column_stack([np.full(n, pos[0, 0]), -a * (np.arange(n) + 0.5), np.zeros(n)])
    np.testing.assert_allclose(pos[1:], want, rtol=0, atol=1e-7)
    assert _verdict(got) == ("neutral", 0, 1)
    [(klass, kind, axis)] = _modes(got)
    assert (klass, kind) == ("neutral", "translation")
    np.testing.assert_allclose(axis, [1, 0, 0], atol=1e-6)
    monkeypatch.setattr(stab, "DENSE_LIMIT", 10 ** 6)
    dense = runner.api(d, "chain_dense.xml")
    assert _verdict(dense) == ("neutral", 0, 1)


@pytest.mark.parametrize("make,expected", [
    (lambda u: spherical_pendulum(u), ("neutral", 0, 1)),
    (lambda u: horizontal_slider(u), ("neutral", 0, 1)),
    (lambda u: body_on_spring(u), ("neutral", 0, 3)),
])
@pytest.mark.parametrize("units", UNITS)
def test_sparse_path_same_verdicts_on_one_body_decks(runner, monkeypatch, make, expected, units):
    monkeypatch.setattr(stab, "DENSE_LIMIT", 0)
    a = runner.api(make(units))
    assert a.converged, a.message
    assert _verdict(a) == expected


def test_sparse_path_load_free_delta(runner, monkeypatch):
    monkeypatch.setattr(stab, "DENSE_LIMIT", 0)
    a = runner.api(delta_robot("mm", "FIM_S", end=0.5, dt=0.25), "delta_sparse.xml")
    assert a.converged, a.message
    d = a.datasets
    assert d["frames/stability"].tolist() == ["neutral"] * 3
    assert d["frames/n_negative"].tolist() == [0] * 3
    assert d["frames/n_zero"].tolist() == [6] * 3


# -- scalar unknowns --------------------------------------------------------------------------
@pytest.mark.parametrize("expr,y", [("3 - DIF(2)", 3.0), ("DIF(2) - 3", 3.0),
                                    ("4 - 2*DIF(2) + 0*DX(20,101)", 2.0)])
def test_a_control_state_does_not_change_the_mechanism_verdict(runner, monkeypatch, expr, y):
    """A hanging pendulum (stable) with a Control_Diff state its equations determine (y' = 3 - y,
    y' = y - 3, y' = 4 - 2 y): the state's row is an equation, not a force, whatever its sign.
    Before: UNSTABLE, "body 2 rotation about (nan,nan,nan)". Closed forms: y = 3, 3, 2; the
    pendulum hangs below its pivot. Dense and sparse paths alike."""
    def deck():
        d = Deck(units="mm")
        d.ground()
        d.marker(101, 1, (0, 0, 0))
        d.body(2, 20, (0, -400, 0), mass=2.0, inertia=(9e4, 2e3, 8e4))
        d.marker(21, 2, (0, 0, 0))
        d.joint(1, "REVOLUTE", 21, 101)
        d.add("Control_Diff", id=2, is_implicit=False, ic=0.0, expr=expr)
        return d
    for limit in (stab.DENSE_LIMIT, 0):
        monkeypatch.setattr(stab, "DENSE_LIMIT", limit)
        a = runner.api(deck())
        assert a.converged, a.message
        assert _verdict(a) == ("stable", 0, 0), a.datasets["frames/stability_modes"][0]
        np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], [0, -400, 0], atol=1e-9)
        np.testing.assert_allclose(a.datasets["diffs/value"][0], [y], atol=1e-12)


def test_neutral_modes_do_not_depend_on_the_eigenbasis():
    """A cluster of zero eigenvalues is one eigenvalue: ``eigh`` may return any rotation of its
    space. The described neutral modes come from a basis that does not depend on which: free
    spins of separate bodies, mixed by a random rotation, come back as the single spins (sign
    aside), ordered by coordinate."""
    rng = np.random.default_rng(3)
    nq, k = 40, 5
    spins = np.zeros((nq, k))
    for c, at in enumerate((3, 11, 18, 27, 36)):       # each on its own three coordinates
        spins[at:at + 3, c] = rng.normal(size=3)
    spins /= np.linalg.norm(spins, axis=0)
    for _ in range(5):
        Q, _r = np.linalg.qr(rng.normal(size=(k, k)))
        C = stab.canonical_basis(spins @ Q)
        assert C.shape == (nq, k)
        np.testing.assert_allclose(np.abs(np.sum(C * spins, axis=0)), 1.0, atol=1e-12)


@pytest.mark.parametrize("path", ["dense", "sparse"])
@pytest.mark.parametrize("deck", ["chain_10_spherical.xml", "adm/chain_10_spherical.adm"])
def test_spherical_chain_lists_the_first_six_spins_by_body(deck, path, monkeypatch):
    """The 10 free spins of the spherical chain (each link about its own axis, the line
    through its two joints): the six described are links 2..7 in body order, in the XML deck
    and its ADM twin alike, on both paths (they were an arbitrary, round-off-chosen six, one
    link twice)."""
    from poise.app.api import run_deck
    if path == "sparse":
        monkeypatch.setattr(stab, "DENSE_LIMIT", 0)
    a = run_deck(str(DECKS / deck)).analyses[0]
    d = a.datasets
    assert _verdict(a)[:3] == ("neutral", 0, 10)
    assert int(d["frames/n_modes"][0]) == 6
    ids = [int(b) for b in d["bodies/id"]]
    assert [int(b) for b in d["modes/body"]] == ids[:6]
    for k in range(6):
        assert str(d["modes/kind"][k]) == "rotation"
        x_link = d["bodies/orientation"][0, k][:, 0]          # the link's own axis
        assert abs(abs(d["modes/direction"][k] @ x_link) - 1.0) < 1e-9
        assert abs(d["modes/eigenvalue"][k]) < 1e-9
