"""DeckSpec objects built in Python for unit tests that do not need XML: the deck builder
(:class:`poise.gen.deck.Deck`) without units, gravity or settings, whose methods chain."""
from __future__ import annotations

import zlib

import numpy as np

from poise.gen.deck import Deck
from poise.elements.rotation import from_euler_parameters


class DeckBuilder(Deck):
    """``DeckBuilder().ground().body(...)``; ``.spec`` is the live DeckSpec."""

    def __init__(self):
        super().__init__(units=None)

    def add(self, tag, **attrs):
        super().add(tag, **attrs)
        return self

    def marker(self, id, body, pos=(0, 0, 0), R=None):
        return super().marker(id, body, pos, R)

    def ground(self, id=1, cg=1000):
        return super().ground(id, cg)

    def body(self, id, cg, pos, R=None, mass=1.0, inertia=(1.0, 1.0, 1.0), point=False):
        return super().body(id, cg, pos, R, mass, inertia, point)

    def simulate(self, **kw):
        super().simulate(**kw)
        return self


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return from_euler_parameters(*q)


def stable_seed(*parts) -> int:
    """Deterministic seed from strings/numbers (Python's hash() of str varies per process)."""
    return zlib.crc32(repr(parts).encode())
