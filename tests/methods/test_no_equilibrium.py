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
from poise.gen.deck import Deck, rot_x, rot_z
from poise.gen.slide import rack_and_pinion, slide

G = 9.81


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


@pytest.mark.parametrize("joint", ["TRANSLATIONAL", "CYLINDRICAL"])
def test_a_mass_off_the_axis_of_a_45_degree_slide(tmp_path, joint):
    """The mass centre 600 mm off the slide's axis (horizontal): on a CYLINDRICAL joint gravity
    also turns the body about the axis (zero stiffness there at the start, and a load that
    changes along the turn), but the slide alone is free with a constant load, m g sin 45."""
    a = solve(slide(45.0, joint=joint, arm=600.0), tmp_path)
    said_at_once(a)
    assert "<Body_Rigid id=2> is free to translate along" in a.message
    d = vector(a.message, "along")
    np.testing.assert_allclose(d, [-np.sqrt(0.5), -np.sqrt(0.5), 0.0], atol=1e-6)
    assert number(a.message, r"constant load of ([-0-9.e+]+) N") == pytest.approx(
        G * np.sin(np.pi / 4), rel=1e-5)


ADM_CYLINDER = """poise test: a bar on a cylindrical joint whose axis is 30 deg from the vertical
UNITS/
, FORCE = NEWTON, MASS = KILOGRAM, LENGTH = METER, TIME = SECOND
PART/1, GROUND
MARKER/11, PART = 1, QP = 0, 0, 0, REULER = 0D, 30D, 0D
PART/2, MASS = 2, CM = 21, IP = 0.05, 0.4, 0.4
MARKER/21, PART = 2, QP = 1.5, 0, 0, REULER = 0D, 30D, 0D
MARKER/22, PART = 2, QP = 0, 0, 0, REULER = 0D, 30D, 0D
JOINT/1, CYLINDRICAL, I = 22, J = 11
ACCGRAV/
, KGRAV = -9.80665
END
"""


def test_an_adams_bar_on_a_tilted_cylindrical_joint(tmp_path):
    """An Adams dataset: the bar's mass 1.5 m off an axis 30 deg from the vertical; the axis
    (z of MARKER/11, body-fixed 3-1-3 angles 0, 30, 0) is (0, -sin 30, cos 30); the load
    along it is m g cos 30 = 2 x 9.80665 x cos 30 N, down the axis."""
    p = tmp_path / "cylinder.adm"
    p.write_text(ADM_CYLINDER)
    a = run_deck(str(p)).analyses[0]
    said_at_once(a)
    assert "cylinder.adm:6: PART/2 is free to translate along" in a.message
    np.testing.assert_allclose(vector(a.message, "along"),
                               [0.0, np.sin(np.pi / 6), -np.cos(np.pi / 6)], atol=1e-6)
    assert number(a.message, r"constant load of ([-0-9.e+]+) N") == pytest.approx(
        2 * 9.80665 * np.cos(np.pi / 6), rel=1e-6)


def test_a_rack_free_to_slide_down_turns_its_pinion(tmp_path):
    """Two rigid groups move together: the rack slides down, the pinion turns 2 / PD rad per
    mm of it; the load per mm of rack travel is m g sin 30."""
    a = solve(rack_and_pinion(30.0), tmp_path)
    said_at_once(a)
    assert "bodies 2-3 (2 bodies" in a.message
    assert "as <Body_Rigid id=3> translates along" in a.message
    np.testing.assert_allclose(vector(a.message, "translates along"),
                               [-np.cos(np.pi / 6), -np.sin(np.pi / 6), 0.0], atol=1e-6)
    assert number(a.message, r"<Body_Rigid id=2> turns ([-0-9.e+]+) rad") == pytest.approx(
        2 / 80.0, rel=1e-6)
    np.testing.assert_allclose(np.abs(vector(a.message, "rad about the axis")), [0, 0, 1],
                               atol=1e-9)
    assert number(a.message, r"constant load of ([-0-9.e+]+) N") == pytest.approx(
        G * 0.5, rel=1e-5)


def test_a_torsion_spring_on_the_pinion_holds_the_rack(tmp_path):
    """k = 500 N mm/rad: k |theta| = m g sin 30 x PD / 2, the rack PD / 2 |theta| down."""
    k = 500.0
    a = solve(rack_and_pinion(30.0, spring=k), tmp_path)
    assert a.converged, a.message
    theta = 1.0 * G * 0.5 * 40.0 / k
    R = a.datasets["bodies/orientation"][0, 0]
    assert abs(np.arctan2(R[1, 0], R[0, 0])) == pytest.approx(theta, rel=1e-7)
    at = 40.0 * np.array([0.5, -np.cos(np.pi / 6), 0.0])
    down = -np.array([np.cos(np.pi / 6), 0.5, 0.0])
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 1], at + 40.0 * theta * down,
                               atol=1e-6)


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


def test_a_spring_along_a_cylindrical_joint_holds_the_body_off_its_axis(tmp_path):
    """The slide of the mass-off-the-axis body held by a spring on the axis (k = 1 N/mm, free
    length 0): the turn alone is no proof either; the body settles m g sin 45 / k down the
    slide with its mass hanging 600 mm from the axis along the part of gravity across it."""
    a = solve(slide(45.0, joint="CYLINDRICAL", arm=600.0,
                    extra=lambda d: d.spring(1, 21, 102, 1.0, 0.0)), tmp_path)
    assert a.converged, a.message
    u = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0])          # up the slide
    across = np.array([0.0, -1.0, 0.0]) + np.sin(np.pi / 4) * u        # gravity across it
    cm = -G * np.sin(np.pi / 4) * u + 600.0 * across / np.linalg.norm(across)
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], cm, atol=1e-6)


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
