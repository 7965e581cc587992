"""The model's own datasets of a results file (``/model/...``): bodies, the model's size and
counts, output-group ids, joint markers and graphics for drawing the stick figure.

Built once per run from the compiled model and the parsed deck (:func:`poise.app.runner.run`),
before the deck is dropped."""
from __future__ import annotations

import numpy as np

from poise.deck.spec import DeckSpec
from poise.elements.contact import attr_of


def model_datasets(model) -> dict:
    d = {
        "bodies/id": model.body_id,
        "bodies/label": np.asarray(model.body_label, dtype=str) if len(model.body_label) else np.zeros(0, str),
        "bodies/kind": np.asarray(["rigid" if k == 0 else "point" for k in model.body_kind], dtype=str)
        if len(model.body_kind) else np.zeros(0, str),
        "bodies/mass": model.deck_mass(),
        "length_scale": np.array(model.L),
        "n_coordinates": np.array(model.nq),
        "n_equations": np.array(model.nc),
    }
    for g, o in model.outputs.items():
        d[f"{g}/id"] = np.asarray(o["ids"])
    return d


def joint_marker_datasets(spec: DeckSpec, model) -> dict:
    """``/model/markers/*`` and ``/model/joints/{i,j}_{marker,body}`` (stick-figure drawing).

    Body id -1 = ground / global frame; marker offsets are in the body (CG marker) frame, for
    ground markers in the global frame.
    """
    nb = len(model.body_id)
    mb = np.asarray(model.marker_body)
    bid = np.where(mb < nb, np.asarray(model.body_id)[np.minimum(mb, max(nb - 1, 0))], -1) \
        if nb else np.full(len(mb), -1)
    d = {"markers/id": np.asarray(model.marker_id, np.int64),
         "markers/body_id": np.asarray(bid, np.int64),
         "markers/offset": np.asarray(model.marker_s0, float)}
    jo = model.outputs.get("joints")
    if jo is not None:
        joints = spec.by_id("Constraint_Joint")
        m2b = dict(zip(d["markers/id"].tolist(), d["markers/body_id"].tolist()))
        im = [int(joints[int(j)].attrs.get("i_marker_id", -1)) for j in jo["ids"]]
        jm = [int(joints[int(j)].attrs.get("j_marker_id", -1)) for j in jo["ids"]]
        d["joints/i_marker"] = np.asarray(im, np.int64)
        d["joints/j_marker"] = np.asarray(jm, np.int64)
        d["joints/i_body"] = np.asarray([m2b.get(m, -1) for m in im], np.int64)
        d["joints/j_body"] = np.asarray([m2b.get(m, -1) for m in jm], np.int64)
    return d


def graphics_datasets(spec: DeckSpec, model) -> dict:
    """``/model/graphics/*``: the ``Post_Graphic`` spheres, boxes and planes (for ``poise animate``).

    Empty when the deck has none. Offsets and axes are in the body (CG marker) frame of
    ``body_id`` (ground, ``-1``: global). ``offset`` is the geometric centre (for
    ``BoxDefinedFromCorner`` the corner marker plus half the lengths along its axes); ``axes``
    are the marker's axes as columns (a plane's normal is the third column). Elements of other
    types or with unreadable attributes are skipped (the contact compiler reports those it uses).
    """
    els = list(spec.elements("Post_Graphic"))
    if not els:
        return {}
    nb = len(model.body_id)
    mindex = {int(m): k for k, m in enumerate(np.asarray(model.marker_id))}
    rows = []

    def num(el, name, default=None):
        v = attr_of(el, name, default=default)
        f = float(v)
        if not np.isfinite(f):
            raise ValueError(name)
        return f

    for el in els:
        t = str(attr_of(el, "type", default="")).upper()
        try:
            if t == "SPHERE":
                kind, names = "sphere", ("center_marker_id", "cm_id", "marker_id")
            elif t in ("BOX", "BOXDEFINEDFROMCENTER"):
                kind, names = "box", ("center_marker_id", "cm_id", "marker_id")
            elif t == "BOXDEFINEDFROMCORNER":
                kind, names = "box", ("corner_marker_id", "marker_id")
            elif t == "PLANE":
                kind, names = "plane", ("ref_marker_id", "rm_id", "marker_id", "center_marker_id")
            else:
                continue
            mid = int(float(attr_of(el, *names)))
            k = mindex[mid]
            radius = num(el, "radius") if kind == "sphere" else np.nan
            half = (np.array([num(el, f"length_{c}") for c in "xyz"]) / 2 if kind == "box"
                    else np.full(3, np.nan))
        except (KeyError, TypeError, ValueError, OverflowError):
            continue
        mb = int(model.marker_body[k])
        A = np.asarray(model.marker_A0[k], float)
        off = np.asarray(model.marker_s0[k], float).copy()
        if t == "BOXDEFINEDFROMCORNER":
            off = off + A @ half
        rows.append((int(el.id), kind, mid, int(model.body_id[mb]) if mb < nb else -1, off, A,
                     radius, half))
    if not rows:
        return {}
    return {"graphics/id": np.array([r[0] for r in rows], np.int64),
            "graphics/type": np.array([r[1] for r in rows], dtype=str),
            "graphics/marker_id": np.array([r[2] for r in rows], np.int64),
            "graphics/body_id": np.array([r[3] for r in rows], np.int64),
            "graphics/offset": np.array([r[4] for r in rows], float),
            "graphics/axes": np.array([r[5] for r in rows], float),
            "graphics/radius": np.array([r[6] for r in rows], float),
            "graphics/half_length": np.array([r[7] for r in rows], float)}


__all__ = ["model_datasets", "joint_marker_datasets", "graphics_datasets"]
