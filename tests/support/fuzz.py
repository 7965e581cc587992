"""Byte-level damage shared by the deck fuzzers (XML and Adams datasets)."""
from __future__ import annotations

import random


def damage(out: bytes, rnd: random.Random, truncate: float, noise: float) -> bytes:
    """``out`` truncated at a random offset (probability ``truncate``), else with 1-4 random
    bytes (probability ``noise``), else unchanged."""
    r = rnd.random()
    if r < truncate:
        return out[:rnd.randrange(len(out) + 1)]
    if r < truncate + noise:
        b = bytearray(out)
        for _ in range(rnd.randint(1, 4)):
            b[rnd.randrange(len(b))] = rnd.randrange(256)
        return bytes(b)
    return out
