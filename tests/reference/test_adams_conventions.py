"""Conventions checked against Adams' own results (docs/adm.md, "Checked against Adams"), held
here by datasets written for these tests with closed-form answers.

* RACKPIN as Adams' rack-and-pinion validation model sets it up: the J marker at the pinion's
  centre (not PD/2 away), the pinion axis z_I = +X, x_I along the rack's travel z_J = -Z, the rack
  on a vertical slide under gravity. Adams' result table shows the falling rack turning the
  pinion positively about z_I, the joint pushing the pinion down and driving it about +X; here a
  rotational spring k holds the pinion: k theta = m g r, the rack at z = -r theta, the joint's
  load on the pinion (0, 0, -m g) and torque (m g r, 0, 0).
* GCON reactions: Adams reports a GCON's reaction on the part of its I marker, also when that
  marker is on ground (the distance constraints of the same validation set): a point held at
  L from a ground anchor by DM(I, J) - L, pulled sideways by F under gravity, loads the ground
  marker with (F, -m g, 0), and the point with the opposite.
"""
from __future__ import annotations

import numpy as np

from poise.app.runner import run_deck

G, M, R, K = 9.80665, 1.0, 0.05, 10.0

RACKPIN = """rack and pinion set up as Adams' validation model: J at the pinion centre
UNITS/FORCE = NEWTON, MASS = KILOGRAM, LENGTH = METER, TIME = SECOND
ACCGRAV/KGRAV = -9.80665
EQUILIBRIUM/ERROR = 1E-12, IMBALANCE = 1E-10
!MS#, FIM_S
PART/1, GROUND
MARKER/11, PART = 1, REULER = 90D, 90D, -90D
MARKER/12, PART = 1, QP = 0, -0.1, 0, REULER = 0D, 180D, 0D
! the pinion: z along +X, x along -Z
PART/2, MASS = 2, CM = 21, IP = 0.04, 0.1, 0.1
MARKER/21, PART = 2, REULER = 90D, 90D, -90D
MARKER/22, PART = 2, REULER = 90D, 90D, -90D
! the rack: slides along Z, its rack marker at the pinion centre with z along -Z
PART/3, MASS = 1, CM = 31, IP = 0.1, 0.1, 0.04
MARKER/31, PART = 3, QP = 0, 0.1, 0, REULER = 0D, 180D, 0D
MARKER/32, PART = 3, QP = 0, -0.1, 0, REULER = 0D, 180D, 0D
MARKER/33, PART = 3, REULER = 0D, 180D, 0D
JOINT/1, REVOLUTE, I = 22, J = 11
JOINT/2, TRANSLATIONAL, I = 32, J = 12
JOINT/3, RACKPIN, I = 22, J = 33, PD = 0.1
SPRINGDAMPER/1, ROTATION, I = 22, J = 11, KT = 10
END
"""

GCON = """a point held from a ground anchor by a GCON whose I marker is {where}
ACCGRAV/JGRAV = -9.81
EQUILIBRIUM/ERROR = 1E-12, IMBALANCE = 1E-10
!MS#, FIM_S
PART/1, GROUND
MARKER/10, PART = 1, QP = 0, 1, 0
MARKER/11, PART = 1, FLOATING
MARKER/12, PART = 1
POINT_MASS/2, MASS = 2, CM = 20
MARKER/20, POINT_MASS = 2, QP = 0.3, 0.6, 0
GCON/1, I = {i}, FUNCTION = DM(20, 10) - 0.5
VFORCE/1, I = 20, JFLOAT = 11, RM = 12, FX = 3\\FY = 0\\FZ = 0
END
"""


def _rot_x(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def test_rackpin_in_adams_set_up_turns_the_pinion_the_way_adams_does(tmp_path):
    adm = tmp_path / "rackpin.adm"
    adm.write_text(RACKPIN)
    a = run_deck(str(adm), quiet=True).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    theta = M * G * R / K                   # positive about +X: the rack's weight drives it
    ids = list(d["bodies/id"])
    pinion, rack = ids.index(2), ids.index(3)
    # the pinion's CM marker: x along -Z, y along +Y, z along +X, then turned by theta about X
    cm0 = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    np.testing.assert_allclose(d["bodies/orientation"][-1, pinion], _rot_x(theta) @ cm0,
                               atol=1e-10)
    np.testing.assert_allclose(d["bodies/position"][-1, rack], [0.0, 0.1, -R * theta],
                               atol=1e-12)
    j = list(d["joints/id"]).index(3)
    np.testing.assert_allclose(d["joints/force"][-1, j], [0.0, 0.0, -M * G], atol=1e-9)
    np.testing.assert_allclose(d["joints/torque"][-1, j], [M * G * R, 0.0, 0.0], atol=1e-10)


def _gcon(tmp_path, i):
    adm = tmp_path / f"gcon_{i}.adm"
    adm.write_text(GCON.format(i=i, where="on ground" if i == 10 else "on the point"))
    a = run_deck(str(adm), quiet=True).analyses[0]
    assert a.converged, a.message
    return a.datasets


def test_gcon_reaction_on_a_ground_i_marker_is_what_the_ground_carries(tmp_path):
    F, W = 3.0, 2.0 * 9.81
    u = np.array([F, -W, 0.0]) / np.hypot(F, W)          # the rod along the total load
    for i, sign in ((10, 1.0), (20, -1.0)):
        d = _gcon(tmp_path, i)
        np.testing.assert_allclose(d["bodies/position"][-1, 0], [0, 1, 0] + 0.5 * u, atol=1e-10)
        np.testing.assert_allclose(d["gcons/force"][-1, 0], sign * np.array([F, -W, 0.0]),
                                   atol=1e-9)
        np.testing.assert_allclose(d["gcons/torque"][-1, 0], 0.0, atol=1e-9)
