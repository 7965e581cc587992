"""Compile ``Force_Contact`` (IMPACT law) between ``Post_Graphic`` analytic primitives.

Supported ``Post_Graphic`` forms: sphere, box (centre or corner form), plane; supported pairs:
sphere-plane, sphere-sphere, sphere-box, box-plane (8 corner contacts), any other a deck error.
Statics: only the IMPACT normal law acts (damping and friction act on velocities). The forms and
attributes read: :func:`compile_contacts`; per-frame outputs ``contacts/*``: a frame hook.
"""
from __future__ import annotations

import numpy as np

from poise.elements import contact as C
from poise.elements.context import GLOBAL
from poise.elements.registry import ElementType
from poise.elements.base import EvalContext
from poise.elements.kernel import slot_kinematics


def _get(el, *names, default=None):
    low = {str(k).lower(): v for k, v in el.attrs.items()}
    for n in names:
        if n in low and low[n] is not None:
            return low[n]
    return default


def _ids(v, el=None, attr=None, pc=None):
    """Id list of a ``*_graphics_id`` attribute; bad entries are reported (located) and skipped."""
    if v is None:
        return []
    items = [v] if isinstance(v, (int, float)) else str(v).replace(",", " ").split()
    out = []
    for t in items:
        try:
            f = float(t)
            if not np.isfinite(f) or f != int(f):
                raise ValueError
            out.append(int(f))
        except (TypeError, ValueError, OverflowError):
            if pc is not None:
                pc.error(el.loc, f"not a list of ids; expected integers, got {v!r}", attr)
            return []
    return out


def _real(el, names, default, pc, what=None):
    """A finite number from the first present attribute of ``names`` (located error otherwise)."""
    v = _get(el, *names, default=default)
    try:
        f = float(v)
        if not np.isfinite(f):
            raise ValueError
        return f
    except (TypeError, ValueError, OverflowError):
        pc.error(el.loc, f"attribute is not a finite number; expected a real number, got {v!r}",
                 what or names[0])
        return float(default) if default is not None else 0.0


