"""No equilibrium, said at once, and never said of a model that has one.

A group of bodies free to move rigidly (slide, turn) with nothing resisting anywhere along the
motion, pushed by a constant load: ``no_equilibrium`` before Newton's first step, naming the
bodies, the motion and the load (values from the closed form m g sin 45 deg, etc.). A free
direction whose load is balanced, a zero stiffness that holds only at the start (a horizontal
pendulum, the top of an inverted one) and a stop the element types cannot promise never to hit
(an expression force) are not called so: those models converge to their closed-form answers.
"""
import re

import numpy as np
import pytest

from poise.app.api import run_deck
from poise.gen.chain import build_chain_deck
from poise.gen.deck import Deck, rot_x, rot_y, rot_z

G = 9.81


def slide(angle_deg=45.0, joint="TRANSLATIONAL", units="mm", extra=None, pendulum=False):
    """A 1 kg body on a joint whose axis lies in the XY plane at ``angle_deg`` from X, gravity
    -Y, its ground marker 300 mm down the slide (the model size); ``pendulum``: a 0.5 kg bob
    hinged to it 150 mm below."""
    d = Deck(units=units)
    d.ground()
    R = rot_z(np.radians(angle_deg)) @ rot_y(np.pi / 2)
    d.marker(101, 1, -300.0 * R[:, 2], R)
    d.marker(102, 1, (0, 0, 0))
    d.body(2, 20, (0, 0, 0), mass=1.0, inertia=(100, 100, 100))
    d.marker(21, 2, (0, 0, 0), R)
    d.joint(1, joint, 21, 101)
    if pendulum:
        d.body(3, 30, (0, -150, 0), mass=0.5, inertia=(10, 10, 10))
        d.marker(31, 3, (0, 0, 0))
        d.marker(22, 2, (0, 0, 0))
        d.joint(2, "REVOLUTE", 31, 22)
    if extra:
        extra(d)
    return d


def hinge(theta0=0.0, torque=0.0, gravity=True, axis="z"):
    """A 2 kg bar, CG 200 mm from a hinge at the origin; hinge axis global Z (or Y: a
    turntable); a constant torque about the hinge axis [N mm]."""
    d = Deck(grav=(0, -9810.0, 0) if gravity else None)
    d.ground()
    R = rot_x(-np.pi / 2) if axis == "y" else np.eye(3)
    d.marker(101, 1, (0, 0, 0), R)
    d.body(2, 20, (200 * np.cos(theta0), 200 * np.sin(theta0), 0), rot_z(theta0), mass=2.0,
           inertia=(25, 26679, 26679))
    d.marker(21, 2, (0, 0, 0), R)
    d.joint(1, "REVOLUTE", 21, 101)
    if torque:
        t = dict(tx_expression=0.0, ty_expression=0.0, tz_expression=0.0)
        t["ty_expression" if axis == "y" else "tz_expression"] = float(torque)
        d.add("Force_Vector_OneBody", id=1, type="TORQUEONLY", marker_id=20, ref_marker_id=0,
              **t)
    return d


def solve(d, tmp_path, name="deck.xml", **over):
    return run_deck(d.write(tmp_path / name), overrides=over).analyses[0]


def vector(message, word):
    m = re.search(word + r" \(([^)]*)\)", message)
    assert m, message
    return np.array([float(x) for x in m.group(1).split(",")])


def number(message, pattern):
    m = re.search(pattern, message)
    assert m, message
    return float(m.group(1))


def said_at_once(a):
    """no_equilibrium found before Newton's first step; nothing else tried."""
    assert not a.converged
    assert a.datasets["frames/status"][0] == "no_equilibrium"
    assert a.datasets["frames/iterations"][0] == 0
    assert set(a.datasets["iterations/strategy"]) == {"plain"}


@pytest.mark.parametrize("units", ["mm", "m"])
def test_body_on_a_45_degree_slide(tmp_path, units):
    a = solve(slide(45.0, units=units), tmp_path)
    said_at_once(a)
    assert "<Body_Rigid id=2>" in a.message and "free to translate" in a.message
    d = vector(a.message, "along")
    np.testing.assert_allclose(np.abs(d), [np.sqrt(0.5), np.sqrt(0.5), 0.0], atol=1e-6)
    assert d[1] < 0                                  # downhill
    assert number(a.message, r"constant load of ([-0-9.e+]+) N") == pytest.approx(
        G * np.sin(np.pi / 4), rel=1e-5)


def test_vertical_slide_and_cylindrical_joint(tmp_path):
    for joint in ("TRANSLATIONAL", "CYLINDRICAL"):
        a = solve(slide(90.0, joint=joint), tmp_path, f"{joint}.xml")
        said_at_once(a)
        np.testing.assert_allclose(vector(a.message, "along"), [0, -1, 0], atol=1e-9)
        assert number(a.message, r"constant load of ([-0-9.e+]+) N") == pytest.approx(G)


def test_a_slider_carrying_a_pendulum_slides_as_one_group(tmp_path):
    """The pendulum's angle does not change the load along the slide: (1 + 0.5) kg g sin 45."""
    a = solve(slide(45.0, pendulum=True), tmp_path)
    said_at_once(a)
    assert "bodies 2-3 (2 bodies" in a.message
    assert number(a.message, r"constant load of ([-0-9.e+]+) N") == pytest.approx(
        1.5 * G * np.sin(np.pi / 4), rel=1e-5)


