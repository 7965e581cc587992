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


def stiff_soft_deck(m=1e-3, k1=1e9, k2=1.0, kb=1e9):
    """Masses ``m`` [kg] on springs ``k1`` and ``k2`` [N/m] in series below ground, and a rigid
    body on a ``kb`` N/m bushing, in N-kg-m-s; the springs start at their free lengths."""
    # max_error 1e-9: with max_imbalance 1e-8 N a 1 N/m spring pins its body only to ~1e-8 m
    # (Newton's remaining step ~6e-10 x L); 1e-12 could not be proved and is now reported so
    d = Deck(units="m", static=dict(max_imbalance=1e-8, max_error=1e-9))
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, (300, 0, 0))
    d.point(2, 20, (0, -10, 0), mass=m)
    d.point(3, 30, (0, -510, 0), mass=m)
    d.spring(1, 20, 101, k1 * 1e-3, 10.0)          # Deck takes N/mm
    d.spring(2, 30, 20, k2 * 1e-3, 500.0)
    d.body(4, 40, (300, 0, 0), mass=m, inertia=(1e-2, 1e-2, 1e-2))
    d.bushing(1, 40, 102, (kb * 1e-3,) * 3, (1e12,) * 3)
    return d


def perturbed_chain(directory, links: int, seed: int):
    """A compiled ``links``-link hanging chain (``poise.gen.chain``, written to ``directory``)
    and a state near its start: positions moved by 1e-2 and random multipliers."""
    from poise.deck.parser import load_deck
    from poise.gen.chain import build_chain_deck
    from poise.model.compile import compile_model
    p = directory / "chain.xml"
    p.write_text(build_chain_deck(links))
    model = compile_model(load_deck(str(p)))
    rng = np.random.default_rng(seed)
    st = model.retract(model.initial_state(), 1e-2 * rng.standard_normal(model.nq),
                       rng.standard_normal(model.nc))
    return model, st
