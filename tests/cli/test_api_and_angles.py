"""Library API that fails loudly, result accessors, and the orientation datasets
(Euler parameters, 3-1-3 angles, continuous rotation from the input configuration).

Expected values are closed forms computed here from the decks' own numbers (read with
xml.etree), never poise output.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

import poise
from poise.core.errors import DeckError, UnknownOptionError, UsageError

from support.paths import DECKS


MULTITURN = DECKS / "pendulum_multiturn.xml"


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _from_quat(e):
    e0, e1, e2, e3 = e
    return np.array([
        [e0**2 + e1**2 - e2**2 - e3**2, 2 * (e1 * e2 - e0 * e3), 2 * (e1 * e3 + e0 * e2)],
        [2 * (e1 * e2 + e0 * e3), e0**2 - e1**2 + e2**2 - e3**2, 2 * (e2 * e3 - e0 * e1)],
        [2 * (e1 * e3 - e0 * e2), 2 * (e2 * e3 + e0 * e1), e0**2 - e1**2 - e2**2 + e3**2]])


def _multiturn_params(path=MULTITURN):
    """k [N mm/rad], reference angle [rad], m g l_cg [N mm] from the deck (N-kg-mm-s)."""
    root = ET.parse(path).getroot()
    m = root.find(".//Model")
    spring = m.find("Force_SpringDamper")
    body = [b for b in m.findall("Body_Rigid") if b.get("isground") != "TRUE"][0]
    cg = [r for r in m.findall("Reference_Marker") if r.get("id") == body.get("cg_id")][0]
    g = -float(m.find("Force_Gravity").get("grav_y"))          # mm/s^2
    mgl = float(body.get("mass")) * g * 1e-3 * float(cg.get("pos_x"))   # kg mm/s^2 = 1e-3 N
    return float(spring.get("stiffness")), float(spring.get("length")), mgl, float(cg.get("pos_x"))


# --------------------------------------------------------------------------- failing loudly
def test_unknown_keywords_raise_with_suggestion():
    with pytest.raises(UnknownOptionError) as ei:
        poise.solve(MULTITURN, metod="MKEAM", max_imbalanse=1e-3)
    e = ei.value
    assert isinstance(e, TypeError) and isinstance(e, UsageError) and e.exit_code == 2
    msg = str(e)
    assert "'metod' (did you mean 'method'?)" in msg
    assert "'max_imbalanse' (did you mean 'max_imbalance'?)" in msg
    assert "valid names: method," in msg
    with pytest.raises(UnknownOptionError, match="did you mean 'allow_user_code'"):
        poise.solve(MULTITURN, allow_usercode=True)


def test_unknown_override_names_every_entry(tmp_path):
    from poise.app.api import run_deck
    from poise.app.batch import run_batch
    for call in (lambda: run_deck(str(MULTITURN), overrides={"max_num_itr": 5}),
                 lambda: run_batch([str(MULTITURN)], str(tmp_path / "b"),
                                   overrides={"max_num_itr": 5}),
                 lambda: poise.sweep(MULTITURN, {"Force_SpringDamper[1].stiffness": [2e4]},
                                     out_dir=str(tmp_path / "s"),
                                     overrides={"max_num_itr": 5})):
        with pytest.raises(UnknownOptionError, match="did you mean 'max_num_iter'"):
            call()
    assert not (tmp_path / "b").exists() and not (tmp_path / "s").exists()
    # valid names: case-insensitive, deck aliases accepted; the value is applied
    res = poise.solve(MULTITURN, METHOD="FIM_S", max_residual=1e-9)
    assert res.analyses[0].settings["max_error"] == 1e-9


def test_edited_spec_validated_like_the_file(tmp_path):
    p = tmp_path / "deck.xml"
    text = MULTITURN.read_text()
    p.write_text(text)
    spec = poise.load_deck(p)
    spec.by_id("Force_SpringDamper")[1].attrs["stiffness"] = -5.0
    with pytest.raises(DeckError) as from_spec:
        poise.solve(spec)
    with pytest.raises(DeckError) as from_check:
        poise.check_deck(spec)
    assert 'stiffness="20000.0"' in text
    p.write_text(text.replace('stiffness="20000.0"', 'stiffness="-5.0"'))
    with pytest.raises(DeckError) as from_file:
        poise.load_deck(p)
    want = [str(x) for x in from_file.value.problems]
    assert len(want) == 1 and f"{p}:" in want[0] and "stiffness" in want[0]
    assert [str(x) for x in from_spec.value.problems] == want
    assert [str(x) for x in from_check.value.problems] == want
    assert type(from_spec.value) is type(from_file.value)


def test_unedited_spec_solves_like_the_file():
    spec = poise.load_deck(MULTITURN)
    a, b = poise.solve(spec), poise.solve(MULTITURN)
    assert a.warnings == b.warnings
    assert a.rotation_angle(2) == pytest.approx(b.rotation_angle(2), abs=1e-12)


# --------------------------------------------------------------------------- accessors
SPRING_MASS = """<?xml version="1.0"?>
<MotionSolve>
  <Model>
    <Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="METER" time_unit="SECOND"/>
    <Force_Gravity grav_x="0." grav_y="-9.81" grav_z="0."/>
    <Param_Static method="FIM_S" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Body_Rigid id="1" label="Ground" isground="TRUE" cg_id="10"/>
    <Reference_Marker id="10" body_id="1" pos_x="0." pos_y="0." pos_z="0."
        a00="1" a10="0" a20="0" a01="0" a11="0" a21="-1" a02="0" a12="1" a22="0"/>
    <Body_Rigid id="2" label="Block" cg_id="20" mass="{m}" inertia_xx="1." inertia_yy="1."
        inertia_zz="1." inertia_xy="0." inertia_yz="0." inertia_xz="0."/>
    <Reference_Marker id="20" body_id="2" pos_x="0." pos_y="-{L0}" pos_z="0."
        a00="1" a10="0" a20="0" a01="0" a11="0" a21="-1" a02="0" a12="1" a22="0"/>
    <Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="20" j_marker_id="10"/>
    <Force_SpringDamper id="1" type="TRANSLATIONAL" i_marker_id="20" j_marker_id="10"
        stiffness="{k}" damping="0." length="{L0}" preload="0."/>
    <Post_Request id="7" type="MARKER_DISPLACEMENT" i_marker_id="20" j_marker_id="10"/>
  </Model>
  <Command><Simulate analysis_type="Static"/><Stop/></Command>
