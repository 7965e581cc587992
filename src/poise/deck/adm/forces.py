"""SFORCE, SPRINGDAMPER, BUSHING, BEAM, FIELD, VFORCE, VTORQUE and GFORCE -> the Force_*
elements.

VFORCE, VTORQUE and GFORCE whose JFLOAT marker is on ground act on one body only and become
Force_Vector_OneBody (the same loads, no reaction on ground); without RM (which Adams requires)
their components are global. poise keeps the ids of the three
statements in one namespace (VFORCE(id, ...), VTORQ and GFORCE read any of them), so two of them
with the same id are a located problem. FIELD's KMATRIX lists the 6x6 matrix by columns, as
Adams enters it. Damping (C, CT, CMATRIX, CRATIO) is translated where the XML keeps it and
vanishes in statics either way.
"""
from __future__ import annotations

from poise.deck.adm.parts import floating_marker
from poise.deck.adm.records import Ctx, num

_SIX = ("x", "y", "z", "tx", "ty", "tz")


def _ij(ctx: Ctx, s) -> bool:
    return ctx.marker(s, "I") is not None and ctx.marker(s, "J") is not None


def sforce(ctx: Ctx, s) -> None:
    if ctx.user(s):
        return
    kind = ctx.one_of(s, ["TRANSLATION", "ROTATION"], "force kind")
    if kind is None or not ctx.need(s, "FUNCTION") or not _ij(ctx, s):
        return
    a = {"type": "FORCE" if kind == "TRANSLATION" else "TORQUE",
         "i_marker_id": num(s.get("I")), "j_marker_id": num(s.get("J"))}
    if s.has("ACTIONONLY"):
        a["is_action_only"] = "TRUE"
    a["val_expression"] = s.get("FUNCTION")
    ctx.add(s, "Force_Scalar_TwoBody", a)


def springdamper(ctx: Ctx, s) -> None:
    kind = ctx.one_of(s, ["TRANSLATION", "ROTATION"], "spring kind")
    if kind is None or not _ij(ctx, s):
        return
    keys = ("K", "C", "LENGTH", "FORCE") if kind == "TRANSLATION" else ("KT", "CT", "ANGLE", "TORQUE")
    other = ("KT", "CT", "ANGLE", "TORQUE") if kind == "TRANSLATION" else ("K", "C", "LENGTH", "FORCE")
    wrong = [k for k in other if s.has(k)]
    if wrong:
        ctx.error(s, f"{', '.join(wrong)} given for a {kind} spring; expected "
                     + ", ".join(keys))
        return
    k, c, length, pre = (s.get(x, 0.0) for x in keys)
    ctx.add(s, "Force_SpringDamper", {
        "type": "TRANSLATIONAL" if kind == "TRANSLATION" else "ROTATIONAL",
        "i_marker_id": num(s.get("I")), "j_marker_id": num(s.get("J")), "stiffness": num(k),
        "damping": num(c), "length": num(length), "preload": num(pre)})


def bushing(ctx: Ctx, s) -> None:
    if not _ij(ctx, s):
        return
    a = {"i_marker_id": num(s.get("I")), "j_marker_id": num(s.get("J"))}
    for key, names in (("K", ("kx", "ky", "kz")), ("KT", ("ktx", "kty", "ktz")),
                       ("C", ("cx", "cy", "cz")), ("CT", ("ctx", "cty", "ctz")),
                       ("FORCE", ("preload_x", "preload_y", "preload_z")),
                       ("TORQUE", ("preload_tx", "preload_ty", "preload_tz"))):
        v = ctx.count(s, key, 3, (0.0, 0.0, 0.0))
        if v is None:
            return
        a.update({n: num(x) for n, x in zip(names, v)})
    ctx.add(s, "Force_Bushing", a)


