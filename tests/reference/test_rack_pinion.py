"""RACK_PINION joint against a closed form (its FD-Jacobian case comes from the registry).

``decks/elem_rack_pinion.xml``: a pinion on a REVOLUTE about Z, a rack on a TRANSLATIONAL along X
at y = -r, the RACK_PINION joint (I on the pinion, J on the rack, PD = 2r), a torque T on the
pinion and a spring k holding the rack. The rack travels r per radian of pinion rotation
(x = r theta, PD > 0), so virtual work gives T = k r^2 theta: theta = T / (k r^2), x = r theta.
The joint's reaction on the pinion, reduced to its centre: force (-T/r, 0, 0), torque (0, 0, -T).
The same set-up turned by an arbitrary rotation gives the turned answer; a negative PD reverses the
rack (x = -r theta); a large torque winds the pinion through several turns (turns counted).
"""
import numpy as np
import pytest
from lxml import etree

from poise.app.api import run_deck

from support.paths import DECKS

K, R = 2000.0, 0.04


def _deck(tmp_path, T=0.8, pd=0.08, Q=None):
    root = etree.parse(str(DECKS / "elem_rack_pinion.xml")).getroot()
    for e in root.iter("Reference_Marker"):
        if Q is not None:
            p = Q @ np.array([float(e.get(f"pos_{c}")) for c in "xyz"])
            A = Q @ np.array([[float(e.get(f"a{i}{j}")) for j in range(3)] for i in range(3)])
            for c, v in zip("xyz", p):
                e.set(f"pos_{c}", repr(float(v)))
            for i in range(3):
                for j in range(3):
                    e.set(f"a{i}{j}", repr(float(A[i, j])))
    for e in root.iter("Force_Scalar_TwoBody"):
        e.set("val", repr(T))
    for e in root.iter("Constraint_Joint"):
        if e.get("type") == "RACK_PINION":
            e.set("pitch_diameter", repr(pd))
    model = root.find("Model")
    etree.SubElement(model, "Post_Request", id="1", type="EXPRESSION",
                     expr1="JOINT(3,0,2,0)", expr2="JOINT(3,0,8,0)")
    path = tmp_path / "rp.xml"
    path.write_bytes(etree.tostring(root))
    return path


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _check(tmp_path, T, pd, Q=None):
    Q = np.eye(3) if Q is None else Q
    a = run_deck(str(_deck(tmp_path, T, pd, Q))).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    theta = T / (K * R * R)                       # the pinion's rotation about its axis
    x = np.sign(pd) * R * theta                   # the rack's travel along +X
    np.testing.assert_allclose(d["bodies/position"][-1, 1], Q @ [x, -R, 0.0], atol=1e-9)
    np.testing.assert_allclose(d["bodies/orientation"][-1, 0], Q @ _rz(theta), atol=1e-9)
    assert list(d["joints/id"]) == [1, 2, 3]
    np.testing.assert_allclose(d["joints/force"][-1, 2], Q @ [-np.sign(pd) * T / R, 0, 0],
                               atol=1e-7)
    np.testing.assert_allclose(d["joints/torque"][-1, 2], Q @ [0, 0, -T], atol=1e-8)
    return d


def test_rack_pinion_deck_closed_form(tmp_path):
    d = _check(tmp_path, 0.8, 0.08)
    np.testing.assert_allclose(d["bodies/position"][-1, 1], [0.01, -0.04, 0.0], atol=1e-12)
    # JOINT(id, ...) reads the joint's reaction: Fx and Tz on the pinion
    np.testing.assert_allclose(d["requests/values"][-1, 0, :2], [-20.0, -0.8], atol=1e-8)


def test_rack_pinion_negative_pitch_diameter_reverses_the_rack(tmp_path):
    _check(tmp_path, 0.8, -0.08)


def test_rack_pinion_counts_turns(tmp_path):
    """theta = 10 rad: the pinion turns 1.6 times, the rack travels 0.4 m."""
    _check(tmp_path, 32.0, 0.08)


def test_rack_pinion_turned_set_up(tmp_path):
    rng = np.random.default_rng(7)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    _check(tmp_path, 0.8, 0.08, Q)


@pytest.mark.parametrize("bad,msg", [("0.0", "pitch_diameter 0"),
                                     (None, "needs 'pitch_diameter'")])
def test_rack_pinion_bad_pitch_diameter_is_located(tmp_path, bad, msg):
    from poise.core.errors import DeckError
    root = etree.parse(str(DECKS / "elem_rack_pinion.xml")).getroot()
    j = next(e for e in root.iter("Constraint_Joint") if e.get("type") == "RACK_PINION")
    if bad is None:
        del j.attrib["pitch_diameter"]
    else:
        j.set("pitch_diameter", bad)
    path = tmp_path / "bad.xml"
    path.write_bytes(etree.tostring(root))
    with pytest.raises(DeckError) as e:
        run_deck(str(path))
    line = 1 + path.read_text().split("RACK_PINION")[0].count("\n")
    assert f"bad.xml:{line}: <Constraint_Joint id=3>" in str(e.value)
    assert msg in str(e.value)


def test_rack_pinion_parallel_axes_is_located(tmp_path):
    """A rack along the pinion axis cannot be driven by it: a located error."""
    from poise.core.errors import DeckError
    root = etree.parse(str(DECKS / "elem_rack_pinion.xml")).getroot()
    m = next(e for e in root.iter("Reference_Marker") if e.get("id") == "22")
    for i in range(3):               # I axes x = Z... so that z_I is along X = z_J
        for j in range(3):
            m.set(f"a{i}{j}", "1" if (i, j) in ((2, 0), (1, 1), (0, 2)) else "0")
    m.set("a11", "-1")
    path = tmp_path / "par.xml"
    path.write_bytes(etree.tostring(root))
    with pytest.raises(DeckError) as e:
        run_deck(str(path))
    assert "parallel to the pinion axis" in str(e.value)


@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_rack_pinion_quasi_static_torque_ramp(tmp_path, method):
    """T = 0.8 TIME over t in [0, 1]: theta(t) = T / (k r^2) along the whole run (FIM_D carries
    the rack-and-pinion angle through its chart)."""
    root = etree.parse(str(DECKS / "elem_rack_pinion.xml")).getroot()
    for e in root.iter("Force_Scalar_TwoBody"):
        del e.attrib["val"]
        e.set("val_expression", "0.8*TIME")
    root.find("Model/Param_Static").set("method", method)
    root.find("Command/Simulate").set("end_time", "1.0")
    root.find("Command/Simulate").set("num_steps", "8")
    path = tmp_path / "ramp.xml"
    path.write_bytes(etree.tostring(root))
    a = run_deck(str(path)).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    t = np.asarray(d["time"])
    theta = 0.8 * t / (K * R * R)
    np.testing.assert_allclose(d["bodies/position"][:, 1, 0], R * theta, atol=1e-8)
    R0 = d["bodies/orientation"][:, 0]
    np.testing.assert_allclose(np.arctan2(R0[:, 1, 0], R0[:, 0, 0]), theta, atol=1e-7)
