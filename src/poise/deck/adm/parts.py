"""UNITS, PART, POINT_MASS, MARKER and ACCGRAV -> Param_Unit, Body_Rigid, Body_Point,
Reference_Marker (global position and direction cosines) and Force_Gravity.

Frames are placed before any record is written (:func:`place`), so statements may come in any
order. A part without a CM marker (a massless part) gets a marker at its reference frame as its
CG marker (a new id above every marker id of the dataset), so its position in the results is
that of its frame, as Adams reports it.
"""
from __future__ import annotations

import numpy as np

from poise.deck.adm.geometry import compose, euler313, frame_from_points
from poise.deck.adm.records import Ctx, Frame, MarkerInfo, num
from poise.deck.schema import FORCE_UNITS, LENGTH_UNITS, MASS_UNITS, TIME_UNITS

_EYE = np.eye(3)
_SYSTEMS = {"MKS": ("NEWTON", "KILOGRAM", "METER", "SECOND"),
            "MMKS": ("NEWTON", "KILOGRAM", "MILLIMETER", "SECOND"),
            "CGS": ("DYNE", "GRAM", "CENTIMETER", "SECOND"),
            "FPS": ("POUND_FORCE", "POUND_MASS", "FOOT", "SECOND"),
            "IPS": ("POUND_FORCE", "POUND_MASS", "INCH", "SECOND")}
_UNITS = {"FORCE": FORCE_UNITS.split(), "MASS": MASS_UNITS.split(),
          "LENGTH": LENGTH_UNITS.split(), "TIME": TIME_UNITS.split()}


def _orientation(ctx: Ctx, stmt, origin, angles: str, zkey: str, xkey: str):
    """Axes (in the parent frame) from REULER or ZP/XP (ZG/XG); identity when none."""
    if stmt.has(angles):
        if stmt.has(zkey) or stmt.has(xkey):
            ctx.error(stmt, f"{angles} and {zkey}/{xkey} both given; expected one orientation")
            return None
        v = ctx.count(stmt, angles, 3)
        return None if v is None else euler313(v, stmt.values[angles].degrees)
    if stmt.has(zkey) or stmt.has(xkey):
        z = ctx.count(stmt, zkey, 3)
        x = ctx.count(stmt, xkey, 3)
        use_x = stmt.has("USEXP")
        if (z is None and not use_x) or (x is None and use_x):
            ctx.error(stmt, f"{xkey if use_x else zkey}= is needed to orient the frame"
                      + (" (USEXP)" if use_x else ""))
            return None
        axes, msg = frame_from_points(origin, z, x, use_x)
        if axes is None:
            ctx.error(stmt, msg)
        return axes
    return _EYE


