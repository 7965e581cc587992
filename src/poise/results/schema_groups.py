"""The element groups of the results schema, derived from the element registry.

Every element output group (``joints``, ``forces``, ``contacts``, ``requests``, ...) is declared
once, by the element types that fill it (:class:`poise.elements.registry.OutputGroup`: its
shape symbol, what it holds, its datasets, what its ``force`` is). :func:`element_items` turns
the declarations into schema items: ``/model/<group>/id|label`` (``model_ids``), the reaction
datasets of reaction groups (``id``, ``label``, ``tag``, ``force``, ``torque``, ``unique``) and
the datasets of the other groups, whose meanings are the tables below. A declared dataset
without a meaning here is an error at import of the schema, never a silent gap.
"""
from __future__ import annotations

from functools import cache

from poise.elements.registry import group_declarations

A, M = "analysis", "model"

#: reaction-group datasets: name -> (dtype, shape with "S" the group symbol, unit, meaning)
REACTION = {
    "id": ("int", ("S",), "1", "{what} ids"),
    "label": ("str", ("S",), "", "their `label` attributes (empty if none)"),
    "tag": ("str", ("S",), "", "element tag of each force element (`Force_SpringDamper`, …; "
            "`(tag, id)` identifies an element)"),
    "force": ("float", ("F", "S", 3), "force", "{load}"),
    "torque": ("float", ("F", "S", 3), "force*length", "torque on the same body about the same "
               "marker origin, global axes"),
    "unique": ("bool", ("S",), "1", "the element's reaction is uniquely determined (no removed "
               "redundant equation depends on its rows)"),
}

#: datasets of the other element groups: group -> name -> (dtype, shape, unit, meaning)
OTHER = {
    "contacts": {
        "id": ("int", ("S",), "1", "`Force_Contact` id of each contact point (a box-plane pair "
               "has 8)"),
        "label": ("str", ("S",), "", "that element's `label` (empty if none)"),
        "kind": ("str", ("F", "S"), "", "sphere-plane, sphere-sphere, sphere-box, corner-plane "
                 "(repeated per frame)"),
        "force": ("float", ("F", "S", 3), "force", "force on the I geometry's body, global"),
        "penetration": ("float", ("F", "S"), "length", "penetration (negative = gap)")},
    "curves": {
        "id": ("int", ("S",), "1", "constraint id"),
        "tag": ("str", ("S",), "", "element tag (`Constraint_PTCV`, ...)"),
        "label": ("str", ("S",), "", "its `label` (empty if none)"),
        "parameters": ("float", ("F", "S", 4), "mixed", "curve/surface parameters (their own "
                       "units), padded with NaN: PTCV (u), CVCV (u_i, u_j), PTSF (u, v), CVSF "
                       "(u, s, t), SFSF (u_i, v_i, u_j, v_j)"),
        "point": ("float", ("F", "S", 3), "length", "global contact point: PTCV/PTSF the point "
                  "on J's curve/surface; CVCV/CVSF/SFSF the point of I's curve/surface"),
        "force": ("float", ("F", "S", 3), "force", "reaction on the I marker's body, global"),
        "torque": ("float", ("F", "S", 3), "force*length", "its torque about the I marker "
                   "origin, global")},
    "requests": {
        "id": ("int", ("S",), "1", "`Post_Request` ids"),
        "label": ("str", ("S",), "", "their `label` attributes (empty if none)"),
        "type": ("str", ("S",), "", "request type (`EXPRESSION`, `MARKER_DISPLACEMENT`, "
                 "`MARKER_FORCE`, `ELEMENTAL_FORCE`, …)"),
        "channel": ("str", ("S", 8), "", "name of each channel (`DM DX DY DZ` … `ROLL`, "
                    "`FM` … `TZ`, `expr1` … `expr8`; empty for an unused one): "
                    "`RunResult.request(id, name)` reads a channel by it"),
        "channel_units": ("str", ("S", 8), "", "unit of each channel in the deck's units "
                          "(empty: an expression of unknown unit, or unused)"),
        "values": ("float", ("F", "S", 8), "mixed", "the request's 8 channels in MotionSolve "
                   "order, units per channel in `requests/channel_units`"),
        "message": ("str", ("F",), "", "empty, or why channels of that frame are NaN "
                    "(evaluation error at the frame's state)")},
    "diffs": {
        "id": ("int", ("S",), "1", "{what} ids"),
        "label": ("str", ("S",), "", "their `label` attributes (empty if none)"),
        "value": ("float", ("F", "S"), "mixed", "state value y (held states: their constant "
                  "`ic`) (units of its expression)")},
    "variables": {
        "id": ("int", ("S",), "1", "{what} ids"),
        "label": ("str", ("S",), "", "their `label` attributes (empty if none)"),
        "value": ("float", ("F", "S"), "mixed", "variable value v (held: `ic`) (units of its "
                  "expression)")},
}

#: document section of the groups that are not reaction groups (``results_format.md``)
SECTION = {"contacts": "contacts", "curves": "curves", "requests": "requests",
           "diffs": "requests", "variables": "requests"}


@cache
def _items(item):
    out = []
    groups = group_declarations()
    for g in groups.values():                         # /model/<group>/id|label
        if g.model_ids:
            out.append(item(M, f"{g.name}/id", "dataset", "int", (g.symbol,), "1",
                            f"{g.what} ids, in the order of the analyses' `{g.name}/*`",
                            True, "model"))
            out.append(item(M, f"{g.name}/label", "dataset", "str", (g.symbol,), "",
                            "their `label` attributes (empty if none)", True, "model"))
    for g in groups.values():                         # <analysis>/<group>/*
        table = REACTION if g.load else OTHER.get(g.name)
        if table is None:
            raise RuntimeError(f"element group {g.name!r}: no dataset meanings in the schema "
                               "(poise.results.schema_groups.OTHER) and no load declared")
        for n in g.datasets:
            if n not in table:
                raise RuntimeError(f"element group {g.name!r} declares dataset {n!r}, which "
                                   "the schema does not describe")
            dtype, shape, unit, meaning = table[n]
            shape = tuple(g.symbol if s == "S" else s for s in shape)
            out.append(item(A, f"{g.name}/{n}", "dataset", dtype, shape, unit,
                            meaning.format(what=g.what, load=g.load), True,
                            SECTION.get(g.name, "reactions")))
    return tuple(out)


def element_items(item) -> list:
    """The schema items (``item``: the schema's item class) of every element group."""
    return list(_items(item))
