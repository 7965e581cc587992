"""JOINT, JPRIM, MOTION, COUPLER, GEAR, GCON, PTCV and CVCV -> the Constraint_* and Motion_*
elements.

Joint types keep their names except ``CONVEL`` (CONSTANT_VELOCITY) and ``RACKPIN``
(RACK_PINION, ``PD`` -> pitch_diameter); a joint motion without TRANSLATION/ROTATION drives the
free coordinate of a revolute (R) or translational (T) joint. Curve constraints name their
curve's frame by ``RM``/``IRM``/``JRM`` (the floating markers only say which part carries the
curve); ``DISP`` is given in ``RM`` coordinates and becomes the global contact guess.
"""
from __future__ import annotations

import numpy as np

from poise.deck.adm.records import Ctx, num

JOINT_TYPES = {"REVOLUTE": "REVOLUTE", "SPHERICAL": "SPHERICAL",
               "TRANSLATIONAL": "TRANSLATIONAL", "CYLINDRICAL": "CYLINDRICAL", "FIXED": "FIXED",
               "UNIVERSAL": "UNIVERSAL", "HOOKE": "HOOKE", "PLANAR": "PLANAR",
               "CONVEL": "CONSTANT_VELOCITY", "RACKPIN": "RACK_PINION", "SCREW": "SCREW"}
JPRIM_TYPES = ("ATPOINT", "INLINE", "INPLANE", "ORIENTATION", "PARALLEL_AXES", "PERPENDICULAR")
_FREEDOM = {"REVOLUTE": "R", "TRANSLATIONAL": "T"}


def _ij(ctx: Ctx, s) -> bool:
    i = ctx.marker(s, "I")
    j = ctx.marker(s, "J")
    if i is None or j is None:
        return False
    return True


def joint(ctx: Ctx, s) -> None:
    t = ctx.one_of(s, list(JOINT_TYPES), "joint type")
    if t is None or not _ij(ctx, s):
        return
    a = {"type": JOINT_TYPES[t], "i_marker_id": num(s.get("I")), "j_marker_id": num(s.get("J"))}
    if t == "RACKPIN":
        if not ctx.need(s, "PD"):
            return
        a["pitch_diameter"] = num(s.get("PD"))
    elif t == "SCREW":
        if not ctx.need(s, "PITCH"):
            return
        a["pitch"] = num(s.get("PITCH"))
    for k in ("PD", "PITCH"):
        if s.has(k) and not (k == "PD" and t == "RACKPIN" or k == "PITCH" and t == "SCREW"):
            ctx.warn(s, f"{k} ignored (it belongs to {'RACKPIN' if k == 'PD' else 'SCREW'} "
                        "joints)")
    ctx.add(s, "Constraint_Joint", a)


def jprim(ctx: Ctx, s) -> None:
    t = ctx.one_of(s, JPRIM_TYPES, "primitive type")
    if t is None or not _ij(ctx, s):
        return
    ctx.add(s, "Constraint_Jprim", {"type": t, "i_marker_id": num(s.get("I")),
                                    "j_marker_id": num(s.get("J"))})


def joint_type(ctx: Ctx, j) -> str | None:
    """The translated type of a JOINT statement (None when it has none)."""
    t = [k for k in JOINT_TYPES if j.has(k)]
    return t[0] if len(t) == 1 else None


def motion(ctx: Ctx, s) -> None:
    if ctx.user(s):
        return
    val = {"DISPLACEMENT": "D", "VELOCITY": "V", "ACCELERATION": "A"}
    vt = ctx.one_of(s, list(val), "motion kind", default="DISPLACEMENT")
    if vt is None or not ctx.need(s, "FUNCTION"):
        return
    a = {"val_type": val[vt], "type": "EXPRESSION"}
    if s.has("ICDISP"):
        a["ic_disp"] = num(s.get("ICDISP"))
    if s.has("ICVEL"):
        a["ic_vel"] = num(s.get("ICVEL"))
    if s.has("JOINT"):
        if s.has("I") or s.has("J"):
            ctx.error(s, "JOINT= and I=/J= both given; expected a joint motion or a marker motion")
            return
        j = ctx.ref(s, "JOINT", "JOINT")
        if j is None:
            return
        fr = ctx.one_of(s, ["TRANSLATION", "ROTATION"], "freedom", default="")
        if fr is None:
            return
        if fr:
            f = fr[0]
        else:
            f = _FREEDOM.get(joint_type(ctx, j) or "")
            if f is None:
                ctx.error(s, f"JOINT={j.id} is not a revolute or translational joint; expected "
                             "TRANSLATION or ROTATION")
                return
        a = {"joint_id": num(j.id), "joint_type": f, **a, "expr": s.get("FUNCTION")}
        ctx.add(s, "Motion_Joint", a)
        return
    d = ctx.one_of(s, ["X", "Y", "Z", "B1", "B2", "B3"], "direction")
    if d is None or not _ij(ctx, s):
        return
    a = {"i_marker_id": num(s.get("I")), "j_marker_id": num(s.get("J")), "direction": d, **a,
         "expr": s.get("FUNCTION")}
    ctx.add(s, "Motion_Marker", a)


