"""Holonomic constraint primitives, vectorised.

Every joint and joint primitive of the deck is decomposed into rows of three primitive kinds
(deck_format.md §3.1/3.2, notation: I marker on body i, J marker on body j, d = P_I - P_J):

* :class:`Coincident` — ``d = 0`` (3 rows, global components);
* :class:`Perpendicular` — ``a_I . b_J (+ a2_I . b2_J) = 0`` (1 row; the optional second term
  gives the constant-velocity joint row ``x_I.y_J + y_I.x_J = 0``; its z axes run down the two
  shafts away from the joint centre, MotionSolve/Adams convention, checked at compile time:
  with z axes the same way the row vanishes identically for coaxial shafts);
* :class:`InPlane` — ``d . b_J = 0`` (1 row).

Reactions (``lam``) of Coincident rows are forces; of Perpendicular rows torques; of InPlane
rows forces.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.core.lean import einsum
from poise.elements.base import ConstraintFamily
from poise.elements.kernel import POINT, PairBlocks
from poise.elements.local_pattern import LocalPattern
from poise.elements.registry import (ElementType, FDCase, OutputGroup, claimed_types, static,
                                     workless)


_I3 = np.eye(3)

# equations per joint type: list of ("point",) | ("perp", ci, cj[, ci2, cj2]) | ("plane", cj)
# axis codes: 1 = x, 2 = y, 3 = z.
_REV = [("point",), ("perp", 3, 1), ("perp", 3, 2)]
JOINT_EQUATIONS: dict[str, list[tuple]] = {
    "SPHERICAL": [("point",)],
    "ATPOINT": [("point",)],
    "REVOLUTE": _REV,
    "CYLINDRICAL": [("plane", 1), ("plane", 2), ("perp", 3, 1), ("perp", 3, 2)],
    "TRANSLATIONAL": [("plane", 1), ("plane", 2), ("perp", 3, 1), ("perp", 3, 2), ("perp", 1, 2)],
    "FIXED": [("point",), ("perp", 3, 1), ("perp", 3, 2), ("perp", 1, 2)],
    "UNIVERSAL": [("point",), ("perp", 3, 3)],
    "HOOKE": [("point",), ("perp", 1, 2)],
    "CONSTANT_VELOCITY": [("point",), ("perp", 1, 2, 2, 1)],
    "PLANAR": [("plane", 3), ("perp", 3, 1), ("perp", 3, 2)],
    "INLINE": [("plane", 1), ("plane", 2)],
    "INPLANE": [("plane", 3)],
    "ORIENTATION": [("perp", 3, 1), ("perp", 3, 2), ("perp", 1, 2)],
    "PARALLEL_AXES": [("perp", 3, 1), ("perp", 3, 2)],
    "PERPENDICULAR": [("perp", 3, 3)],
    "FREE": [],
}

_AX = {1: "x", 2: "y", 3: "z"}


def equation_names(eqs) -> list[str]:
    """Readable names of the rows produced by an equation list (for logs and results)."""
    names = []
    for e in eqs:
        if e[0] == "point":
            names += ["dx", "dy", "dz"]
        elif e[0] == "perp":
            s = f"{_AX[e[1]]}I.{_AX[e[2]]}J"
            if len(e) > 3:
                s += f"+{_AX[e[3]]}I.{_AX[e[4]]}J"
            names.append(s)
        else:
            names.append(f"d.{_AX[e[1]]}J")
    return names


def n_rows(eqs) -> int:
    return sum(3 if e[0] == "point" else 1 for e in eqs)


class Coincident(ConstraintFamily):
    """``P_I - P_J = 0``. Slots: P_I, P_J."""

    @classmethod
    def build(cls, name, I, J, owner, **layout):
        n = len(I)
        return cls(name=name, markers=np.stack([I, J], 1).astype(int), slot_ml=np.array([0, 1]),
                   slot_kind=np.zeros((n, 2), int), owner=np.asarray(owner, int), m=3, **layout)

    def values(self, kin, ctx):
        return kin.Y[:, 0] - kin.Y[:, 1]

    def constraints(self, kin, lam, ctx):
        phi = kin.Y[:, 0] - kin.Y[:, 1]
        return phi, self._phi_y(ctx), None

    def _phi_y(self, ctx):
        """``phi_y = [I, -I]`` of every instance (n, 3, 6), read-only: made once per solve (the
        solve's workspace) and shared by its evaluations."""
        sc = ctx.workspace.scratch(self, dict) if getattr(ctx, "workspace", None) else {}
        phi_y = sc.get("phi_y")
        if phi_y is None:
            phi_y = sc["phi_y"] = np.zeros((self.n, 3, 6))
            phi_y[:, :, 0:3] = _I3
            phi_y[:, :, 3:6] = -_I3
            phi_y.setflags(write=False)
        return phi_y

    def g_blocks(self):
        return np.zeros((2, 2), bool)                        # G is always None

    def phi_y_mask(self):
        return np.hstack([_I3, _I3]).astype(bool)


@dataclass(frozen=True, eq=False, kw_only=True)
class Perpendicular(ConstraintFamily):
    """``a_I . b_J + c (a2_I . b2_J) = 0``. Slots: a_I, b_J, a2_I, b2_J; c in {0, 1}
    (``coef2`` (n,)); ``paired``: some instance has ``c = 1``. A big family with no pair
    (every row but the constant-velocity twist) has the slots a_I, b_J only: the second
    product's slots would carry exact zeros (no reaction, no Jacobian entry; its markers'
    entries are the first product's), which the big families' elementwise kernels add onto
    sums started from +0.0, so the values are the same bits without them, for half the slot
    work. Families small enough for a :class:`~poise.elements.slot_index.SlotIndex` with two
    slots keep the four (and their kernel paths): the index's sums and the dense slot pass of
    small models are matrix products over every slot, in an order the slot count changes."""

    coef2: np.ndarray
    paired: bool = True

    @classmethod
    def build(cls, name, I, J, ci, cj, ci2, cj2, coef2, owner, **layout):
        coef2 = np.asarray(coef2, float)
        paired = bool(np.any(coef2 != 0))
        four = paired or 2 * len(I) <= LocalPattern.SLOT_INDEX_MAX     # (no SlotIndex either way)
        kinds = np.stack([ci, cj, ci2, cj2] if four else [ci, cj], 1).astype(int)
        return cls(name=name, markers=np.stack([I, J], 1).astype(int),
                   slot_ml=np.array([0, 1, 0, 1] if four else [0, 1]), slot_kind=kinds,
                   owner=np.asarray(owner, int), m=1, coef2=coef2, paired=paired, **layout)

    @property
    def four(self) -> bool:
        """The family has the four slots a_I, b_J, a2_I, b2_J (else a_I, b_J only)."""
        return len(self.slot_ml) == 4

    def values(self, kin, ctx):
        Y = kin.Y
        phi = einsum("ni,ni->n", Y[:, 0], Y[:, 1])
        if self.paired:
            phi = phi + self.coef2 * einsum("ni,ni->n", Y[:, 2], Y[:, 3])
        return phi[:, None]

    def constraints(self, kin, lam, ctx):
        Y = kin.Y
        n = self.n
        phi = einsum("ni,ni->n", Y[:, 0], Y[:, 1])
        phi_y = np.zeros((n, 1, 12 if self.four else 6))
        phi_y[:, 0, 0:3] = Y[:, 1]
        phi_y[:, 0, 3:6] = Y[:, 0]
        # G: lam I on the (a_I, b_J) blocks, lam c I on (a2_I, b2_J); compact (PairBlocks)
        l = lam[:, 0]
        if not self.paired:            # c = 0 everywhere: x + 0 y is x, the c blocks zeros
            return phi[:, None], phi_y, PairBlocks(n, len(self.slot_ml), {(0, 1): l, (1, 0): l})
        c = self.coef2
        phi = (phi + c * einsum("ni,ni->n", Y[:, 2], Y[:, 3]))[:, None]
        phi_y[:, 0, 6:9] = c[:, None] * Y[:, 3]
        phi_y[:, 0, 9:12] = c[:, None] * Y[:, 2]
        l2 = l * c
        return phi, phi_y, PairBlocks(n, 4, {(0, 1): l, (1, 0): l, (2, 3): l2, (3, 2): l2})

    def g_blocks(self):
        gb = np.zeros((4, 4) if self.four else (2, 2), bool)
        gb[0, 1] = gb[1, 0] = True
        if self.paired:
            gb[2, 3] = gb[3, 2] = True
        return gb


class InPlane(ConstraintFamily):
    """``(P_I - P_J) . b_J = 0``. Slots: P_I, P_J, b_J."""

    @classmethod
    def build(cls, name, I, J, cj, owner, **layout):
        n = len(I)
        kinds = np.stack([np.zeros(n, int), np.zeros(n, int), np.asarray(cj, int)], 1)
        return cls(name=name, markers=np.stack([I, J], 1).astype(int),
                   slot_ml=np.array([0, 1, 1]), slot_kind=kinds,
                   owner=np.asarray(owner, int), m=1, **layout)

    def values(self, kin, ctx):
        Y = kin.Y
        return einsum("ni,ni->n", Y[:, 0] - Y[:, 1], Y[:, 2])[:, None]

    def constraints(self, kin, lam, ctx):
        Y = kin.Y
        d = Y[:, 0] - Y[:, 1]
        b = Y[:, 2]
        phi = einsum("ni,ni->n", d, b)[:, None]
        n = self.n
        phi_y = np.zeros((n, 1, 9))
        phi_y[:, 0, 0:3] = b
        phi_y[:, 0, 3:6] = -b
        phi_y[:, 0, 6:9] = d
        # G: lam I on the (P_I, b_J) blocks, -lam I on (P_J, b_J); compact (PairBlocks)
        l = lam[:, 0]
        m = -l
        return phi, phi_y, PairBlocks(n, 3, {(0, 2): l, (2, 0): l, (1, 2): m, (2, 1): m})

    def g_blocks(self):
        gb = np.zeros((3, 3), bool)
        gb[0, 2] = gb[2, 0] = gb[1, 2] = gb[2, 1] = True
        return gb


assert POINT == 0


# ----------------------------------- compile
_TEMPLATES: dict = {}    # joint type -> [(kind, equation tuple, row offset, row names, row kind)]


def _template(jt):
    t = _TEMPLATES.get(jt)
    if t is None:
        eqs = JOINT_EQUATIONS[jt]
        names = equation_names(eqs)
        t, ni = [], 0
        for e in eqs:
            if e[0] == "point":
                t.append(("point", e, ni, tuple(names[ni:ni + 3]), ("trans",) * 3))
                ni += 3
            else:
                t.append((e[0], e, ni, (names[ni],), ("rot" if e[0] == "perp" else "trans",)))
                ni += 1
        _TEMPLATES[jt] = t
    return t


def compile_joints(spec, ctx):
    """Joints and joint primitives: rows in element order (each element's equations in the
    order of ``JOINT_EQUATIONS``), one family per primitive kind with its instances in that
    order. The per-element work is a few dictionary look-ups; arrays are built per kind.

    Compile ``Constraint_Joint`` and ``Constraint_Jprim`` into constraint primitive families.
    """
    mindex = ctx.geometry.marker_index
    for tag, group in (("Constraint_Joint", "joints"), ("Constraint_Jprim", "jprims")):
        els = spec.elements(tag)
        if not els:
            continue
        acc = {"point": [], "perp": [], "plane": []}   # (I, J, owner, first row, eq)
        claimed = claimed_types(tag)      # types compiled by their own element type (SCREW)
        ids = []
        seen = set()
        for el in els:
            a = el.attrs
            jt = str(a.get("type", "")).upper()
            if jt in claimed:
                continue
            if jt not in JOINT_EQUATIONS:
                ctx.pc.error(el.loc, f"joint type {jt} is not supported yet; supported: "
                           + ", ".join(sorted({*JOINT_EQUATIONS, *claimed})), "type")
                continue
            I = mindex.get(a.get("i_marker_id"), -1) if "i_marker_id" in a else -1
            if I < 0:
                I = ctx.marker(el, "i_marker_id")
            J = mindex.get(a.get("j_marker_id"), -1) if "j_marker_id" in a else -1
            if J < 0:
                J = ctx.marker(el, "j_marker_id")
            if jt == "CONSTANT_VELOCITY":
                _check_cv_axes(ctx, el)
            owner = len(ids)
            ids.append(el.id)
            r0 = None
            for kind, e, off, names, rkinds in _template(jt):
                for nm, rk in zip(names, rkinds):
                    r = ctx.add_row(el, nm, rk, group, owner)
                    r0 = r if r0 is None else r0        # the element's first row (off 0)
                acc[kind].append((I, J, owner, r0 + off, e))
            if jt not in seen:
                seen.add(jt)
                ctx.effect(f"{tag}:{jt}")
        ctx.output(group, tag, ids)
        if acc["point"]:
            I, J, own, r0 = _columns(acc["point"])
            ctx.add_family(Coincident.build(f"{group}:coincident", I, J, own.tolist(),
                                            crow=r0[:, None] + np.arange(3), group=group))
        if acc["perp"]:
            a = acc["perp"]
            I, J, own, r0 = _columns(a)
            e4 = [x[4] for x in a]
            ctx.add_family(Perpendicular.build(
                f"{group}:perpendicular", I, J,
                [e[1] for e in e4], [e[2] for e in e4],
                [e[3] if len(e) > 3 else 1 for e in e4], [e[4] if len(e) > 3 else 1 for e in e4],
                [1.0 if len(e) > 3 else 0.0 for e in e4], own.tolist(),
                crow=r0[:, None], group=group))
        if acc["plane"]:
            a = acc["plane"]
            I, J, own, r0 = _columns(a)
            ctx.add_family(InPlane.build(f"{group}:inplane", I, J, [x[4][1] for x in a],
                                         own.tolist(), crow=r0[:, None], group=group))


def _check_cv_axes(ctx, el):
    """CONSTANT_VELOCITY: each marker's z axis runs down its own shaft away from the joint
    centre (MotionSolve/Adams convention; coaxial shafts have opposite z axes). With z axes
    pointing the same way the twist row ``x_I.y_J + y_I.x_J`` vanishes identically for coaxial
    shafts (the output shaft stays still) and makes bent shafts counter-rotate, so such a set-up
    (a bend beyond 90 degrees in the convention) is an error."""
    gi = ctx.marker_pose(el.attrs.get("i_marker_id"))
    gj = ctx.marker_pose(el.attrs.get("j_marker_id"))
    if gi is None or gj is None:
        return
    c = float(gi[1][:, 2] @ gj[1][:, 2])
    if c > 0.0:
        ctx.pc.error(el.loc, f"CONSTANT_VELOCITY joint whose I and J marker z axes point the same "
                   f"way (z_I.z_J = {c:.3g}): its twist equation degenerates and the output "
                   "shaft would not turn with the input; expected the MotionSolve/Adams "
                   "convention, each marker's z axis along its own shaft pointing away from the "
                   "joint centre (opposite z axes for coaxial shafts)", "i_marker_id")


def _columns(acc):
    """(I, J, owner, first row) int arrays of accumulated primitive instances."""
    arr = np.array([x[:4] for x in acc], int).reshape(len(acc), 4)
    return arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3]


