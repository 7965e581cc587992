"""Scale-aware tolerances and stiff/soft mixes."""
import numpy as np

from poise.gen.deck import Deck, rot_x, rot_y, rot_z
from support.builders import stiff_soft_deck

G = 9.81


def arm3d(units):
    """3-D double pendulum: link 1 on a REVOLUTE about a tilted axis with a ROTATIONAL spring,
    link 2 on a SPHERICAL joint at its tip with a rotational Force_Bushing, gravity and a tip
    force with components on all three axes. Written in mm or m (forces in N)."""
    d = Deck(units=units, static=dict(max_imbalance=1e-6, max_error=1e-8))
    d.ground()
    A = rot_y(0.3)                                 # hinge axis z tilted towards +X
    d.marker(101, 1, (0, 0, 0), A)
    R1 = rot_z(-0.4)
    d.body(2, 20, R1 @ [150, 0, 0], R1, mass=1.5, inertia=(20, 11250, 11250))
    d.marker(21, 2, (0, 0, 0), A)
    tip = R1 @ [300, 0, 0]
    d.marker(22, 2, tip, R1)
    R2 = rot_x(0.3) @ rot_z(-1.0)
    d.body(3, 30, tip + R2 @ [100, 0, 0], R2, mass=1.0, inertia=(10, 3333, 3333))
    d.marker(31, 3, tip, R1)
    d.marker(32, 3, tip + R2 @ [200, 0, 0], R2)
    d.joint(1, "REVOLUTE", 21, 101)
    d.spring(1, 21, 101, 3e4, 0.2, rotational=True)
    d.joint(2, "SPHERICAL", 31, 22)
    d.bushing(1, 31, 22, (0, 0, 0), (2e4, 3e4, 1e4))
    d.force(1, 32, (10.0, -20.0, 5.0))
    return d


def test_same_3d_deck_in_m_and_mm(runner):
    a_mm = runner.api(arm3d("mm"), "mm.xml")
    a_m = runner.api(arm3d("m"), "m.xml")
    assert a_mm.converged and a_m.converged, (a_mm.message, a_m.message)
    it_mm = a_mm.datasets["frames/iterations"][0]
    assert it_mm == a_m.datasets["frames/iterations"][0]
    assert it_mm >= 3                                    # a real solve, not a trivial one
    np.testing.assert_allclose(a_mm.datasets["bodies/position"] * 1e-3,
                               a_m.datasets["bodies/position"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(a_mm.datasets["bodies/orientation"],
                               a_m.datasets["bodies/orientation"], rtol=0, atol=1e-9)
    # it moved: link 2 is far from its input orientation
    assert np.abs(a_m.datasets["bodies/orientation"][0, 1] - rot_x(0.3) @ rot_z(-1.0)).max() > 0.05
    np.testing.assert_allclose(a_mm.datasets["joints/force"], a_m.datasets["joints/force"],
                               rtol=0, atol=1e-7)
    np.testing.assert_allclose(a_mm.datasets["joints/torque"] * 1e-3,
                               a_m.datasets["joints/torque"], rtol=0, atol=1e-9)
    # the same iteration history, step by step (scaled residuals and updates)
    np.testing.assert_allclose(a_mm.datasets["iterations/step_length"],
                               a_m.datasets["iterations/step_length"])
    for a in (a_mm, a_m):
        assert a.datasets["frames/stability"][0] == "stable"


def test_stiff_soft_mix(runner):
    """Masses of 1e-3 kg on springs of 1e9 N/m and 1 N/m in series, and a rigid body on a
    1e9 N/m bushing, in N-kg-m-s. The springs start at their free lengths (no tension, hence no
    lateral stiffness: plain Newton meets a singular Jacobian and the fallback's stability
    term takes over). Closed form: each spring carries the weight below it."""
    m, k1, k2, kb = 1e-3, 1e9, 1.0, 1e9
    a = runner.api(stiff_soft_deck(m, k1, k2, kb))
    assert a.converged, a.message
    d1, d2 = 2 * m * G / k1, m * G / k2
    ref = np.array([[0, -0.01 - d1, 0], [0, -0.51 - d1 - d2, 0], [0.3, -m * G / kb, 0]])
    P = a.datasets["bodies/position"][0]
    L = 0.51
    assert np.abs(P - ref).max() < 1e-9 * L
    # the soft spring's stretch (9.81 mm) and force: bounded by max_imbalance = 1e-8 N against
    # a weight of 9.81e-3 N (1e-6 relative); measured 1e-8
    assert abs((P[0, 1] - P[1, 1]) - (0.5 + d2)) < 3e-8 * d2
    F = a.datasets["forces/force"][0]
    assert abs(np.linalg.norm(F[1]) - m * G) < 3e-8 * m * G
    assert abs(np.linalg.norm(F[0]) - 2 * m * G) < 1e-5 * m * G    # 1e9 N/m x round-off
    ev = set(a.datasets["iterations/event"])
    assert any(e.startswith("fallback: stability") for e in ev)
    # stiff and soft directions alike are positive (the classification is per direction)
    assert a.datasets["frames/stability"][0] == "stable"
