"""Redundant constraints of several kinds: the physics answer and the ``redundant/…`` contents.

References are closed forms / 1-DOF root finds written here, independent of poise.
"""
import numpy as np
from scipy.optimize import brentq

from poise.gen.deck import Deck, rot_z

G = 9.81          # N/kg (gravity 9810 mm/s^2 in N-kg-mm-s)


def door(offset=0.0, k=1e4, m=2.0, w=400.0):
    """A door hinged on global Z by two coaxial 3-D REVOLUTEs at z = -100 and z = +100.

    10 equations, 6 coordinates, 1 DOF -> the 5 equations of the second hinge are redundant.
    ``offset`` moves the second hinge's ground marker along X: the joints then contradict each
    other (no configuration satisfies both)."""
    d = Deck()
    d.ground()
    d.marker(101, 1, (0, 0, -100))
    d.marker(102, 1, (offset, 0, 100))
    d.body(2, 20, (w / 2, 0, 0), mass=m, inertia=(100, m * w * w / 12, m * w * w / 12))
    d.marker(21, 2, (0, 0, -100))
    d.marker(22, 2, (0, 0, 100))
    d.joint(1, "REVOLUTE", 21, 101)
    line2 = d.joint(2, "REVOLUTE", 22, 102)
    d.spring(1, 21, 101, k, 0.0, rotational=True)
    return d, line2


def test_door_two_coaxial_revolutes(runner):
    k, m, w = 1e4, 2.0, 400.0
    d, line2 = door(k=k, m=m, w=w)
    a = runner.api(d)
    assert a.converged, a.message
    th = brentq(lambda t: k * t + m * G * (w / 2) * np.cos(t), -np.pi / 2, 0.0)
    p = a.datasets["bodies/position"][0, 0]
    np.testing.assert_allclose(p, [w / 2 * np.cos(th), w / 2 * np.sin(th), 0.0], atol=1e-7 * w)
    # the second hinge's 5 equations are the removed ones, located at its deck line
    assert list(a.datasets["redundant/id"]) == [2] * 5
    assert set(a.datasets["redundant/tag"]) == {"Constraint_Joint"}
    assert set(a.datasets["redundant/line"]) == {line2}
    assert a.attrs["reactions_unique"] is False
    assert not a.datasets["joints/unique"].any()
    # minimum-norm reactions: mirror-symmetric split of the weight (z -> -z symmetry)
    F = a.datasets["joints/force"][0]
    np.testing.assert_allclose(F.sum(0), [0, m * G, 0], atol=1e-8)
    np.testing.assert_allclose(F[0], F[1], atol=1e-8)
    assert a.datasets["frames/stability"][0] == "stable"


def _fails_as_inconsistent(runner, d, line2, name):
    """``poise solve`` of ``d``: a failure naming the second hinge, never "converged"."""
    r, js, out = runner.cli(d, name)
    assert r.returncode == 1, r.stderr
    a = js["analyses"][0]
    assert a["status"] == "failed"
    assert f"{name}:{line2}: <Constraint_Joint id=2>" in a["message"]
    assert "violated by 1" in a["message"]
    from support.runner import h5
    with h5(out) as f:
        assert f["analysis_000/frames/status"].asstr()[0] == "inconsistent_constraints"
        assert f["analysis_000/frames/stability"].asstr()[0] == "unknown"
        assert not f["analysis_000/frames/converged"][0]


def test_door_contradicting_hinges_is_a_failure_not_a_wrong_answer(runner):
    # second hinge axis 1 mm off the first: the redundant equations cannot be satisfied; before
    # the fix this reported "converged" with the second hinge violated by 1 mm
    d, line2 = door(offset=1.0)
    _fails_as_inconsistent(runner, d, line2, "offset_door.xml")


def test_contradicting_hinges_in_a_sparse_model_fail_the_same_way(runner):
    # the offset door beside 55 bodies welded to ground: a KKT system above DENSE_MAX (sparse
    # assembly), where the check of the removed rows evaluates the constraint values alone
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    from poise.model.model import DENSE_MAX
    d, line2 = door(offset=1.0)
    for b in range(55):
        y = 1000.0 + 10.0 * b
        d.marker(1000 + b, 1, (0, y, 0))
        d.body(100 + b, 2000 + b, (0, y, 0), mass=1.0)
        d.joint(100 + b, "FIXED", 2000 + b, 1000 + b)
    _fails_as_inconsistent(runner, d, line2, "offset_door_large.xml")
    model = compile_model(load_deck(str(runner.tmp / "offset_door_large.xml")))
    assert model.N > DENSE_MAX and not model.assembler.dense


