"""Command versions of model elements between ``Simulate`` commands (deck_format 1.1, 1.5).

A command element (``<Force_SpringDamper id="1" stiffness="400"/>`` in the command section)
changes attributes of the model element with the same tag and id for the analyses that follow.
poise applies it by recompiling the model with the command's attributes merged into that element
and carrying the solver state over; only changes that keep the model's structure (coordinates,
constraint rows, continuous angles, scalar unknowns) are possible, so each supported tag lists
the attributes a command may change. Anything else is rejected with a located message (exit 3),
never ignored.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from poise.core.errors import DeckError, Problem
from poise.model.compile import compile_model

_SIX = ("x", "y", "z", "tx", "ty", "tz")
_VEC = tuple(f"{c}_expression" for c in ("fx", "fy", "fz", "tx", "ty", "tz"))

#: tag -> attributes a command may change (besides ``id`` and ``label``)
CHANGEABLE: dict[str, tuple[str, ...]] = {
    "Force_Gravity": ("grav_x", "grav_y", "grav_z"),
    "Force_SpringDamper": ("stiffness", "damping", "length", "preload"),
    "Force_Bushing": tuple(f"k{c}" for c in _SIX) + tuple(f"c{c}" for c in _SIX)
    + tuple(f"preload_{c}" for c in _SIX),
    "Force_Vector_OneBody": _VEC,
    "Force_Vector_TwoBody": _VEC,
    "Force_Scalar_TwoBody": ("val", "val_expression"),
    "Force_Beam": ("length", "e", "g", "area", "ixx", "iyy", "izz", "asy", "asz", "cratio")
    + tuple(f"preload_{c}" for c in _SIX),
    "Body_Rigid": ("mass", "inertia_xx", "inertia_yy", "inertia_zz", "inertia_xy", "inertia_yz",
                   "inertia_xz"),
    "Body_Point": ("mass",),
    "Reference_Variable": ("expr",),
    "Motion_Joint": ("expr",),
    "Motion_Marker": ("expr",),
    "Control_Diff": ("expr",),
    "Constraint_General": ("expr",),
}

#: command elements that are settings, not model changes (handled by the runner, or output
#: options that have no effect on results, like their model versions)
SETTINGS = ("Param_Static", "Param_Transient", "Param_Simulation", "Reference_Array",
            "ResOutput", "DebugOutput", "H3DOutput", "Simulate", "Stop", "Param_Linear")


def model_commands(commands) -> list:
    """The command elements of ``commands`` that change the model."""
    return [c for c in commands if c.tag not in SETTINGS]


def check(commands, warnings=()) -> list[Problem]:
    """Located problems of model-changing commands poise cannot apply. ``warnings``: the deck's
    parser warnings; an attribute the schema does not know is dropped from the element with a
    warning, which for a command would leave it silently without effect, so it is an error."""
    probs = []
    where = {(c.loc.file, c.loc.line, c.tag): c for c in model_commands(commands)}
    for w in warnings:
        loc = getattr(w, "loc", None)
        c = where.get((loc.file, loc.line, loc.tag)) if loc is not None else None
        if c is not None and str(w.message).startswith("unknown attribute"):
            name = str(w.message).split("'")[1] if "'" in str(w.message) else "?"
            probs.append(Problem(c.loc, f"a command cannot change unknown attribute '{name}' of "
                                 f"<{c.tag}>; expected one of "
                                 + ", ".join(CHANGEABLE.get(c.tag, ()))))
    for c in model_commands(commands):
        allowed = CHANGEABLE.get(c.tag)
        if allowed is None:
            probs.append(Problem(c.loc, f"the command version of <{c.tag}> is not supported yet; "
                                 "expected a command changing one of "
                                 + ", ".join(f"<{t}>" for t in CHANGEABLE)))
            continue
        bad = [a for a in c.attrs if a not in allowed and a not in ("id", "label")]
        if bad:
            probs.append(Problem(c.loc, f"a command cannot change '{bad[0]}' of <{c.tag}> (it "
                                 "would change the model's structure); expected only "
                                 + ", ".join(allowed)))
    return probs


def apply(spec, commands):
    """A copy of ``spec`` with the commands' attributes merged into their model elements (a
    ``Force_Gravity`` command without a model element adds one)."""
    model = list(spec.model)
    for c in model_commands(commands):
        new = {k: v for k, v in c.attrs.items() if k != "label"}
        if c.tag == "Force_Gravity":
            k = next((i for i in range(len(model) - 1, -1, -1)
                      if model[i].tag == "Force_Gravity"), None)
        else:
            k = next((i for i, e in enumerate(model) if e.tag == c.tag and e.id == c.id), None)
        if k is None:
            if c.tag != "Force_Gravity":
                raise DeckError(Problem(c.loc, f"command modifies a missing <{c.tag}>; expected "
                                        f"the id of a model <{c.tag}>, got {c.id}"))
            model.append(dataclasses.replace(c, attrs=dict(new), is_command=False))
            continue
        merged = {**model[k].attrs, **new}
        if c.tag.startswith("Motion_") and str(merged.get("val_type", "D")).upper() != "D":
            # the displacement target integrates the expression from the start time: a new
            # velocity/acceleration expression would rewrite the past, not continue from now
            raise DeckError(Problem(c.loc, "a command cannot change the expression of a "
                                    f"velocity/acceleration motion (val_type "
                                    f"{merged.get('val_type')}); expected a val_type D motion",
                                    "expr"))
        model[k] = dataclasses.replace(model[k], attrs=merged)
    new_spec = dataclasses.replace(spec, model=model)
    new_spec.__dict__.pop("_tag_index", None)
    return new_spec


def _structure(m):
    return (m.nq, m.nc, m.n_extra, tuple(m.extra_names), tuple(np.asarray(m.body_id).tolist()),
            tuple(np.asarray(m.body_kind).tolist()),
            tuple((r["tag"], r["id"], r["equation"]) for r in m.row_info),
            tuple(np.asarray(m.angle_I).tolist()), tuple(np.asarray(m.angle_J).tolist()),
            tuple(np.asarray(m.angle_axis).tolist()))


def recompile(base, spec, commands, compile_fn=None):
    """The model of the analyses after ``commands``: ``spec`` with the commands applied,
    compiled by ``compile_fn`` (default ``compile_model``); raises a located DeckError when the
    change would alter the model's structure (the solver state could not be carried over).
    Returns (new spec, model)."""
    if compile_fn is None:
        compile_fn = compile_model
    new_spec = apply(spec, commands)
    model = compile_fn(new_spec)
    if _structure(model) != _structure(base):
        mc = model_commands(commands)
        raise DeckError(Problem(mc[0].loc, "these commands change the model's structure "
                                "(coordinates, constraint equations, angles or scalar "
                                "unknowns), which is not supported between analyses; expected "
                                "changes of parameter values only"))
    return new_spec, model
