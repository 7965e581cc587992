"""Compile ``Constraint_Joint`` and ``Constraint_Jprim`` into constraint primitive families."""
from __future__ import annotations

import numpy as np

from poise.elements import constraints as C
from poise.elements.registry import ElementType, FDCase, claimed_types


_TEMPLATES: dict = {}    # joint type -> [(kind, equation tuple, row offset, row names, row kind)]


def _template(jt):
    t = _TEMPLATES.get(jt)
    if t is None:
        eqs = C.JOINT_EQUATIONS[jt]
        names = C.equation_names(eqs)
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
    order. The per-element work is a few dictionary look-ups; arrays are built per kind."""
    b = ctx.b
    rows, fams, outputs = ctx.rows, ctx.families, ctx.outputs
    mindex = b.marker_index
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
            if jt not in C.JOINT_EQUATIONS:
                b.pc.error(el.loc, f"joint type {jt} is not supported yet; supported: "
                           + ", ".join(sorted({*C.JOINT_EQUATIONS, *claimed})), "type")
                continue
            I = mindex.get(a.get("i_marker_id"), -1) if "i_marker_id" in a else -1
            if I < 0:
                I = b.mk(el, "i_marker_id")
            J = mindex.get(a.get("j_marker_id"), -1) if "j_marker_id" in a else -1
            if J < 0:
                J = b.mk(el, "j_marker_id")
            if jt == "CONSTANT_VELOCITY":
                _check_cv_axes(b, el)
            owner = len(ids)
            ids.append(el.id)
            r0 = len(rows)
            for kind, e, off, names, rkinds in _template(jt):
                acc[kind].append((I, J, owner, r0 + off, e))
                for nm, rk in zip(names, rkinds):
                    ctx.add_row(el, nm, rk, group, owner)
            if jt not in seen:
                seen.add(jt)
                b.effects.append(f"{tag}:{jt}")
        outputs[group] = dict(tag=tag, ids=np.array(ids, int))
        if acc["point"]:
            I, J, own, r0 = _columns(acc["point"])
            f = C.Coincident.build(f"{group}:coincident", I, J, own.tolist())
            f.crow = r0[:, None] + np.arange(3)
            f.group = group
            fams.append(f)
        if acc["perp"]:
            a = acc["perp"]
            I, J, own, r0 = _columns(a)
            e4 = [x[4] for x in a]
            f = C.Perpendicular.build(
                f"{group}:perpendicular", I, J,
                [e[1] for e in e4], [e[2] for e in e4],
                [e[3] if len(e) > 3 else 1 for e in e4], [e[4] if len(e) > 3 else 1 for e in e4],
                [1.0 if len(e) > 3 else 0.0 for e in e4], own.tolist())
            f.crow = r0[:, None]
            f.group = group
            fams.append(f)
        if acc["plane"]:
            a = acc["plane"]
            I, J, own, r0 = _columns(a)
            f = C.InPlane.build(f"{group}:inplane", I, J, [x[4][1] for x in a], own.tolist())
            f.crow = r0[:, None]
            f.group = group
            fams.append(f)


def _check_cv_axes(b, el):
    """CONSTANT_VELOCITY: each marker's z axis runs down its own shaft away from the joint
    centre (MotionSolve/Adams convention; coaxial shafts have opposite z axes). With z axes
    pointing the same way the twist row ``x_I.y_J + y_I.x_J`` vanishes identically for coaxial
    shafts (the output shaft stays still) and makes bent shafts counter-rotate, so such a set-up
    (a bend beyond 90 degrees in the convention) is an error."""
    gi = b.marker_glob.get(el.attrs.get("i_marker_id"))
    gj = b.marker_glob.get(el.attrs.get("j_marker_id"))
    if gi is None or gj is None:
        return
    c = float(gi[1][:, 2] @ gj[1][:, 2])
    if c > 0.0:
        b.pc.error(el.loc, f"CONSTANT_VELOCITY joint whose I and J marker z axes point the same "
                   f"way (z_I.z_J = {c:.3g}): its twist equation degenerates and the output "
                   "shaft would not turn with the input; expected the MotionSolve/Adams "
                   "convention, each marker's z axis along its own shaft pointing away from the "
                   "joint centre (opposite z axes for coaxial shafts)", "i_marker_id")


def _columns(acc):
    """(I, J, owner, first row) int arrays of accumulated primitive instances."""
    arr = np.array([x[:4] for x in acc], int).reshape(len(acc), 4)
    return arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3]


def _fd_cases():
    for jt in sorted(t for t, e in C.JOINT_EQUATIONS.items() if e):
        for tag in ("Constraint_Joint", "Constraint_Jprim"):
            yield FDCase(f"{tag}:{jt}", ((tag, {"type": jt}),), pairs=((21, 31), (22, 11)),
                         point_b=(False,), seed=(jt, tag), opposite_z=jt == "CONSTANT_VELOCITY")


ELEMENTS = (ElementType(
    "joints", ("Constraint_Joint", "Constraint_Jprim"), compile_joints,
    kernels=lambda: (C.Coincident, C.Perpendicular, C.InPlane),
    tileable=lambda: (C.Coincident, C.Perpendicular, C.InPlane),
    outputs={"joints": ("Constraint_Joint",), "jprims": ("Constraint_Jprim",)},
    datasets=("id", "force", "torque"),
    reactions={"JOINT": ("joints", ("Constraint_Joint",)),
               "JPRIM": ("jprims", ("Constraint_Jprim",))},
    reaction_aliases={"CONSTRAINT_JOINT": "JOINT", "CONSTRAINT_JPRIM": "JPRIM"},
    fd_cases=_fd_cases),)