def _fd_cases():
    for jt in sorted(t for t, e in JOINT_EQUATIONS.items() if e):
        for tag in ("Constraint_Joint", "Constraint_Jprim"):
            yield FDCase(f"{tag}:{jt}", ((tag, {"type": jt}),), pairs=((21, 31), (22, 11)),
                         point_b=(False,), seed=(jt, tag), opposite_z=jt == "CONSTANT_VELOCITY")


#: the output groups of joints and joint primitives (the results schema's, too)
_WITH_UNIQUE = ("id", "label", "force", "torque", "unique")
JOINTS = OutputGroup("joints", "J", "joint", "joint",
                     "`Constraint_Joint`", ("Constraint_Joint",), _WITH_UNIQUE,
                     load="force on the I body at the I marker, global axes")
JPRIMS = OutputGroup("jprims", "P", "jprim", "joint primitive",
                     "`Constraint_Jprim`", ("Constraint_Jprim",), _WITH_UNIQUE,
                     load="as for joints")

ELEMENTS = (ElementType(
    "joints", ("Constraint_Joint", "Constraint_Jprim"), compile_joints,
    rank=10,                    # the joints' rows lead the constraint rows
    kernels=lambda: (Coincident, Perpendicular, InPlane),
    tileable=lambda: (Coincident, Perpendicular, InPlane),
    potential_energy=workless, time_dependent=static,
    outputs=(JOINTS, JPRIMS),
    reactions={"JOINT": ("joints", ("Constraint_Joint",)),
               "JPRIM": ("jprims", ("Constraint_Jprim",))},
    reaction_aliases={"CONSTRAINT_JOINT": "JOINT", "CONSTRAINT_JPRIM": "JPRIM"},
    fd_cases=_fd_cases),)