def parallelogram(phi_in, k, m=(1.0, 2.0, 1.5), l=150.0, w=300.0):
    """Planar parallelogram from four 3-D REVOLUTEs (about Z): cranks A-B and D-C of length l,
    coupler B-C of length w; ROTATIONAL spring on the crank pivot A (free at the input angle)."""
    d = Deck()
    d.ground()
    c, s = np.cos(phi_in), np.sin(phi_in)
    B = np.array([l * c, l * s, 0.0])
    D = np.array([w, 0.0, 0.0])
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, D)
    R = rot_z(phi_in)
    d.body(2, 20, B / 2, R, mass=m[0], inertia=(1, m[0] * l * l / 12, m[0] * l * l / 12))
    d.marker(21, 2, (0, 0, 0))
    d.marker(22, 2, B)
    d.body(3, 30, B + [w / 2, 0, 0], mass=m[1], inertia=(1, m[1] * w * w / 12, m[1] * w * w / 12))
    d.marker(31, 3, B)
    d.marker(32, 3, B + D)
    d.body(4, 40, D + B / 2, R, mass=m[2], inertia=(1, m[2] * l * l / 12, m[2] * l * l / 12))
    d.marker(41, 4, D + B)
    d.marker(42, 4, D)
    lines = [d.joint(1, "REVOLUTE", 21, 101), d.joint(2, "REVOLUTE", 31, 22),
             d.joint(3, "REVOLUTE", 41, 32), d.joint(4, "REVOLUTE", 42, 102)]
    d.spring(1, 21, 101, k, 0.0, rotational=True)
    return d, lines


def test_parallelogram_planar_from_3d_revolutes(runner):
    m, l, w, k = (1.0, 2.0, 1.5), 150.0, 300.0, 2e4
    phi_in = 0.6
    d, lines = parallelogram(phi_in, k, m, l, w)
    a = runner.api(d)
    assert a.converged, a.message
    wgt = G * l * (m[0] / 2 + m[1] + m[2] / 2)
    phi = brentq(lambda p: k * (p - phi_in) + wgt * np.cos(p), -0.5, phi_in)
    B = l * np.array([np.cos(phi), np.sin(phi), 0.0])
    P = a.datasets["bodies/position"][0]
    np.testing.assert_allclose(P[0], B / 2, atol=1e-7 * w)
    np.testing.assert_allclose(P[1], B + [w / 2, 0, 0], atol=1e-7 * w)
    np.testing.assert_allclose(P[2], [w, 0, 0] + B / 2, atol=1e-7 * w)
    # the coupler translates without rotating
    np.testing.assert_allclose(a.datasets["bodies/orientation"][0, 1], np.eye(3), atol=1e-9)
    # 20 equations, 18 coordinates, 1 DOF -> 3 out-of-plane equations removed, all from the last
    # joint that closes the loop (deck order decides which copy is removed)
    assert len(a.datasets["redundant/id"]) == 3
    assert set(a.datasets["redundant/line"]) <= set(lines)
    assert a.attrs["reactions_unique"] is False
    # in-plane reactions are still statically determinate for the whole linkage: the ground
    # pivots carry the weight
    F = a.datasets["joints/force"][0]
    ground_y = F[0, 1] + F[3, 1]
    assert abs(ground_y - G * sum(m)) < 1e-6
    assert a.datasets["frames/stability"][0] == "stable"


def test_beam_between_two_fixed_joint_sets(runner):
    """A beam clamped at both ends: FIXED at the left, SPHERICAL + ORIENTATION jprim at the
    right (a second FIXED-like set): 12 equations for 6 coordinates, the right set's 6 removed."""
    m, Lb = 3.0, 600.0
    d = Deck()
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, (Lb, 0, 0))
    d.body(2, 20, (Lb / 2, 0, 0), mass=m, inertia=(10, m * Lb * Lb / 12, m * Lb * Lb / 12))
    d.marker(21, 2, (0, 0, 0))
    d.marker(22, 2, (Lb, 0, 0))
    d.joint(1, "FIXED", 21, 101)
    l2 = d.joint(2, "SPHERICAL", 22, 102)
    l3 = d.jprim(3, "ORIENTATION", 22, 102)
    a = runner.api(d)
    assert a.converged, a.message
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], [Lb / 2, 0, 0], atol=1e-9)
    np.testing.assert_allclose(a.datasets["bodies/orientation"][0, 0], np.eye(3), atol=1e-12)
    assert len(a.datasets["redundant/id"]) == 6
    assert set(a.datasets["redundant/line"]) == {l2, l3}
    # total support = weight; moment balance about the left end
    Fj = a.datasets["joints/force"][0]
    Fp = a.datasets["jprims/force"][0]
    Tj = a.datasets["joints/torque"][0]
    Tp = a.datasets["jprims/torque"][0]
    Ftot = Fj.sum(0) + Fp.sum(0)
    np.testing.assert_allclose(Ftot, [0, m * G, 0], atol=1e-8)
    Mz = Tj[:, 2].sum() + Tp[:, 2].sum() + Lb * (Fj[1, 1] + Fp[0, 1]) - (Lb / 2) * m * G
    assert abs(Mz) < 1e-6 * m * G * Lb
    # no degree of freedom left: nothing to be unstable
    assert a.datasets["frames/stability"][0] == "stable"
