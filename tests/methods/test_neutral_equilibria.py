"""Neutral equilibria: Newton converges (stability regularisation in the Jacobian only), the
neutral directions do not drift, the frame is classified ``neutral`` with the right zero count."""
import numpy as np

from poise.gen.deck import Deck, rot_x

G = 9.81
UP = rot_x(-np.pi / 2)          # marker z axis along global +Y (table normal)


def ball(kind):
    d = Deck()
    d.ground()
    d.marker(101, 1, (0, 50, 0), UP)
    d.body(2, 20, (120, 50, -30), mass=1.5, inertia=(1500, 1500, 1500))
    d.marker(21, 2, (120, 50, -30), UP)
    if kind == "PLANAR":
        d.joint(1, "PLANAR", 21, 101)
    else:
        d.jprim(1, "INPLANE", 21, 101)
    return d


def _check_ball(a, n_zero):
    assert a.converged, a.message
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], [120, 50, -30], atol=1e-9)
    np.testing.assert_allclose(a.datasets["bodies/orientation"][0, 0], np.eye(3), atol=1e-12)
    assert a.datasets["frames/stability"][0] == "neutral"
    assert a.datasets["frames/n_negative"][0] == 0
    assert a.datasets["frames/n_zero"][0] == n_zero
    n = int(a.datasets["frames/n_modes"][0])
    assert n == n_zero
    assert a.datasets["modes/body"].tolist() == [2] * n
    assert a.datasets["modes/class"].tolist() == ["neutral"] * n
    assert a.datasets["frames/imbalance"][0] < 1e-8


def test_ball_on_table_planar_joint(runner):
    a = runner.api(ball("PLANAR"))
    _check_ball(a, 3)                          # x, z translation and spin about the normal
    np.testing.assert_allclose(a.datasets["joints/force"][0, 0], [0, 1.5 * G, 0], atol=1e-9)


def test_ball_on_table_inplane_jprim(runner):
    a = runner.api(ball("INPLANE"))
    _check_ball(a, 5)                          # two translations and three rotations
    np.testing.assert_allclose(a.datasets["jprims/force"][0, 0], [0, 1.5 * G, 0], atol=1e-9)


def test_car_on_flat_road(runner):
    """Chassis (800 kg) on four wheels (20 kg): each wheel slides vertically in the chassis
    (TRANSLATIONAL along Y) on a suspension spring (50 N/mm, free length = input length 200 mm)
    and rolls on the road (INPLANE: wheel centre at height 300 mm). Closed form: each spring
    carries a quarter of the chassis weight; the road carries the chassis quarter plus the
    wheel. Horizontal translation and yaw are neutral (3 zero modes) and must not drift."""
    M, mw, k = 800.0, 20.0, 50.0
    d = Deck()
    d.ground()
    d.marker(101, 1, (0, 300, 0), UP)                        # road: wheel centres at y = 300
    d.body(2, 20, (100, 500, 40), mass=M, inertia=(3e8, 4e8, 3e8))
    corners = [(1200, 700), (1200, -700), (-1200, 700), (-1200, -700)]
    for n, (x, z) in enumerate(corners):
        b = 3 + n
        x, z = x + 100, z + 40
        d.body(b, 10 * b, (x, 300, z), mass=mw, inertia=(9e5, 9e5, 9e5))
        d.marker(10 * b + 1, b, (x, 300, z), UP)            # wheel slide I / road contact
        d.marker(200 + n, 2, (x, 300, z), UP)               # chassis slide J
        d.marker(210 + n, 2, (x, 500, z), UP)               # spring top on the chassis
        d.joint(10 + n, "TRANSLATIONAL", 10 * b + 1, 200 + n)
        d.spring(10 + n, 10 * b + 1, 210 + n, k, 200.0)
        d.jprim(20 + n, "INPLANE", 10 * b + 1, 101)
    a = runner.api(d)
    assert a.converged, a.message
    defl = M * G / 4 / k
    P = a.datasets["bodies/position"][0]
    np.testing.assert_allclose(P[0], [100, 500 - defl, 40], atol=1e-8)
    for n, (x, z) in enumerate(corners):
        np.testing.assert_allclose(P[1 + n], [x + 100, 300, z + 40], atol=1e-8)
    R = a.datasets["bodies/orientation"][0]
    np.testing.assert_allclose(R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(a.datasets["jprims/force"][0][:, 1], (M / 4 + mw) * G, rtol=1e-10)
    assert a.datasets["frames/stability"][0] == "neutral"
    assert a.datasets["frames/n_zero"][0] == 3
    assert a.datasets["frames/n_negative"][0] == 0
