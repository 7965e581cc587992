"""Body_Point, Constraint_Coupler, Constraint_Gear, Force_Field, Force_Beam.

FD Jacobian checks on random configurations with random multipliers, and reference decks
(decks/elem_*.xml) with references computed here independently of the solver (closed forms,
scipy root finding, equilibrium re-checked from the body poses).
"""
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from poise.app.api import run_deck
from poise.core.errors import DeckError
from poise.elements.field_beam import beam_stiffness
from poise.model.compile import compile_model

from support.builders import random_rotation, stable_seed
from support.fd import fd_check, perturbed_state, two_body_deck
from support.paths import DECKS


# ----------------------------------------------------------------------------- Jacobians
def _joint_deck(rng, point_b=False):
    d = two_body_deck(rng, point_b)
    d.marker(12, 1, rng.normal(size=3), random_rotation(rng))
    d.marker(13, 1, rng.normal(size=3), random_rotation(rng))
    return d


@pytest.mark.parametrize("case", ["two", "three", "cyl_T", "cyl_R"])
def test_coupler_jacobian(case):
    rng = np.random.default_rng(stable_seed("coupler", case))
    d = _joint_deck(rng)
    d.add("Constraint_Joint", id=1, type="REVOLUTE", i_marker_id=21, j_marker_id=11)
    d.add("Constraint_Joint", id=2, type="TRANSLATIONAL", i_marker_id=31, j_marker_id=22)
    d.add("Constraint_Joint", id=3, type="CYLINDRICAL", i_marker_id=32, j_marker_id=12)
    if case == "two":
        d.add("Constraint_Coupler", id=1, joint1_id=1, joint2_id=2, coefficients=(1.5, -2.0))
    elif case == "three":
        d.add("Constraint_Coupler", id=1, joint1_id=2, joint2_id=1, joint3_id=3,
              freedom_3="R", coefficients=(0.7, 1.5, -2.0))
    else:
        d.add("Constraint_Coupler", id=1, joint1_id=3, freedom_1=case[-1], joint2_id=1,
              coefficients=(1.0, 3.0))
    m = compile_model(d.spec)
    fd_check(m, perturbed_state(m, rng))


@pytest.mark.parametrize("second", ["REVOLUTE", "TRANSLATIONAL"])
def test_gear_jacobian(second):
    rng = np.random.default_rng(stable_seed("gear", second))
    d = _joint_deck(rng)
    d.add("Constraint_Joint", id=1, type="REVOLUTE", i_marker_id=21, j_marker_id=11)
    d.add("Constraint_Joint", id=2, type=second, i_marker_id=32, j_marker_id=12)
    d.add("Constraint_Gear", id=1, joint1_id=1, joint2_id=2, cv_marker_id=13)
    m = compile_model(d.spec)
    fd_check(m, perturbed_state(m, rng))


def _field_attrs(rng):
    A = rng.normal(size=(6, 6))
    K = A @ A.T + 6 * np.eye(6) + 0.3 * rng.normal(size=(6, 6))      # dense, non-symmetric
    at = {f"k{i + 1}{j + 1}": float(K[i, j]) for i in range(6) for j in range(6)}
    for c, v in zip(("x", "y", "z", "tx", "ty", "tz"), rng.normal(size=6)):
        at[f"length_{c}"] = float(v)
    for c, v in zip(("x", "y", "z", "tx", "ty", "tz"), rng.normal(size=6)):
        at[f"preload_{c}"] = float(v)
    return at


BEAM = dict(length=1.3, e=2.0e3, g=8.0e2, area=0.5, ixx=0.02, iyy=0.03, izz=0.05, asy=1.2, asz=1.1,
            preload_x=0.5, preload_tz=-0.2)


@pytest.mark.parametrize("tag", ["Force_Field", "Force_Beam"])
@pytest.mark.parametrize("point_b", [False, True])
def test_field_beam_jacobian(tag, point_b):
    rng = np.random.default_rng(stable_seed(tag, point_b))
    d = two_body_deck(rng, point_b)
    attrs = _field_attrs(rng) if tag == "Force_Field" else BEAM
    d.add(tag, id=1, i_marker_id=21, j_marker_id=31, **attrs)
    d.add(tag, id=2, i_marker_id=32, j_marker_id=11, **attrs)     # J on ground
    m = compile_model(d.spec)
    fd_check(m, perturbed_state(m, rng))


