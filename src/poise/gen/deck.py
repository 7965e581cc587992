"""The deck builder: a deck written element by element in Python, as XML text and as a DeckSpec.

Tests, the hard-case suite, the generators and the benchmarks build their decks here. Each model
element is one line of the XML text (:meth:`Deck.add` returns that line number, so a test can
expect a message located at it) and, for elements given as a tag and attributes, also an
:class:`~poise.deck.spec.Element` of the live :attr:`Deck.spec` (typed values as given, located at
the same line) for tests that compile a model without parsing XML.

Lengths are given in millimetres and scaled by ``units``: ``"mm"`` (N-kg-mm-s), ``"m"``
(N-kg-m-s) or ``"km"`` (N-kg-km-s); forces stay in newtons, so translational stiffness scales
by 1/s, rotational by s, inertia by s**2 and gravity by s. ``units=None`` writes no ``Param_Unit`` / gravity /
``Param_Static`` and scales nothing (a bare deck).
"""
from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np

from poise.core.errors import SourceLoc
from poise.deck.spec import DeckSpec, Element

I3 = np.eye(3)
_LENGTH = {"mm": (1.0, "MILLIMETER"), "m": (1e-3, "METER"), "km": (1e-6, "KILOMETER")}


def rot_x(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def xml_value(v) -> str:
    """An attribute value as the deck writes it: TRUE/FALSE, repr of floats (round-trips)."""
    if isinstance(v, bool):
        return "TRUE" if v else "FALSE"
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return str(v)


def element_line(tag: str, attrs: dict) -> str:
    return "<" + " ".join([tag, *(f"{k}={quoteattr(xml_value(v))}" for k, v in attrs.items())]) + "/>"


class Deck:
    """A deck under construction (see the module docstring)."""

    def __init__(self, units: str | None = "mm", grav=(0.0, -9810.0, 0.0), static=None,
                 method: str = "FIM_S", path: str = "<built>"):
        self.s = _LENGTH.get(units, (1.0, ""))[0]
        self.spec = DeckSpec(path=path, sha256="0" * 64)
        self.lines = ["<MotionSolve>", "<Model>"]
        self.commands = []
        if units is None:
            return
        self.add("Param_Unit", force_unit="NEWTON", mass_unit="KILOGRAM",
                 length_unit=_LENGTH[units][1], time_unit="SECOND")
        if grav is not None:
            g = [float(x) * self.s for x in grav]
            self.add("Force_Gravity", grav_x=g[0], grav_y=g[1], grav_z=g[2])
        st = dict(max_num_iter=100, max_imbalance=1e-8, max_error=1e-8)
        st.update(static or {})
        self.add("Param_Static", method=method, **st)
        self.commands = ['<Simulate analysis_type="Static"/>', "<Stop/>"]

    def L(self, x) -> float:
        """A length given in millimetres, in the deck's units."""
        return float(x) * self.s

    # -- elements ----------------------------------------------------------------------------
    def add(self, tag: str, **attrs) -> int:
        """Add a model element: ``add("Tag", attr=value, ...)`` (also to :attr:`spec`) or a raw
        XML line ``add('<Tag .../>')`` (text only). Returns its line number."""
        if tag.lstrip().startswith("<"):
            self.lines.append(tag)
        else:
            self.lines.append(element_line(tag, attrs))
            loc = SourceLoc(self.spec.path, len(self.lines), tag, attrs.get("id"))
            self.spec.model.append(Element(tag=tag, attrs=dict(attrs), loc=loc))
        return len(self.lines)

    def simulate(self, **attrs) -> None:
        """A ``Simulate`` command (static unless ``analysis_type`` says otherwise)."""
        attrs = dict(analysis_type="STATIC", **attrs) if "analysis_type" not in attrs else attrs
        line = len(self.lines) + 3 + len(self.commands)
        self.commands.append(element_line("Simulate", attrs))
        self.spec.commands.append(Element("Simulate", attrs,
                                          SourceLoc(self.spec.path, line, "Simulate", None),
                                          None, True))

    def marker(self, id, body, pos=(0, 0, 0), R=I3) -> int:
        """``R``: the marker's axes as columns (None: write no orientation, i.e. identity)."""
        a = dict(id=id, body_id=body, pos_x=self.L(pos[0]), pos_y=self.L(pos[1]),
                 pos_z=self.L(pos[2]))
        if R is not None:
            R = np.asarray(R, float)
            a.update({f"a{i}{j}": float(R[i, j]) for i in range(3) for j in range(3)})
        return self.add("Reference_Marker", **a)

    def ground(self, id=1, cg=100) -> int:
        self.marker(cg, id)
        return self.add("Body_Rigid", id=id, isground=True, cg_id=cg)

    def body(self, id, cg, pos, R=I3, mass=1.0, inertia=(1.0, 1.0, 1.0), point=False) -> int:
        """Rigid body (``point``: a ``Body_Point``); ``inertia`` in kg mm^2 (scaled)."""
        self.marker(cg, id, pos, R)
        if point:
            return self.add("Body_Point", id=id, cg_id=cg, mass=mass)
        ii = [float(x) * self.s ** 2 for x in inertia]
        return self.add("Body_Rigid", id=id, cg_id=cg, mass=mass, inertia_xx=ii[0],
                        inertia_yy=ii[1], inertia_zz=ii[2], inertia_xy=0.0, inertia_yz=0.0,
                        inertia_xz=0.0)

    def point(self, id, cg, pos, mass=1.0) -> int:
        self.marker(cg, id, pos)
        return self.add("Body_Point", id=id, cg_id=cg, mass=mass)

    def joint(self, id, type, i, j) -> int:
        return self.add("Constraint_Joint", id=id, type=type, i_marker_id=i, j_marker_id=j)

    def jprim(self, id, type, i, j) -> int:
        return self.add("Constraint_Jprim", id=id, type=type, i_marker_id=i, j_marker_id=j)

    def spring(self, id, i, j, k, length, rotational=False, preload=0.0) -> int:
        """Translational: k in N/mm, length in mm. Rotational: k in N mm/rad, length in rad."""
        if rotational:
            kk, ll, pl, typ = float(k) * self.s, float(length), float(preload) * self.s, "ROTATIONAL"
        else:
            kk, ll, pl, typ = float(k) / self.s, self.L(length), float(preload), "TRANSLATIONAL"
        return self.add("Force_SpringDamper", id=id, type=typ, i_marker_id=i, j_marker_id=j,
                        stiffness=kk, damping=0, length=ll, preload=pl)

    def bushing(self, id, i, j, k, kt) -> int:
        """Stiffnesses ``k`` [N/mm] and ``kt`` [N mm/rad] per axis (scaled)."""
        k = [float(x) / self.s for x in k]
        kt = [float(x) * self.s for x in kt]
        return self.add("Force_Bushing", id=id, i_marker_id=i, j_marker_id=j, kx=k[0], ky=k[1],
                        kz=k[2], ktx=kt[0], kty=kt[1], ktz=kt[2])

    def force(self, id, marker, f, ref=0) -> int:
        """A constant force ``f`` [N] at ``marker`` along ``ref``'s axes."""
        return self.add("Force_Vector_OneBody", id=id, type="FORCEONLY", marker_id=marker,
                        ref_marker_id=ref, fx_expression=float(f[0]), fy_expression=float(f[1]),
                        fz_expression=float(f[2]))

    # -- output ------------------------------------------------------------------------------
    def text(self) -> str:
        return "\n".join(self.lines + ["</Model>", "<Command>"] + self.commands
                         + ["</Command>", "</MotionSolve>", ""])

    def write(self, path) -> str:
        path.write_text(self.text())
        return str(path)