def test_a_constant_torque_on_a_free_hinge(tmp_path):
    """No gravity: the torque turns the bar about the hinge axis through the origin."""
    a = solve(hinge(torque=3000.0, gravity=False), tmp_path)
    said_at_once(a)
    assert "free to turn about the axis" in a.message
    ax = vector(a.message, "the axis")
    np.testing.assert_allclose(np.abs(ax), [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(vector(a.message, r"through"), [0, 0, 0], atol=1e-6)
    moment = number(a.message, r"constant moment of ([-0-9.e+]+) N\*mm")
    assert abs(moment) == pytest.approx(3000.0, rel=1e-9)


def test_a_turntable_under_gravity_and_a_torque(tmp_path):
    """Hinge axis vertical: gravity does no work along the turn, the torque does."""
    a = solve(hinge(torque=500.0, axis="y"), tmp_path)
    said_at_once(a)
    np.testing.assert_allclose(np.abs(vector(a.message, "the axis")), [0, 1, 0], atol=1e-9)
    assert abs(number(a.message, r"constant moment of ([-0-9.e+]+) N\*mm")) == pytest.approx(
        500.0, rel=1e-9)


def test_a_chain_with_two_pins_removed_names_the_falling_middle(tmp_path):
    """20 links, the pins of joints 8 and 15 removed: links 8..14 (bodies 9..15) fall together;
    the load is their weight (the generator's links weigh 1 kg)."""
    text = build_chain_deck(20)
    for j in (8, 15):
        text, k = re.subn(rf'\s*<Constraint_Joint id="{j}"[^>]*/>', "", text, flags=re.S)
        assert k == 1
    p = tmp_path / "chain.xml"
    p.write_text(text)
    a = run_deck(str(p)).analyses[0]
    said_at_once(a)
    assert "bodies 9-15 (7 bodies" in a.message
    np.testing.assert_allclose(vector(a.message, "along"), [0, -1, 0], atol=1e-9)
    assert number(a.message, r"constant load of ([-0-9.e+]+) N") == pytest.approx(7 * G,
                                                                                 rel=1e-5)


# ------------------------------------------------------------------ not called no_equilibrium
def test_a_balanced_free_direction_is_neutral(tmp_path):
    """A constant force cancels gravity along the slide: an equilibrium anywhere on it."""
    f = G * np.sin(np.pi / 4)

    def force(d):
        d.force(1, 20, (f * np.cos(np.pi / 4), f * np.sin(np.pi / 4), 0.0))
    a = solve(slide(45.0, extra=force), tmp_path)
    assert a.converged, a.message
    assert a.datasets["frames/stability"][0] == "neutral"


def test_a_spring_along_the_slide_holds_it(tmp_path):
    """k = 1 N/mm to the origin: the body settles m g sin 45 / k down the slide."""
    a = solve(slide(45.0, extra=lambda d: d.spring(1, 20, 102, 1.0, 0.0)), tmp_path)
    assert a.converged, a.message
    s = G * np.sin(np.pi / 4) / 1.0
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0],
                               [-s * np.cos(np.pi / 4), -s * np.sin(np.pi / 4), 0], atol=1e-6)


def test_zero_stiffness_only_at_the_start_is_no_proof(tmp_path):
    """Horizontal pendulum: the stiffness about the hinge is zero there and the load is not,
    but both change along the turn: it hangs (theta = -90 deg). At the top of an inverted
    pendulum the load is zero: an (unstable) equilibrium."""
    a = solve(hinge(0.0), tmp_path, "horizontal.xml")
    assert a.converged, a.message
    R = a.datasets["bodies/orientation"][0, 0]
    assert np.arctan2(R[1, 0], R[0, 0]) == pytest.approx(-np.pi / 2, abs=1e-9)
    top = solve(hinge(np.pi / 2), tmp_path, "top.xml")
    assert top.converged, top.message
    assert top.datasets["frames/stability"][0] == "unstable"


def test_a_torque_below_m_g_l_is_held(tmp_path):
    """T = 0.5 m g l: cos(theta) = T / (m g l) at the equilibrium."""
    mgl = 2.0 * G * 200.0
    a = solve(hinge(0.0, torque=0.5 * mgl), tmp_path)
    assert a.converged, a.message
    R = a.datasets["bodies/orientation"][0, 0]
    assert np.cos(np.arctan2(R[1, 0], R[0, 0])) == pytest.approx(0.5, abs=1e-9)


def test_an_expression_stop_down_the_slide_is_not_ruled_out(tmp_path):
    """A one-sided stop 200 mm down the slide written as an expression force (k = 0.5 N/mm):
    expressions may switch on anywhere, so no claim; the body rests on the stop where
    k (s - 200) = m g sin 45 (s measured down the slide)."""
    k, s0 = 0.5, 200.0
    u = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0])      # up the slide

    def stop(d):
        s = "(-(DX(20)*0.7071067811865476 + DY(20)*0.7071067811865476))"
        f = f"IF({s} - {s0}: 0, 0, {k}*({s} - {s0}))"
        d.add(f'<Force_Vector_OneBody id="1" type="FORCEONLY" marker_id="20" ref_marker_id="0" '
              f'fx_expression="{f}*0.7071067811865476" fy_expression="{f}*0.7071067811865476" '
              'fz_expression="0"/>')
    a = solve(slide(45.0, extra=stop), tmp_path)
    assert a.datasets["frames/status"][0] != "no_equilibrium"
    assert a.converged, a.message
    s = s0 + G * np.sin(np.pi / 4) / k
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], -s * u, atol=1e-5)