# ----------------------------------------------------------------------------- reference decks
def _solve(path, method, tmp_path=None, text=None):
    if text is not None:
        p = tmp_path / Path(path).name
        p.write_text(text)
        path = p
    res = run_deck(str(path), overrides={"method": method})
    a = res.analyses[0]
    assert a.converged, a.message
    return a.datasets


def _zangle(d, frame=-1):
    R = d["bodies/orientation"][frame]
    return np.arctan2(R[:, 1, 0], R[:, 0, 0])


def _quasi_static(text, old, new):
    """The deck with a TIME-ramped load (``old`` -> ``new``), run as a FIM_D sequence to t = 1."""
    assert old in text
    text = text.replace(old, new).replace('method="FIM_S"', 'method="FIM_D"')
    return text.replace('<Simulate analysis_type="Static"/>',
                        '<Simulate analysis_type="Static" end_time="1.0" print_interval="0.25"/>')


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_point_mass_two_springs(method):
    k, L0, a, m, g = 500.0, 0.6, 0.5, 2.0, 9.81
    y = brentq(lambda y: 2 * k * (np.hypot(a, y) - L0) * (-y) / np.hypot(a, y) - m * g, -0.34, -3.0)
    d = _solve(DECKS / "elem_point_springs.xml", method)
    np.testing.assert_allclose(d["bodies/position"][0, 0], [0.0, y, 0.0], atol=1e-8)
    np.testing.assert_allclose(d["bodies/orientation"][0, 0], np.eye(3), atol=0)


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_point_mass_in_spherical_joint(method):
    k, g, mb, mp, l = 20.0, 9.81, 1.0, 0.5, 0.5
    th = brentq(lambda t: -k * t - g * np.cos(t) * (mb * l / 2 + mp * l), -np.pi / 2, 0.0)
    d = _solve(DECKS / "elem_point_pendulum.xml", method)
    assert abs(_zangle(d)[0] - th) < 1e-8
    np.testing.assert_allclose(d["bodies/position"][0, 1], [l * np.cos(th), l * np.sin(th), 0], atol=1e-8)
    # the spherical joint carries the point mass' weight
    np.testing.assert_allclose(d["joints/force"][0, 1], [0, mp * g, 0], atol=1e-7)


