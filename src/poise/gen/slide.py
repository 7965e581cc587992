"""Bodies on slides under gravity: the mechanisms of the "no equilibrium" tests and the
time-to-fail table of ``make bench``.

:func:`slide`: a 1 kg body on a joint whose axis lies in the XY plane at ``angle_deg`` from X,
gravity -Y: ``m g sin(angle)`` along the slide, nothing holding it unless the caller adds a
spring. :func:`rack_and_pinion`: a rack on a slide turning a pinion (RACK_PINION joint), held
by a torsion spring on the pinion or by nothing.
"""
from __future__ import annotations

import numpy as np

from poise.gen.deck import Deck, rot_y, rot_z

PITCH_DIAMETER = 80.0       # mm, of the rack and pinion


def slide(angle_deg=45.0, joint="TRANSLATIONAL", units="mm", extra=None, pendulum=False,
          arm=0.0) -> Deck:
    """The body's ground marker 101 lies 300 mm down the slide (the model size), marker 102 at
    the origin (for a spring); ``pendulum``: a 0.5 kg bob hinged to the body 150 mm below;
    ``arm``: the body's mass centre that far off the axis along Z (horizontal: on a
    CYLINDRICAL joint gravity turns it about the axis as well); ``extra(deck)`` adds more."""
    d = Deck(units=units)
    d.ground()
    R = rot_z(np.radians(angle_deg)) @ rot_y(np.pi / 2)
    d.marker(101, 1, -300.0 * R[:, 2], R)
    d.marker(102, 1, (0, 0, 0))
    d.body(2, 20, (0, 0, arm), mass=1.0, inertia=(100, 100, 100))
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


def rack_and_pinion(angle_deg=30.0, spring=0.0) -> Deck:
    """A 0.5 kg pinion turning about Z at the origin (REVOLUTE) meshing with a 1 kg rack that
    slides along (cos a, sin a, 0) (TRANSLATIONAL), pitch diameter :data:`PITCH_DIAMETER`:
    the rack's weight pushes ``m g sin a`` down its slide; ``spring``: a torsion spring on
    the pinion [N mm/rad], which then holds it at ``k |theta| = m g sin a PD / 2``."""
    d = Deck()
    d.ground()
    a = np.radians(angle_deg)
    R = rot_z(a) @ rot_y(np.pi / 2)                       # z along the rack's travel
    at = PITCH_DIAMETER / 2 * np.array([np.sin(a), -np.cos(a), 0.0])   # its pitch line
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, at, R)
    d.body(2, 20, (0, 0, 0), mass=0.5, inertia=(200, 200, 400))
    d.marker(21, 2, (0, 0, 0))
    d.body(3, 30, at, mass=1.0, inertia=(100, 100, 100))
    d.marker(31, 3, at, R)
    d.joint(1, "REVOLUTE", 21, 101)
    d.joint(2, "TRANSLATIONAL", 31, 102)
    d.add("Constraint_Joint", id=3, type="RACK_PINION", i_marker_id=21, j_marker_id=31,
          pitch_diameter=d.L(PITCH_DIAMETER))
    if spring:
        d.spring(1, 21, 101, spring, 0.0, rotational=True)
    return d
