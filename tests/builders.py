"""Build DeckSpec objects in Python (for unit tests that do not need XML)."""
from __future__ import annotations

import numpy as np

from poise.deck.spec import DeckSpec, Element
from poise.core.errors import SourceLoc


class DeckBuilder:
    def __init__(self):
        self.spec = DeckSpec(path="<built>", sha256="0" * 64)
        self.line = 1

    def add(self, tag, **attrs):
        self.line += 1
        loc = SourceLoc("<built>", self.line, tag, attrs.get("id"))
        self.spec.model.append(Element(tag=tag, attrs=dict(attrs), loc=loc))
        return self

    def marker(self, id, body, pos=(0, 0, 0), R=None):
        a = dict(id=id, body_id=body, pos_x=float(pos[0]), pos_y=float(pos[1]), pos_z=float(pos[2]))
        if R is not None:
            R = np.asarray(R, float)
            for i in range(3):
                for j in range(3):
                    a[f"a{i}{j}"] = float(R[i, j])
        return self.add("Reference_Marker", **a)

    def ground(self, id=1, cg=1000):
        self.marker(cg, id)
        return self.add("Body_Rigid", id=id, isground=True, cg_id=cg)

    def body(self, id, cg, pos, R=None, mass=1.0, inertia=(1.0, 1.0, 1.0), point=False):
        self.marker(cg, id, pos, R)
        if point:
            return self.add("Body_Point", id=id, cg_id=cg, mass=mass)
        return self.add("Body_Rigid", id=id, cg_id=cg, mass=mass, inertia_xx=inertia[0],
                        inertia_yy=inertia[1], inertia_zz=inertia[2], inertia_xy=0.0,
                        inertia_yz=0.0, inertia_xz=0.0)

    def simulate(self, **kw):
        self.line += 1
        self.spec.commands.append(Element("Simulate", dict(analysis_type="STATIC", **kw),
                                          SourceLoc("<built>", self.line, "Simulate", None), None, True))
        return self


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    from poise.elements.rotation import from_euler_parameters
    return from_euler_parameters(*q)


def stable_seed(*parts) -> int:
    """Deterministic seed from strings/numbers (Python's hash() of str varies per process)."""
    import zlib
    return zlib.crc32(repr(parts).encode())