def compile_contacts(spec, ctx):
    """``Post_Graphic`` forms read (attribute names case-insensitive):

    * sphere: ``type="Sphere"`` with ``center_marker_id`` (also ``cm_id``, ``marker_id``) and
      ``radius``;
    * box: ``type="BoxDefinedFromCenter"`` (``center_marker_id``) or ``type="BoxDefinedFromCorner"``
      (``corner_marker_id``: the box spans +x/+y/+z of that marker) with ``length_x/y/z`` (full
      lengths); ``type="Box"`` is read as the centre form;
    * plane: ``type="Plane"`` with ``ref_marker_id`` (also ``rm_id``, ``marker_id``,
      ``center_marker_id``): the marker's x-y plane, outward normal +z, material on the -z side
      (unbounded: ``x_min``... extents are ignored).

    Pairs: sphere-plane, sphere-sphere, sphere-box, box-plane (8 corner contacts); other pairs are a
    deck error. ``cnf_type`` must be ``IMPACT``; ``stiffness``, ``exponent`` (default 1.5), ``dmax``
    (smoothing length for exponent <= 1); damping and friction act only on velocities, so they vanish
    in statics. Per-frame outputs ``contacts/id``, ``contacts/kind``, ``contacts/force`` (force on the
    I geometry's body, global), ``contacts/penetration`` (negative = gap) come from a frame hook.
    """
    els = list(spec.elements("Force_Contact"))
    if not els:
        return
    b = ctx.b
    pc = ctx.pc
    graphics = {e.id: e for e in spec.elements("Post_Graphic")}
    rows = []          # dict per instance
    L = getattr(b, "L", 1.0)

    def geom(gid, el, attr):
        g = graphics.get(gid)
        if g is None:
            pc.error(el.loc, f"Post_Graphic {gid} does not exist; expected a Post_Graphic id", attr)
            return None
        t = str(_get(g, "type", default="")).upper()
        if t == "SPHERE":
            mk = _get(g, "center_marker_id", "cm_id", "marker_id")
            return dict(kind="sphere", m=b.mk(g, _key(g, mk, "center_marker_id", "cm_id", "marker_id")),
                        r=_real(g, ("radius",), 0.0, pc), o=np.zeros(3))
        if t in ("BOX", "BOXDEFINEDFROMCENTER", "BOXDEFINEDFROMCORNER"):
            lens = np.array([_real(g, (f"length_{c}",), 0.0, pc) for c in "xyz"])
            if t == "BOXDEFINEDFROMCORNER":
                mk = _key(g, None, "corner_marker_id", "marker_id")
                o = lens / 2
            else:
                mk = _key(g, None, "center_marker_id", "cm_id", "marker_id")
                o = np.zeros(3)
            return dict(kind="box", m=b.mk(g, mk), half=lens / 2, o=o)
        if t == "PLANE":
            mk = _key(g, None, "ref_marker_id", "rm_id", "marker_id", "center_marker_id")
            return dict(kind="plane", m=b.mk(g, mk), o=np.zeros(3))
        pc.error(g.loc, f"Post_Graphic type {t or '?'} is not supported for contact; expected "
                 "Sphere, BoxDefinedFromCenter, BoxDefinedFromCorner or Plane", "type")
        return None

    for el in els:
        law = str(_get(el, "cnf_type", default="IMPACT")).upper()
        if law != "IMPACT":
            pc.error(el.loc, f"cnf_type {law} is not supported; expected IMPACT", "cnf_type")
            continue
        k = _real(el, ("stiffness",), 0.0, pc)
        e = _real(el, ("exponent",), 1.5, pc)
        dmax = _real(el, ("dmax",), 0.0, pc)
        ds = dmax if dmax > 0 else 1e-3 * L
        gi = [geom(g, el, "i_graphics_id")
              for g in _ids(_get(el, "i_graphics_id"), el, "i_graphics_id", pc)]
        gj = [geom(g, el, "j_graphics_id")
              for g in _ids(_get(el, "j_graphics_id"), el, "j_graphics_id", pc)]
        if not gi or not gj:
            pc.error(el.loc, "contact needs i_graphics_id and j_graphics_id; expected "
                     "Post_Graphic ids", "i_graphics_id")
            continue
        base = dict(k=k, e=e, ds=ds, cid=el.id, el=el)
        for a in gi:
            for c in gj:
                if a is None or c is None:
                    continue
                pair = (a["kind"], c["kind"])
                if pair in (("plane", "sphere"), ("box", "sphere"), ("plane", "box")):
                    a, c = c, a
                    pair = (a["kind"], c["kind"])
                z3 = np.zeros(3)
                if pair == ("sphere", "plane"):
                    rows.append(dict(base, kind=C.SPHERE_PLANE, I=a["m"], J=c["m"], rI=a["r"],
                                     rJ=0.0, oI=a["o"], oJ=z3, half=z3))
                elif pair == ("sphere", "sphere"):
                    rows.append(dict(base, kind=C.SPHERE_SPHERE, I=a["m"], J=c["m"], rI=a["r"],
                                     rJ=c["r"], oI=a["o"], oJ=c["o"], half=z3))
                elif pair == ("sphere", "box"):
                    rows.append(dict(base, kind=C.SPHERE_BOX, I=a["m"], J=c["m"], rI=a["r"],
                                     rJ=0.0, oI=a["o"], oJ=c["o"], half=c["half"]))
                elif pair == ("box", "plane"):
                    for sx in (-1, 1):
                        for sy in (-1, 1):
                            for sz in (-1, 1):
                                o = a["o"] + np.array([sx, sy, sz]) * a["half"]
                                rows.append(dict(base, kind=C.CORNER_PLANE, I=a["m"], J=c["m"],
                                                 rI=0.0, rJ=0.0, oI=o, oJ=z3, half=z3))
                else:
                    pc.error(el.loc, f"contact between {pair[0]} and {pair[1]} is not supported; "
                             "expected sphere-plane, sphere-sphere, sphere-box or box-plane",
                             "i_graphics_id")
        ctx.effect("Force_Contact:IMPACT")
    if not rows:
        return
    n = len(rows)
    fam = C.ContactForce.build(
        "contact:IMPACT", np.array([r["I"] for r in rows]), np.array([r["J"] for r in rows]),
        np.full(n, GLOBAL), np.arange(n),
        kind=[r["kind"] for r in rows], rI=[r["rI"] for r in rows], rJ=[r["rJ"] for r in rows],
        k=[r["k"] for r in rows], e=[r["e"] for r in rows], ds=[r["ds"] for r in rows],
        oI=np.array([r["oI"] for r in rows]), oJ=np.array([r["oJ"] for r in rows]),
        half=np.array([r["half"] for r in rows]))
    fam.kind = fam.kind.astype(int)
    fam.element_locs = [r["el"].loc for r in rows]
    fam.contact_ids = np.array([r["cid"] for r in rows], int)
    ctx.families.append(fam)
    ctx.frame_hooks.append(contact_frame_hook)


def _key(g, _unused, *names):
    low = {str(k).lower(): v for k, v in g.attrs.items()}
    for nm in names:
        if low.get(nm) is not None:
            # Builder.mk reads el.attrs[attr]: return the attribute name as written
            for k in g.attrs:
                if str(k).lower() == nm:
                    return k
    return names[0]


def contact_frame_hook(model, state):
    """Per-frame contact outputs (one row per contact instance)."""
    fam = next(f for f in model.families if isinstance(f, C.ContactForce))
    P, A, pos = model.marker_kinematics(state)
    kin = slot_kinematics(fam.markers, fam.slot_ml, fam.slot_kind, P, A, model.marker_body, pos)
    F, _, _, _ = fam.compute(kin.Y, EvalContext(t=state.t, angle=state.angle), False)
    return {"contacts/id": fam.contact_ids,
            "contacts/kind": np.array([C.KIND_NAMES[k] for k in fam.kind], dtype=str),
            "contacts/force": F, "contacts/penetration": fam.last_delta.copy()}


ELEMENTS = (ElementType(
    "contacts", ("Force_Contact",), compile_contacts,
    after=("expressions",),     # contact families after the expression forces (model layout)
    kernels=lambda: (C.ContactForce,), tileable=lambda: (C.ContactForce,),
    potential_energy=True, outputs={"contacts": ("Force_Contact",)},
    datasets=("id", "kind", "force", "penetration"), fd_tests="tests/test_contact.py"),)
