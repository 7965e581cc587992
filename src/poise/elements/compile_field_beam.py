"""Compile ``Force_Field`` (linear form) and ``Force_Beam`` into one
:class:`poise.elements.field_beam.FieldForce` family (output group ``forces``).

* ``Force_Field``: ``K11 … K66`` (row i, column j of K; absent entries 0), ``length_x … tz``
  (reference X), ``preload_x … tz`` (F0); damping (``C11…``/``cratio``) vanishes in statics.
  User fields (FIESUB via ``usrsub_*``/``script_name``) are rejected (exit 3).
* ``Force_Beam``: K from :func:`poise.elements.field_beam.beam_stiffness`, L = [length, 0 …],
  F0 = ``preload_*``.
"""
from __future__ import annotations

import numpy as np

from poise.elements.field_beam import FieldForce, beam_stiffness
from poise.elements.context import GLOBAL, num as _num
from poise.elements.compile_couplers import user_routine_error
from poise.elements.registry import ElementType

_C6 = ("x", "y", "z", "tx", "ty", "tz")


def compile_field_beam(spec, ctx):
    els = spec.elements("Force_Field") + spec.elements("Force_Beam")
    if not els:
        return
    b, pc = ctx.b, ctx.pc
    items = []
    for el in els:
        def g(name, default=0.0, el=el):
            v = _num(el, name, default, pc)
            return float(default if v is None else v)
        if el.tag == "Force_Field":
            if user_routine_error(pc, el, "field (FIESUB)"):
                continue
            K = np.array([[g(f"k{i}{j}") for j in range(1, 7)] for i in range(1, 7)])
            L = np.array([g(f"length_{c}") for c in _C6])
        else:
            vals = {k: g(k, None) if el.attrs.get(k) is not None else None
                    for k in ("length", "e", "g", "area", "ixx", "iyy", "izz", "asy", "asz")}
            missing = [k for k in ("length", "e", "g", "area", "ixx", "iyy", "izz")
                       if vals[k] is None]
            if missing:
                pc.error(el.loc, "missing " + ", ".join(missing) + "; expected the beam's "
                         "length, E, G, area, ixx, iyy, izz", missing[0])
                continue
            bad = [k for k in ("length", "e", "g", "area") if vals[k] <= 0]
            if bad:
                pc.error(el.loc, f"{bad[0]} = {vals[bad[0]]}; expected a positive value", bad[0])
                continue
            K = beam_stiffness(vals["length"], vals["e"], vals["g"], vals["area"], vals["ixx"],
                               vals["iyy"], vals["izz"], vals["asy"] or 0.0, vals["asz"] or 0.0)
            L = np.array([vals["length"], 0, 0, 0, 0, 0], float)
        F0 = np.array([g(f"preload_{c}") for c in _C6])
        I, J = b.mk(el, "i_marker_id"), b.mk(el, "j_marker_id")
        items.append((el, I, J, K, L, F0))
        b.effects.append(el.tag)
    pc.raise_if_any()
    if not items:
        return
    # owners in the shared "forces" output group (after compile_forces' elements)
    fo = ctx.outputs.get("forces")
    tags = [] if fo is None else list(fo["tag"])
    ids = [] if fo is None else list(fo["ids"])
    owners = []
    for el, *_ in items:
        owners.append(len(ids))
        tags.append(el.tag)
        ids.append(el.id)
    ctx.outputs["forces"] = dict(tag=np.array(tags), ids=np.array(ids, int))
    n = len(items)
    f = FieldForce.build("forces:Field", np.array([it[1] for it in items]),
                         np.array([it[2] for it in items]), np.full(n, GLOBAL), owners,
                         K6=np.array([it[3] for it in items]), L6=np.array([it[4] for it in items]),
                         F06=np.array([it[5] for it in items]))
    f.angle_index = np.array([[ctx.angle(it[1], it[2], a) for a in range(3)] for it in items], int)
    f.element_locs = [it[0].loc for it in items]
    f.group = "forces"
    ctx.families.append(f)


ELEMENTS = (ElementType(
    "field_beam", ("Force_Field", "Force_Beam"), compile_field_beam,
    after=("forces", "gears"),  # extends the "forces" output group after compile_forces
    kernels=lambda: (FieldForce,), tileable=lambda: (FieldForce,), potential_energy=True,
    outputs={"forces": None}, datasets=("id", "tag", "force", "torque"),
    fd_tests="tests/test_elements_8b.py"),)