def place(ctx: Ctx, stmts) -> None:
    """Frames of every part, point mass and marker (global), before translation."""
    for s in stmts:
        if s.name in ("PART", "POINT_MASS") and s.id is not None:
            o = ctx.count(s, "QG", 3, (0.0, 0.0, 0.0))
            o = np.zeros(3) if o is None else np.asarray(o, float)
            ax = _orientation(ctx, s, o, "REULER", "ZG", "XG")
            if s.id in ctx.parts:
                kind = "PART" if not ctx.parts[s.id].point else "POINT_MASS"
                ctx.error(s, f"id {s.id} is also {kind}/{s.id} (line "
                             f"{ctx.stmts[kind][s.id].line}); poise numbers parts and point "
                             "masses in one namespace")
                continue
            ctx.parts[s.id] = Frame(s.id, o, _EYE if ax is None else ax, s.has("GROUND"),
                                    s.name == "POINT_MASS", s.who)
    top = 0
    for s in stmts:
        if s.name != "MARKER" or s.id is None:
            continue
        top = max(top, s.id)
        owners = [k for k in ("PART", "POINT_MASS", "FLEX_BODY", "FE_PART") if s.has(k)]
        if len(owners) != 1:
            ctx.error(s, "expected exactly one of PART=, POINT_MASS=, FLEX_BODY=, FE_PART=" if
                      owners else "PART= is missing; expected the id of the marker's part")
            continue
        if owners[0] == "FE_PART" or s.has("NODE_LABEL"):
            ctx.refuse(s, "FE_PART", "a marker on a finite-element part")
            continue
        if owners[0] == "FLEX_BODY" or s.has("NODE_ID"):
            ctx.refuse(s, "FLEX_BODY", "a marker on a flexible body")
            continue
        pid = s.get(owners[0])
        part = ctx.parts.get(pid)
        if part is None or part.point != (owners[0] == "POINT_MASS"):
            ctx.error(s, f"{owners[0]}={pid}: no {owners[0]}/{pid} in the dataset",
                      s.values[owners[0]].line)
            continue
        if s.has("FLOATING"):
            ctx.markers[s.id] = MarkerInfo(s.id, pid, part.origin, part.axes, True, s.who)
            continue
        qp = ctx.count(s, "QP", 3, (0.0, 0.0, 0.0))
        qp = np.zeros(3) if qp is None else np.asarray(qp, float)
        ax = _orientation(ctx, s, qp, "REULER", "ZP", "XP")
        if ax is None:
            continue
        o, a = compose(part.origin, part.axes, qp, ax)
        ctx.markers[s.id] = MarkerInfo(s.id, pid, o, a, False, s.who)
    ctx.next_marker = top


def _marker_rec(ctx: Ctx, stmt, mid: int, body: int, origin, axes, label=None,
                first: bool = True):
    a = {"id": num(mid), "body_id": num(body)}
    if label is not None:
        a["label"] = label
    a.update({f"pos_{c}": num(origin[k]) for k, c in enumerate("xyz")})
    a.update({f"a{r}{c}": num(axes[r, c]) for c in range(3) for r in range(3)})
    ctx.add(stmt, "Reference_Marker", a, first=first)


def units(ctx: Ctx, s) -> None:
    names = dict(zip(("FORCE", "MASS", "LENGTH", "TIME"),
                     _SYSTEMS.get(str(s.get("SYSTEM", "")).upper(), (None,) * 4)))
    if s.has("SYSTEM"):
        sysname = str(s.get("SYSTEM")).upper()
        if sysname not in _SYSTEMS and sysname != "NONE":
            ctx.error(s, f"SYSTEM={s.get('SYSTEM')}: unknown unit system; expected one of "
                         + ", ".join([*_SYSTEMS, "NONE"]))
    for key, table in _UNITS.items():
        if not s.has(key):
            continue
        w = str(s.get(key)).upper().replace(" ", "_")
        hits = [w] if w in table else [n for n in table if n.startswith(w)]
        if len(hits) != 1:
            ctx.error(s, f"{key}={s.get(key)}: unknown unit; expected one of " + ", ".join(table),
                      s.values[key].line)
            continue
        names[key] = hits[0]
    a = {f"{k.lower()}_unit": v for k, v in names.items() if v is not None}
    if s.has("UCF"):
        ucf = s.get("UCF")
        if not ucf > 0:
            ctx.error(s, f"UCF={ucf}; expected a positive units consistency factor")
            return
        a = {"mass_mult_factor": num(1.0 / ucf)}
        if any(names.values()):
            ctx.warn(s, "UCF given: poise uses it (mass_mult_factor = 1/UCF) and keeps the unit "
                        "names only as labels of the results")
            a.update({f"{k.lower()}_unit": v for k, v in names.items() if v is not None})
    if a:
        ctx.add(s, "Param_Unit", a)