COUPLER_REF = dict(T=2.0, k2=50.0, k3=400.0)


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_coupler_three_joints(method):
    T, k2, k3 = COUPLER_REF.values()
    th2, x3 = -2 * T / k2, 0.5 * T / k3
    th1 = 0.3 - 2 * th2 + 0.5 * x3               # offsets: the input configuration satisfies it
    d = _solve(DECKS / "elem_coupler.xml", method)
    np.testing.assert_allclose(_zangle(d)[:2], [th1, th2], atol=1e-8)
    np.testing.assert_allclose(d["bodies/position"][0, 2], [x3, 1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(d["couplers/id"], [1])
    np.testing.assert_allclose(d["couplers/torque"][0, 0], [0, 0, -T], atol=1e-7)
    np.testing.assert_allclose(d["couplers/force"][0, 0], [0, 0, 0], atol=1e-7)


def test_coupler_quasi_static_fim_d(tmp_path):
    T, k2, k3 = COUPLER_REF.values()
    text = _quasi_static((DECKS / "elem_coupler.xml").read_text(), 'val="2.0"',
                         'val_expression="2.0*TIME"')
    d = _solve("elem_coupler.xml", "FIM_D", tmp_path, text)
    t = d["time"]
    np.testing.assert_allclose(t, [0, 0.25, 0.5, 0.75, 1.0])
    for f, tf in enumerate(t):
        th2 = -2 * T * tf / k2
        x3 = 0.5 * T * tf / k3
        np.testing.assert_allclose(_zangle(d, f)[:2], [0.3 - 2 * th2 + 0.5 * x3, th2], atol=1e-6)
        np.testing.assert_allclose(d["couplers/torque"][f, 0, 2], -T * tf, atol=1e-5)


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_gear_pair_transmits_torque(method):
    T, k, r1, r2 = 3.0, 100.0, 0.05, 0.15
    d = _solve(DECKS / "elem_gear_pair.xml", method)
    th1, th2 = _zangle(d)
    assert abs(r1 * th1 + r2 * th2) < 1e-9                  # rolling without slip, opposite turn
    # output torque (held by the spring) = ratio x input torque
    np.testing.assert_allclose(-k * th2, (r2 / r1) * T, rtol=1e-8)
    np.testing.assert_allclose(d["gears/torque"][0, 0], [0, 0, -T], atol=1e-7)
    np.testing.assert_allclose(d["gears/id"], [1])


def test_gear_pair_quasi_static_fim_d(tmp_path):
    T, k, r1, r2 = 3.0, 100.0, 0.05, 0.15
    text = _quasi_static((DECKS / "elem_gear_pair.xml").read_text(), 'val="3.0"',
                         'val_expression="3.0*TIME"')
    d = _solve("elem_gear_pair.xml", "FIM_D", tmp_path, text)
    for f, tf in enumerate(d["time"]):
        np.testing.assert_allclose(-k * _zangle(d, f)[1], (r2 / r1) * T * tf, atol=1e-5)


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_rack_and_pinion(method):
    T, k, r = 0.8, 2000.0, 0.04
    d = _solve(DECKS / "elem_gear_rack.xml", method)
    x = d["bodies/position"][0, 1, 0]
    np.testing.assert_allclose(x, T / (r * k), rtol=1e-8)
    np.testing.assert_allclose(_zangle(d)[0], x / r, rtol=1e-8)
    np.testing.assert_allclose(d["gears/torque"][0, 0], [0, 0, -T], atol=1e-8)


def test_user_coupler_rejected(tmp_path):
    text = (DECKS / "elem_coupler.xml").read_text().replace(
        'coefficients="1, 2, -0.5"', 'usrsub_dll_name="libcou.so" usrsub_param_string="USER(1)"')
    p = tmp_path / "cou.xml"
    p.write_text(text)
    with pytest.raises(DeckError, match=r"Constraint_Coupler id=1.*user coupler"):
        run_deck(str(p))


def _force_index(d, tag, id):
    k = np.nonzero((np.asarray(d["forces/tag"]) == tag) & (d["forces/id"] == id))[0]
    assert len(k) == 1
    return int(k[0])


def _pose_X(pos, R):
    """[DX, DY, DZ, AX, AY, AZ] of a marker at ``pos`` with axes ``R`` relative to the global
    frame (J on ground with identity axes), computed independently of poise's kernels."""
    x, y, z = R[:, 0], R[:, 1], R[:, 2]
    ex, ey, ez = np.eye(3)
    return np.array([*pos, np.arctan2(y @ ez, y @ ey), np.arctan2(z @ ex, z @ ez),
                     np.arctan2(x @ ey, x @ ex)])


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_field_equilibrium(method):
    import xml.etree.ElementTree as ET
    root = ET.parse(DECKS / "elem_field.xml").getroot()
    f = root.find(".//Force_Field").attrib
    K = np.array([[float(f[f"K{i}{j}"]) for j in range(1, 7)] for i in range(1, 7)])
    C6 = ("x", "y", "z", "tx", "ty", "tz")
    L = np.array([float(f[f"length_{c}"]) for c in C6])
    F0 = np.array([float(f[f"preload_{c}"]) for c in C6])
    v = root.find(".//Force_Vector_OneBody").attrib
    ext = np.array([float(v[f"{c}_expression"]) for c in ("fx", "fy", "fz", "tx", "ty", "tz")])
    d = _solve(DECKS / "elem_field.xml", method)
    X = _pose_X(d["bodies/position"][0, 0], d["bodies/orientation"][0, 0])
    np.testing.assert_allclose(-K @ (X - L) + F0 + ext, 0.0, atol=1e-6)
    # small rotations: close to the linear solution
    np.testing.assert_allclose(X, L + np.linalg.solve(K, F0 + ext), atol=2e-3)
    k = _force_index(d, "Force_Field", 1)
    np.testing.assert_allclose(d["forces/force"][0, k], -ext[:3], atol=1e-6)
    np.testing.assert_allclose(d["forces/torque"][0, k], -ext[3:], atol=1e-6)


def test_beam_matrix_tip_flexibility():
    L, E, G, A, ixx, iyy, izz, asy, asz = 0.7, 3.0, 1.1, 0.2, 0.01, 0.02, 0.03, 1.2, 1.4
    C = np.linalg.inv(beam_stiffness(L, E, G, A, ixx, iyy, izz, asy, asz))
    np.testing.assert_allclose(C[1, 1], L ** 3 / (3 * E * izz) + L * asy / (G * A), rtol=1e-12)
    np.testing.assert_allclose(C[2, 2], L ** 3 / (3 * E * iyy) + L * asz / (G * A), rtol=1e-12)
    np.testing.assert_allclose(C[5, 1], L ** 2 / (2 * E * izz), rtol=1e-12)
    np.testing.assert_allclose(C[4, 2], -L ** 2 / (2 * E * iyy), rtol=1e-12)
    np.testing.assert_allclose(C[0, 0], L / (E * A), rtol=1e-12)
    np.testing.assert_allclose(C[3, 3], L / (G * ixx), rtol=1e-12)


BEAM_DECK = dict(L=0.3, E=2.1e11, G=8.1e10, A=2.0e-3, ixx=5.0e-7, iyy=2.6667e-7, izz=4.1667e-7,
                 asy=1.2, asz=1.1)


def _beam_refs():
    b = BEAM_DECK
    L, E, G, A = b["L"], b["E"], b["G"], b["A"]
    P, F, T = 1000.0, 2.0e4, 50.0
    return dict(v=P * L ** 3 / (3 * E * b["izz"]) + P * L * b["asy"] / (G * A),
                rz=P * L ** 2 / (2 * E * b["izz"]),
                w=P * L ** 3 / (3 * E * b["iyy"]) + P * L * b["asz"] / (G * A),
                ry=-P * L ** 2 / (2 * E * b["iyy"]), u=F * L / (E * A), rx=T * L / (G * b["ixx"]))


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_beam_cantilever(method):
    r = _beam_refs()
    d = _solve(DECKS / "elem_beam_cantilever.xml", method)
    pos, R = d["bodies/position"][0], d["bodies/orientation"][0]
    X = [_pose_X(pos[k] - [0, 0, 0.2 * k], R[k]) for k in range(3)]
    # Euler-Bernoulli P L^3/(3 E I) plus the shear term P L as/(G A) (2-3 % here)
    np.testing.assert_allclose(X[0][1], r["v"], rtol=1e-5)
    np.testing.assert_allclose(X[0][5], r["rz"], rtol=1e-5)
    np.testing.assert_allclose(X[1][2], r["w"], rtol=1e-5)
    np.testing.assert_allclose(X[1][4], r["ry"], rtol=1e-5)
    np.testing.assert_allclose(X[2][0] - 0.3, r["u"], rtol=1e-4)
    np.testing.assert_allclose(X[2][3], r["rx"], rtol=1e-5)
    assert abs(r["v"] - 1000 * 0.3 ** 3 / (3 * 2.1e11 * 4.1667e-7)) > 1e-2 * r["v"]   # shear visible
    # the beam's force on the tip body balances the load (forces/* = action on I)
    np.testing.assert_allclose(d["forces/force"][0, _force_index(d, "Force_Beam", 2)],
                               [0, -1000, 0], atol=1e-4)


def test_beam_quasi_static_fim_d(tmp_path):
    r = _beam_refs()
    text = _quasi_static((DECKS / "elem_beam_cantilever.xml").read_text(),
                         'fy_expression="1000"', 'fy_expression="1000*TIME"')
    d = _solve("elem_beam_cantilever.xml", "FIM_D", tmp_path, text)
    for f, tf in enumerate(d["time"]):
        np.testing.assert_allclose(d["bodies/position"][f, 0, 1], r["v"] * tf, rtol=1e-4,
                                   atol=1e-12)


def test_field_quasi_static_fim_d(tmp_path):
    text = _quasi_static((DECKS / "elem_field.xml").read_text(), 'fx_expression="100"',
                         'fx_expression="100*TIME"')
    d = _solve("elem_field.xml", "FIM_D", tmp_path, text)
    assert len(d["time"]) == 5
    d1 = _solve(DECKS / "elem_field.xml", "FIM_S")
    np.testing.assert_allclose(d["bodies/position"][-1], d1["bodies/position"][0], atol=1e-7)


def test_user_field_rejected(tmp_path):
    text = (DECKS / "elem_field.xml").read_text().replace(
        '<Force_Field id="1"', '<Force_Field id="1" usrsub_dll_name="libfie.so" usrsub_param_string="USER(1)"')
    p = tmp_path / "fie.xml"
    p.write_text(text)
    with pytest.raises(DeckError, match=r"Force_Field id=1.*user field"):
        run_deck(str(p))


def test_gear_on_cylindrical_joint_uses_rotation(tmp_path):
    # a gear on a CYLINDRICAL joint couples the joint's rotation (no freedom attribute exists)
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    src = (DECKS / "elem_gear_pair.xml").read_text()
    text = src.replace('type="REVOLUTE"', 'type="CYLINDRICAL"', 1)
    assert text != src
    p = tmp_path / "gear_cyl.xml"
    p.write_text(text)
    m = compile_model(load_deck(str(p)))
    assert any(r["tag"] == "Constraint_Gear" for r in m.row_info)