def coupler(ctx: Ctx, s) -> None:
    if ctx.user(s) or not ctx.need(s, "JOINTS", "SCALES"):
        return
    ids = ctx.count(s, "JOINTS", (2, 3))
    scales = ctx.count(s, "SCALES", (2, 3))
    if ids is None or scales is None:
        return
    if len(ids) != len(scales):
        ctx.error(s, f"{len(ids)} JOINTS and {len(scales)} SCALES; expected as many scales as "
                     "joints")
        return
    joints = ctx.stmts.get("JOINT", {})
    types = []
    given = str(s.get("TYPE", "")).replace(",", ":").split(":") if s.has("TYPE") else []
    if given and len(given) != len(ids):
        ctx.error(s, f"TYPE={s.get('TYPE')} names {len(given)} freedoms; expected {len(ids)} "
                     "(T or R each, separated by ':')")
        return
    for k, jid in enumerate(ids):
        j = joints.get(jid)
        if j is None:
            ctx.error(s, f"JOINTS: no JOINT/{jid} in the dataset", s.values["JOINTS"].line)
            return
        f = given[k].strip().upper()[:1] if given else _FREEDOM.get(joint_type(ctx, j) or "")
        if f not in ("T", "R"):
            ctx.error(s, f"the freedom of JOINT/{jid} is not clear; expected TYPE=T:R... "
                         "(T or R for each joint)")
            return
        types.append(f)
    a = {}
    for k, (jid, f) in enumerate(zip(ids, types), 1):
        a[f"joint{k}_id"] = num(jid)
        a[f"freedom_{k}"] = f
    a["coefficients"] = ", ".join(num(c) for c in scales)
    ctx.add(s, "Constraint_Coupler", a)


def gear(ctx: Ctx, s) -> None:
    if not ctx.need(s, "JOINTS", "CV"):
        return
    ids = ctx.count(s, "JOINTS", 2)
    cv = ctx.marker(s, "CV")
    if ids is None or cv is None:
        return
    for jid in ids:
        if jid not in ctx.stmts.get("JOINT", {}):
            ctx.error(s, f"JOINTS: no JOINT/{jid} in the dataset", s.values["JOINTS"].line)
            return
    ctx.add(s, "Constraint_Gear", {"joint1_id": num(ids[0]), "joint2_id": num(ids[1]),
                                   "cv_marker_id": num(cv.id)})


def gcon(ctx: Ctx, s) -> None:
    if ctx.user(s) or not ctx.need(s, "FUNCTION"):
        return
    a = {"expr": s.get("FUNCTION")}
    if s.has("I"):
        if ctx.marker(s, "I") is None:
            return
        a["i_marker_id"] = num(s.get("I"))
    ctx.add(s, "Constraint_General", a)


def _on_part(ctx: Ctx, s, rm_key: str, float_key: str):
    """The curve frame marker (RM) after checking the floating marker is on its part."""
    rm = ctx.marker(s, rm_key)
    fl = ctx.marker(s, float_key, floating_ok=True)
    if rm is None or fl is None:
        return None
    if fl.part != rm.part:
        ctx.error(s, f"{float_key}={fl.id} is on PART/{fl.part} but {rm_key}={rm.id} on "
                     f"PART/{rm.part}; expected both on the part carrying the curve")
        return None
    return rm


def _curve(ctx: Ctx, s, key: str) -> bool:
    return ctx.ref(s, key, "CURVE") is not None


def ptcv(ctx: Ctx, s) -> None:
    if not ctx.need(s, "I", "JFLOAT", "CURVE", "RM"):
        return
    i = ctx.marker(s, "I")
    rm = _on_part(ctx, s, "RM", "JFLOAT")
    if i is None or rm is None or not _curve(ctx, s, "CURVE"):
        return
    a = {"i_marker_id": num(i.id), "j_marker_id": num(rm.id), "curve_id": num(s.get("CURVE"))}
    d = ctx.count(s, "DISP", 3)
    if d is not None:
        g = rm.origin + rm.axes @ np.asarray(d, float)
        a.update({f"disp_{c}0": num(g[k]) for k, c in enumerate("xyz")})
    ctx.add(s, "Constraint_PTCV", a)


def cvcv(ctx: Ctx, s) -> None:
    if not ctx.need(s, "IFLOAT", "JFLOAT", "ICURVE", "JCURVE", "IRM", "JRM"):
        return
    irm = _on_part(ctx, s, "IRM", "IFLOAT")
    jrm = _on_part(ctx, s, "JRM", "JFLOAT")
    if irm is None or jrm is None or not (_curve(ctx, s, "ICURVE") and _curve(ctx, s, "JCURVE")):
        return
    a = {"i_marker_id": num(irm.id), "j_marker_id": num(jrm.id),
         "i_curve_id": num(s.get("ICURVE")), "j_curve_id": num(s.get("JCURVE"))}
    for side in ("I", "J"):
        d = ctx.count(s, f"{side}DISP", 3)
        if d is not None:
            a.update({f"{side.lower()}_disp_{c}0": num(d[k]) for k, c in enumerate("xyz")})
    ctx.add(s, "Constraint_CVCV", a)


TRANSLATORS = {"JOINT": joint, "JPRIM": jprim, "MOTION": motion, "COUPLER": coupler,
               "GEAR": gear, "GCON": gcon, "PTCV": ptcv, "CVCV": cvcv}