def part(ctx: Ctx, s) -> None:
    fr = ctx.parts.get(s.id)
    if fr is None or fr.point:          # not placed, or the id is a point mass's (reported)
        return
    if s.has("GROUND"):
        extra = [k for k in ("MASS", "CM", "IP", "IM") if s.has(k)]
        if extra:
            ctx.warn(s, f"{', '.join(extra)} of the ground part ignored")
        ctx.add(s, "Body_Rigid", {"isground": "TRUE"})
        return
    mass = s.get("MASS", 0.0)
    a = {"mass": num(mass)} if s.has("MASS") else {}
    cm = s.get("CM")
    if cm is None:
        if mass:
            ctx.error(s, "MASS given without CM; expected CM=<id of the centre-of-mass marker>")
            return
        mid = ctx.new_marker_id()
        a["cg_id"] = num(mid)
        ctx.add(s, "Body_Rigid", a)
        _marker_rec(ctx, s, mid, s.id, fr.origin, fr.axes,
                    f"{s.who} reference frame (poise: CG marker of a part without CM)", False)
        return
    for key in ("CM", "IM"):
        m = ctx.marker(s, key, required=(key == "CM"))
        if key == "CM" and m is None:
            return
        if m is not None and m.part != s.id:
            ctx.error(s, f"{key}={m.id}: MARKER/{m.id} belongs to PART/{m.part}; expected a "
                         "marker of this part", s.values[key].line)
            return
    a["cg_id"] = num(cm)
    if s.has("IM"):
        a["im_id"] = num(s.get("IM"))
    ip = ctx.count(s, "IP", (3, 6))
    if ip is not None:
        names = ("xx", "yy", "zz", "xy", "xz", "yz")
        a.update({f"inertia_{n}": num(v) for n, v in zip(names, ip)})
    ctx.add(s, "Body_Rigid", a)


def point_mass(ctx: Ctx, s) -> None:
    fr = ctx.parts.get(s.id)
    if fr is None or not fr.point:
        return
    m = ctx.marker(s, "CM")
    if m is None:
        return
    if m.part != s.id:
        ctx.error(s, f"CM={m.id}: MARKER/{m.id} is not on this point mass")
        return
    a = {"cg_id": num(m.id)}
    if s.has("MASS"):
        a["mass"] = num(s.get("MASS"))
    ctx.add(s, "Body_Point", a)


def marker(ctx: Ctx, s) -> None:
    m = ctx.markers.get(s.id)
    if m is None:
        return
    if m.floating:
        if any(s.has(k) for k in ("QP", "REULER", "XP", "ZP")):
            ctx.warn(s, "a FLOATING marker's QP/REULER/XP/ZP are ignored (its position is that "
                        "of the force or constraint using it)")
        return              # written where a two-body vector force needs it (floating_marker)
    _fixed_marker(ctx, s, m)


def floating_marker(ctx: Ctx, mid: int) -> None:
    """The Reference_Marker of FLOATING marker ``mid`` (once), where a force needs one: at its
    part's reference frame (its position is not used: poise applies the reaction at I)."""
    done = ctx.__dict__.setdefault("_floating_done", set())
    if mid in done:
        return
    done.add(mid)
    m = ctx.markers[mid]
    s = ctx.stmts["MARKER"][mid]
    _fixed_marker(ctx, s, m)


def _fixed_marker(ctx: Ctx, s, m) -> None:
    a = {"id": num(s.id), "body_id": num(m.part)}
    if s.label is not None:
        a["label"] = s.label
    a.update({f"pos_{c}": num(m.origin[k]) for k, c in enumerate("xyz")})
    a.update({f"a{r}{c}": num(m.axes[r, c]) for c in range(3) for r in range(3)})
    ctx.add(s, "Reference_Marker", a)


def accgrav(ctx: Ctx, s) -> None:
    ctx.add(s, "Force_Gravity", {f"grav_{c}": num(s.get(k, 0.0))
                                 for c, k in zip("xyz", ("IGRAV", "JGRAV", "KGRAV"))})


TRANSLATORS = {"UNITS": units, "PART": part, "POINT_MASS": point_mass, "MARKER": marker,
               "ACCGRAV": accgrav}
