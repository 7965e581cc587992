"""A hinged bar under gravity and a constant torque: the simplest load a model cannot hold.

A 2 kg bar, its CG 200 mm from a REVOLUTE hinge about global Z at the origin, started
horizontal, gravity -Y, and a constant torque ``frac x m g l`` about the hinge
(``Force_Vector_OneBody`` TORQUEONLY): equilibria where ``cos(theta) = frac`` for ``frac <= 1``,
none above (the torque exceeds what gravity can hold at any angle). Used by the fail-fast tests
and the time-to-fail table of ``make bench``.
"""
from __future__ import annotations

from poise.gen.deck import Deck

G = 9.81            # m/s^2: the weight of the 2 kg bar is 2 G newtons


def torque_pendulum(frac: float, units: str = "mm") -> Deck:
    """The deck (see the module docstring); ``units`` as :class:`~poise.gen.deck.Deck`."""
    d = Deck(units=units)
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 20, (200, 0, 0), mass=2.0, inertia=(25, 26679, 26679))
    d.marker(21, 2, (0, 0, 0))
    d.joint(1, "REVOLUTE", 21, 101)
    torque = frac * 2.0 * G * 200.0 * d.s          # N mm, scaled to the deck's length unit
    d.add("Force_Vector_OneBody", id=1, type="TORQUEONLY", marker_id=20, ref_marker_id=0,
          tx_expression=0.0, ty_expression=0.0, tz_expression=torque)
    return d