</MotionSolve>
"""


def test_accessors_spring_mass(tmp_path):
    m, k, L0, g = 2.0, 100.0, 1.0, 9.81
    p = tmp_path / "spring_mass.xml"
    p.write_text(SPRING_MASS.format(m=m, k=k, L0=L0))
    res = poise.solve(p)
    assert res.status == "converged"
    y = -(L0 + m * g / k)                                   # stretched by m g / k
    assert res.position(2) == pytest.approx([0.0, y, 0.0], abs=1e-9)
    assert res.position("Block") == pytest.approx([0.0, y, 0.0], abs=1e-9)
    assert res.position(2, frame=None).shape == (1, 3)
    assert res.request(7, "DY") == pytest.approx(y, abs=1e-9)
    assert res.request(7, 1) == pytest.approx(-y, abs=1e-9)          # DM
    assert res.request(7, "dm", frame=None) == pytest.approx([-y], abs=1e-9)
    assert res.rotation_from_input(2) == pytest.approx([0, 0, 0], abs=1e-12)
    with pytest.raises(KeyError, match="ids: 2"):
        res.position(5)
    with pytest.raises(KeyError, match="'Block'"):
        res.position("Blok")
    with pytest.raises(KeyError, match="request channel"):
        res.request(7, "DQ")


def test_accessors_pendulum_multiturn_and_file(tmp_path):
    k, ref, mgl, lcg = _multiturn_params()
    th = brentq(lambda t: -k * (t - ref) - mgl * math.cos(t), ref - 10.0, ref + 10.0,
                xtol=1e-15)
    res = poise.solve(MULTITURN)
    assert res.status == "converged"
    assert 19.72 < th < 19.73
    assert res.rotation_angle("Pendulum") == pytest.approx(th, abs=1e-7)
    assert res.rotation_from_input(2) == pytest.approx([0, 0, th], abs=1e-7)
    assert res.orientation(2) == pytest.approx(_rz(th), abs=1e-8)
    assert res.position(2) == pytest.approx([lcg * math.cos(th), lcg * math.sin(th), 0], abs=1e-5)
    e = np.array([math.cos(th / 2), 0, 0, math.sin(th / 2)])
    e = e if e[0] >= 0 else -e
    assert res.euler_parameters(2) == pytest.approx(e, abs=1e-9)
    psi = math.atan2(math.sin(th), math.cos(th))        # tilt 0: gimbal lock, phi = 0
    assert res.euler_313(2) == pytest.approx([psi, 0.0, 0.0], abs=1e-9)
    F, T = res.reaction(1)
    assert F == pytest.approx([0.0, mgl / lcg, 0.0], abs=1e-6)     # the hinge carries m g
    assert T == pytest.approx([0.0, 0.0, 0.0], abs=1e-6)
    from poise.results.hdf5 import write_results
    write_results(res, str(tmp_path / "r.h5"))
    back = poise.read_results(str(tmp_path / "r.h5"))
    assert back.rotation_angle("Pendulum") == pytest.approx(th, abs=1e-7)
    assert back.analyses[0].euler_313(2) == pytest.approx([psi, 0.0, 0.0], abs=1e-9)


def test_angles_derived_when_a_file_has_no_euler_datasets():
    """Results written before the Euler datasets existed: derived from bodies/orientation."""
    res = poise.solve(MULTITURN)
    a = res.analyses[-1]
    e, e313 = a.euler_parameters(2), a.euler_313(2)
    for key in ("bodies/euler_parameters", "bodies/euler_313"):
        a.datasets.pop(key, None)
    assert a.euler_parameters(2) == pytest.approx(e, abs=1e-12)
    assert a.euler_313(2) == pytest.approx(e313, abs=1e-12)


# --------------------------------------------------------------------------- angle maths
def _rotations():
    R = list(Rotation.random(500, random_state=11).as_matrix())
    for psi, phi in ((0.3, 0.7), (-2.9, 3.0), (math.pi, 0.0)):
        R += [_rz(psi) @ _rx(0.0) @ _rz(phi), _rz(psi) @ _rx(math.pi) @ _rz(phi),
              _rz(psi) @ _rx(1e-9) @ _rz(phi), _rz(psi) @ _rx(math.pi - 1e-9) @ _rz(phi)]
    R += [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]),
          np.diag([-1.0, -1.0, 1.0])]                       # 180 deg: e0 = 0
    return np.array(R)


def test_euler_parameters_and_313_reconstruct():
    from poise.elements.rotation import euler_313, euler_parameters
    R = _rotations()
    q = euler_parameters(R)
    a = euler_313(R)
    assert np.all(q[:, 0] >= 0) and np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    assert np.all((a[:, 1] >= 0) & (a[:, 1] <= math.pi))
    assert np.all(np.abs(a[:, [0, 2]]) <= math.pi)
    for Ri, qi, ai in zip(R, q, a):
        assert np.abs(_from_quat(qi) - Ri).max() < 1e-12
        assert np.abs(_rz(ai[0]) @ _rx(ai[1]) @ _rz(ai[2]) - Ri).max() < 1e-12
    # gimbal lock: deterministic, phi = 0 and psi carries the turn
    sing = euler_313(np.array([_rz(0.3) @ _rz(0.7), _rz(0.3) @ _rx(math.pi) @ _rz(0.7)]))
    assert sing[0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-14)
    assert sing[1] == pytest.approx([-0.4, math.pi, 0.0], abs=1e-14)
    assert euler_parameters(np.diag([-1.0, 1.0, -1.0]))[None][0] == pytest.approx([0, 0, 1, 0])


def test_stored_orientation_datasets_reconstruct():
    res = poise.solve(DECKS / "chain_10_spherical.xml")
    a = res.analyses[0]
    R = a.datasets["bodies/orientation"]
    q = a.datasets["bodies/euler_parameters"]
    e = a.datasets["bodies/euler_313"]
    v = a.datasets["bodies/rotation_from_input"]
    assert q.shape == R.shape[:2] + (4,) and e.shape == v.shape == R.shape[:2] + (3,)
    for f in range(R.shape[0]):
        for b in range(R.shape[1]):
            assert np.abs(_from_quat(q[f, b]) - R[f, b]).max() < 1e-12
            assert np.abs(_rz(e[f, b, 0]) @ _rx(e[f, b, 1]) @ _rz(e[f, b, 2]) - R[f, b]).max() < 1e-12


# --------------------------------------------------------------------------- continuous angle
TORQUE = ('    <Force_Scalar_TwoBody id="5" type="TORQUE" i_marker_id="201" j_marker_id="101" '
          'val_expression="{c}*TIME"/>\n  </Model>')


def test_quasistatic_multiturn_angle_grows_continuously(tmp_path):
    """The multi-turn pendulum with a free-length-0 torsion spring and a torque ramp
    T = c t (c = 4 pi k): theta(t) solves -k theta - m g l cos(theta) + c t = 0 (unique: k > m g l)
    and passes 2 pi half-way."""
    k, _, mgl, _ = _multiturn_params()
    c = 4 * math.pi * k
    text = MULTITURN.read_text().replace('length="19.84955592153876"', 'length="0."')
    text = text.replace("  </Model>", TORQUE.format(c=repr(c)), 1)
    text = text.replace('<Simulate analysis_type="Static"/>',
                        '<Simulate analysis_type="Static" end_time="1.0" print_interval="0.05"/>')
    p = tmp_path / "multiturn_qs.xml"
    p.write_text(text)
    res = poise.solve(p)
    assert res.status == "converged"
    a = res.analyses[0]
    t = a.datasets["time"]
    assert len(t) == 21
    want = [brentq(lambda x, ti=ti: -k * x - mgl * math.cos(x) + c * ti, -10.0, 30.0, xtol=1e-15)
            for ti in t]
    got = res.rotation_angle(2, frame=None)
    assert got == pytest.approx(want, abs=1e-6)
    assert got[-1] > 2 * math.pi + 5.0 and np.all(np.diff(got) > 0) and np.all(np.diff(got) < 1.0)
    v = res.rotation_from_input(2, frame=None)
    assert np.abs(v[:, :2]).max() < 1e-9
