"""Compile ``Constraint_Joint`` and ``Constraint_Jprim`` into constraint primitive families."""
from __future__ import annotations

import numpy as np

from poise.families import constraints as C


def compile_joints(spec, ctx):
    b = ctx.b
    rows, fams, outputs = ctx.rows, ctx.families, ctx.outputs
    for tag, group in (("Constraint_Joint", "joints"), ("Constraint_Jprim", "jprims")):
        els = spec.elements(tag)
        if not els:
            continue
        acc = {"point": [], "perp": [], "plane": []}
        ids = []
        for el in els:
            jt = str(el.attrs.get("type", "")).upper()
            eqs = C.JOINT_EQUATIONS.get(jt)
            if eqs is None:
                b.pc.error(el.loc, f"joint type {jt} is not supported yet; supported: "
                           + ", ".join(sorted(C.JOINT_EQUATIONS)), "type")
                continue
            I = b.mk(el, "i_marker_id")
            J = b.mk(el, "j_marker_id")
            ids.append(el.id)
            names = C.equation_names(eqs)
            ni = 0
            for e in eqs:
                if e[0] == "point":
                    r0 = len(rows)
                    for nm in names[ni:ni + 3]:
                        ctx.add_row(el, nm, "trans", group, len(ids) - 1)
                    acc["point"].append((I, J, len(ids) - 1, [r0, r0 + 1, r0 + 2]))
                    ni += 3
                else:
                    r0 = len(rows)
                    ctx.add_row(el, names[ni], "rot" if e[0] == "perp" else "trans", group,
                                len(ids) - 1)
                    acc[e[0]].append((I, J, len(ids) - 1, [r0], e))
                    ni += 1
            b.effects.append(f"{tag}:{jt}")
        outputs[group] = dict(tag=tag, ids=np.array(ids, int))
        if acc["point"]:
            a = acc["point"]
            f = C.Coincident.build(f"{group}:coincident", np.array([x[0] for x in a]),
                                   np.array([x[1] for x in a]), [x[2] for x in a])
            f.crow = np.array([x[3] for x in a], int)
            f.group = group
            fams.append(f)
        if acc["perp"]:
            a = acc["perp"]
            e4 = [x[4] for x in a]
            f = C.Perpendicular.build(
                f"{group}:perpendicular", np.array([x[0] for x in a]), np.array([x[1] for x in a]),
                [e[1] for e in e4], [e[2] for e in e4],
                [e[3] if len(e) > 3 else 1 for e in e4], [e[4] if len(e) > 3 else 1 for e in e4],
                [1.0 if len(e) > 3 else 0.0 for e in e4], [x[2] for x in a])
            f.crow = np.array([x[3] for x in a], int)
            f.group = group
            fams.append(f)
        if acc["plane"]:
            a = acc["plane"]
            f = C.InPlane.build(f"{group}:inplane", np.array([x[0] for x in a]),
                                np.array([x[1] for x in a]), [x[4][1] for x in a],
                                [x[2] for x in a])
            f.crow = np.array([x[3] for x in a], int)
            f.group = group
            fams.append(f)