def beam(ctx: Ctx, s) -> None:
    if not ctx.need(s, "LENGTH", "IXX", "IYY", "IZZ", "AREA", "EMODULUS", "GMODULUS") \
            or not _ij(ctx, s):
        return
    a = {"i_marker_id": num(s.get("I")), "j_marker_id": num(s.get("J"))}
    for key, name in (("LENGTH", "length"), ("IXX", "ixx"), ("IYY", "iyy"), ("IZZ", "izz"),
                      ("AREA", "area"), ("ASY", "asy"), ("ASZ", "asz"), ("EMODULUS", "e"),
                      ("GMODULUS", "g"), ("CRATIO", "cratio")):
        if s.has(key):
            a[name] = num(s.get(key))
    ctx.add(s, "Force_Beam", a)


def field(ctx: Ctx, s) -> None:
    if ctx.user(s) or not ctx.need(s, "KMATRIX") or not _ij(ctx, s):
        return
    k = ctx.count(s, "KMATRIX", 36)
    c = ctx.count(s, "CMATRIX", 36)
    length = ctx.count(s, "LENGTH", 6, (0.0,) * 6)
    force = ctx.count(s, "FORCE", 6, (0.0,) * 6)
    if k is None or length is None or force is None or (s.has("CMATRIX") and c is None):
        return
    if s.has("CMATRIX") and s.has("CRATIO"):
        ctx.error(s, "CMATRIX and CRATIO both given; expected one damping")
        return
    a = {"i_marker_id": num(s.get("I")), "j_marker_id": num(s.get("J"))}
    # by columns: value n is row n % 6, column n // 6
    a.update({f"k{n % 6 + 1}{n // 6 + 1}": num(v) for n, v in enumerate(k) if v})
    if c is not None:
        a.update({f"c{n % 6 + 1}{n // 6 + 1}": num(v) for n, v in enumerate(c) if v})
    if s.has("CRATIO"):
        a["cratio"] = num(s.get("CRATIO"))
    a.update({f"length_{n}": num(v) for n, v in zip(_SIX, length)})
    a.update({f"preload_{n}": num(v) for n, v in zip(_SIX, force)})
    ctx.add(s, "Force_Field", a)


_COMPONENTS = {"VFORCE": ("FX", "FY", "FZ"), "VTORQUE": ("TX", "TY", "TZ"),
               "GFORCE": ("FX", "FY", "FZ", "TX", "TY", "TZ")}
_TYPE = {"VFORCE": "FORCEONLY", "VTORQUE": "TORQUEONLY", "GFORCE": "FORCEANDTORQUE"}


def vector(ctx: Ctx, s) -> None:
    if ctx.user(s):
        return
    comps = _COMPONENTS[s.name]
    if not ctx.need(s, "I", "JFLOAT", *comps):
        return
    i = ctx.marker(s, "I")
    jf = ctx.marker(s, "JFLOAT", floating_ok=True)
    rm = ctx.marker(s, "RM", required=False)
    if i is None or jf is None or (s.has("RM") and rm is None):
        return
    axes = {} if rm is None else {"ref_marker_id": num(rm.id)}
    for other in _COMPONENTS:
        prev = ctx.stmts.get(other, {}).get(s.id)
        if other != s.name and prev is not None and prev.line < s.line:
            ctx.error(s, f"id {s.id} is also {other}/{s.id} (line {prev.line}); poise keeps "
                         "VFORCE, VTORQUE and GFORCE ids in one namespace: renumber one")
            return
    expr = {f"{c.lower()}_expression": s.get(c) for c in comps}
    ground = ctx.parts.get(jf.part)
    if ground is not None and ground.ground:
        a = {"marker_id": num(i.id), **axes, "type": _TYPE[s.name], **expr}
        ctx.add(s, "Force_Vector_OneBody", a)
        return
    if jf.floating:
        floating_marker(ctx, jf.id)
    a = {"i_marker_id": num(i.id), "j_floating_marker_id": num(jf.id), **axes,
         "type": _TYPE[s.name], **expr}
    ctx.add(s, "Force_Vector_TwoBody", a)


TRANSLATORS = {"SFORCE": sforce, "SPRINGDAMPER": springdamper, "BUSHING": bushing, "BEAM": beam,
               "FIELD": field, "VFORCE": vector, "VTORQUE": vector, "GFORCE": vector}
