"""netCDF-4 view of the results schema: dimension names, coordinates and long names.

Every declared dataset is written with named dimensions (HDF5 dimension scales, as netCDF-4
stores them), a ``long_name`` and, in element groups, a ``coordinates`` attribute, so that
``xarray.open_datatree(file, engine="h5netcdf")`` gives labelled arrays. The dimension of a
shape symbol is :data:`DIMENSIONS`; a fixed-size axis is named by :data:`ITEM_DIMS` or, for a
trailing 3 (or 3×3), ``axis`` (``axis, marker_axis``). Symbol dimensions live in the group of
their scope (``/model``, each ``/analysis_NNN``); fixed-size ones at the root, with coordinate
values (:data:`COMPONENTS`). ``case`` (symbol ``C``) is the root dimension of sweep files
(:mod:`poise.results.schema_sweep`).
Adding a dataset: give it a long name in :data:`LONG_NAMES` (patterns ``<group>``: any element
group); a new shape symbol needs a :data:`DIMENSIONS` entry. An element group's symbol, dimension
and noun are declared with the group (:class:`poise.elements.registry.OutputGroup`).
"""
from __future__ import annotations

import functools

#: shape symbol -> dimension name (one per symbol; sizes per scope instance), besides the
#: element groups' (:func:`symbol_dimensions`)
DIMENSIONS = {
    "F": "frame", "B": "body", "W": "warning", "Mk": "marker", "Gr": "graphic", "K": "mode",
    "N": "iteration", "Np": "pose", "I1": "mkeam_iterate", "D": "redundant_equation",
    "Mc": "compliance_marker", "S": "step", "C": "case",
}
RESERVED = ("case",)
#: meanings of the symbol dimensions in the format document
DIM_MEANINGS = {
    "frame": "output frame; coordinate `time` (the analysis' `coordinates` attribute)",
    "iteration": "iteration row (all frames); the dataset `iterations/iteration` (number "
                 "within its frame, repeats) is its coordinate, `iterations/frame` another",
    "pose": "recorded iterate pose (`iterations/pose_row`)",
    "mkeam_iterate": "MKEAM start and restarts", "mode": "described mode (all frames)",
    "redundant_equation": "removed redundant equation", "step": "accepted IDA step",
    "warning": "deck warning", "compliance_marker": "compliance marker",
    "case": "sweep case (sweep files: `case` holds the case numbers; the swept parameters "
            "are its other coordinates)",
}

#: fixed-size dimensions (root): name -> (coordinate values or a size, meaning)
COMPONENTS = {
    "axis": (("x", "y", "z"), "x, y, z components (global axes unless the dataset says "
             "otherwise)"),
    "marker_axis": (("x", "y", "z"), "the marker's x, y, z axes (columns of a rotation "
                    "matrix)"),
    "euler_parameter": (("e0", "e1", "e2", "e3"), "Euler parameters"),
    "euler_angle": (("psi", "theta", "phi"), "body-fixed 3-1-3 angles"),
    "stage": (("plain", "stability", "continuation", "mkeam", "polish"), "recovery stage"),
    "channel": ((1, 2, 3, 4, 5, 6, 7, 8), "request channel number (MotionSolve order)"),
    "curve_parameter": (4, "curve/surface parameter slot"),
    "mkeam_point": (1, "the MKEAM point (one row)"),
}

#: dataset path (scope/name) -> dimension names, where the default rule does not name them
ITEM_DIMS = {
    "analysis/frames/strategy_iterations": ("frame", "stage"),
    "analysis/bodies/euler_parameters": ("frame", "body", "euler_parameter"),
    "analysis/bodies/euler_313": ("frame", "body", "euler_angle"),
    "analysis/mkeam/position": ("mkeam_point", "body", "axis"),
    "analysis/mkeam/orientation": ("mkeam_point", "body", "axis", "marker_axis"),
    "analysis/requests/channel": ("request", "channel"),
    "analysis/requests/channel_units": ("request", "channel"),
    "analysis/requests/values": ("frame", "request", "channel"),
    "analysis/curves/parameters": ("frame", "curve", "curve_parameter"),
    "analysis/frames/compliance": ("frame", "response", "load"),
    "model/graphics/half_length": ("graphic", "marker_axis"),
}

#: per-scope dimensions that are not a shape symbol: name -> (symbol, factor, meaning)
DERIVED = {
    "response": ("Mc", 6, "compliance row: displacement component a of marker i (6i+a)"),
    "load": ("Mc", 6, "compliance column: load component b at marker j (6j+b)"),
}

#: coordinate datasets of a group (in this order), attached to the group's other datasets
#: that share their dimension
COORDINATE_NAMES = ("id", "label", "tag", "type", "channel", "channel_units", "frame")

#: singular nouns of the groups that are not element groups (those declare theirs)
_E = {"bodies": "body", "markers": "marker", "graphics": "graphic"}

#: long names (``<group>``: any group of :data:`_E`); "scope/name" or "<any>/name"
LONG_NAMES = {
    "root/warnings": "deck warning",
    "<any>/<group>/id": "{e} deck id",
    "<any>/<group>/label": "{e} label",
    "<any>/<group>/force": "{e} force on its I body",
    "<any>/<group>/torque": "{e} torque on its I body",
    "<any>/<group>/tag": "{e} element tag",
    "<any>/<group>/unique": "{e} reaction uniquely determined",
    "model/bodies/kind": "body kind", "model/bodies/mass": "body mass",
    "model/length_scale": "model length scale L",
    "model/n_coordinates": "number of coordinates",
    "model/n_equations": "number of constraint equations",
    "model/markers/body_id": "body of the marker", "model/markers/offset": "marker offset",
    "model/joints/i_marker": "joint I marker id", "model/joints/j_marker": "joint J marker id",
    "model/joints/i_body": "joint I body id", "model/joints/j_body": "joint J body id",
    "model/graphics/type": "graphic type", "model/graphics/marker_id": "graphic marker id",
    "model/graphics/body_id": "graphic body id", "model/graphics/offset": "graphic centre",
    "model/graphics/axes": "graphic marker axes", "model/graphics/radius": "sphere radius",
    "model/graphics/half_length": "box half length",
    "analysis/time": "time",
    "analysis/frames/converged": "frame converged",
    "analysis/frames/iterations": "iterations of the frame",
    "analysis/frames/strategy": "recovery stage of the frame",
    "analysis/frames/strategy_iterations": "iterations of the frame per stage",
    "analysis/frames/imbalance": "force imbalance (infinity norm)",
    "analysis/frames/error": "error (constraint violation and update)",
    "analysis/frames/status": "frame status",
    "analysis/frames/stability": "stability class",
    "analysis/frames/n_negative": "negative stiffness eigenvalues",
    "analysis/frames/n_zero": "zero stiffness eigenvalues",
    "analysis/frames/stability_modes": "unstable and neutral modes",
    "analysis/frames/n_modes": "modes described",
    "analysis/frames/min_stiffness_eigenvalue": "smallest reduced stiffness eigenvalue",
    "analysis/frames/compliance": "compliance matrix",
    "analysis/frames/compliance_flag": "compliance matrix flag",
    "analysis/modes/class": "mode class", "analysis/modes/body": "body of the mode",
    "analysis/modes/kind": "kind of motion of the mode",
    "analysis/modes/direction": "mode direction",
    "analysis/modes/eigenvalue": "mode eigenvalue",
    "analysis/bodies/position": "CG position", "analysis/bodies/orientation": "orientation",
    "analysis/bodies/euler_parameters": "Euler parameters",
    "analysis/bodies/euler_313": "Euler 3-1-3 angles",
    "analysis/bodies/rotation_from_input": "rotation vector from the input",
    "analysis/iterations/frame": "frame of the iteration",
    "analysis/iterations/iteration": "iteration within the frame",
    "analysis/iterations/imbalance": "force imbalance (infinity norm)",
    "analysis/iterations/error": "error (constraint violation and update)",
    "analysis/iterations/step_norm": "scaled step norm",
    "analysis/iterations/step_length": "line-search factor",
    "analysis/iterations/worst_equation": "worst equation",
    "analysis/iterations/event": "event", "analysis/iterations/strategy": "recovery stage",
    "analysis/iterations/position": "CG position of the iterate",
    "analysis/iterations/orientation": "orientation of the iterate",
    "analysis/iterations/pose_row": "iteration row of the pose",
    "analysis/iterations/kinetic_energy": "MKEAM peak kinetic energy",
    "analysis/iterations/peak_time": "MKEAM time of the peak",
    "analysis/iterations/max_dq": "MKEAM largest change since the restart",
    "analysis/iterations/potential_energy": "MKEAM potential energy at the peak",
    "analysis/iterations/integrator_steps": "MKEAM integration steps",
    "analysis/mkeam/iterate_position": "CG position at each MKEAM restart",
    "analysis/mkeam/iterate_orientation": "orientation at each MKEAM restart",
    "analysis/mkeam/position": "MKEAM point CG position",
    "analysis/mkeam/orientation": "MKEAM point orientation",
    "analysis/mkeam/initial_potential_energy": "potential energy of the start",
    "analysis/contacts/kind": "contact kind", "analysis/contacts/penetration": "penetration",
    "analysis/curves/parameters": "curve/surface parameters",
    "analysis/curves/point": "contact point",
    "analysis/redundant/tag": "element tag of the removed equation",
    "analysis/redundant/id": "element id of the removed equation",
    "analysis/redundant/equation": "removed equation",
    "analysis/redundant/line": "deck line of the element",
    "analysis/requests/type": "request type", "analysis/requests/channel": "channel name",
    "analysis/requests/channel_units": "channel unit",
    "analysis/requests/values": "request channel values",
    "analysis/requests/message": "request evaluation message",
    "analysis/diffs/value": "Control_Diff state value",
    "analysis/variables/value": "variable value",
    "analysis/compliance/marker_id": "compliance marker id",
    "analysis/compliance/method": "compliance method",
    "analysis/steps/time": "time reached by the IDA step",
    "analysis/steps/step_size": "IDA step size", "analysis/steps/order": "BDF order",
    "analysis/steps/nonlinear_iterations": "IDA Newton iterations",
    "analysis/steps/error_test_failures": "IDA error-test failures",
    "analysis/steps/convergence_failures": "IDA convergence failures",
    "analysis/steps/jacobian_evaluations": "IDA Jacobian evaluations",
    "analysis/steps/rebase": "IDA reinitialised before the step",
    "sweep/case": "case number", "sweep/time": "time", "sweep/analysis": "analysis of the frame",
    "sweep/status": "case status", "sweep/exit_code": "exit code of the case",
    "sweep/iterations": "iterations of all frames", "sweep/wall_time": "wall time of the case",
    "sweep/imbalance": "largest force imbalance",
    "sweep/imbalance_analysis": "analysis of the largest imbalance",
    "sweep/imbalance_frame": "frame of the largest imbalance", "sweep/error": "largest error",
    "sweep/stability": "worst stability class",
    "sweep/stability_analysis": "analysis of the worst stability class",
    "sweep/stability_frame": "frame of the worst stability class",
    "sweep/n_negative": "negative stiffness eigenvalues",
    "sweep/n_zero": "zero stiffness eigenvalues",
    "sweep/stability_modes": "unstable and neutral modes", "sweep/modes": "modes as numbers",
    "sweep/message": "why the case failed", "sweep/converged": "frame converged",
    "sweep/file": "the case's results file", "sweep/<parameter>": "swept parameter",
    "sweep/<output>": "(the long name of the output's dataset)",
}


@functools.cache
def _groups() -> dict:
    from poise.elements.registry import group_declarations   # lazy: every element type
    return group_declarations()


@functools.cache
def symbol_dimensions() -> dict:
    """Shape symbol -> dimension name: :data:`DIMENSIONS` and the element groups'."""
    out = dict(DIMENSIONS)
    for g in _groups().values():
        if out.setdefault(g.symbol, g.dimension) != g.dimension or not g.dimension:
            raise AssertionError(f"element group {g.name!r}: symbol {g.symbol!r} needs its own "
                                 "dimension name (OutputGroup.dimension)")
    return out


def element_name(group: str) -> str | None:
    """The singular noun of a group (``joints`` -> ``joint``), or None."""
    g = _groups().get(group)
    return _E.get(group) if g is None else g.noun


def dims(it) -> tuple[str, ...]:
    """The dimension names of dataset ``it`` ."""
    return _dims(it.scope, it.name, it.shape)


@functools.lru_cache(maxsize=None)
def _dims(scope: str, name: str, shape: tuple) -> tuple[str, ...]:
    explicit = ITEM_DIMS.get(f"{scope}/{name}")
    if explicit is not None:
        assert len(explicit) == len(shape), f"{scope}/{name}: ITEM_DIMS rank != shape"
        return tuple(explicit)
    out = []
    for k, s in enumerate(shape):
        if isinstance(s, int):
            if s == 3 and k and out[-1] == "axis":
                out.append("marker_axis")
            elif s == 3:
                out.append("axis")
            else:
                raise AssertionError(f"{scope}/{name}: axis {k} of size {s} needs a dimension "
                                     f"name (poise.results.ITEM_DIMS)")
        elif s in symbol_dimensions():
            out.append(symbol_dimensions()[s])
        else:
            raise AssertionError(f"{scope}/{name}: shape symbol {s!r} has no dimension name "
                                 f"(poise.results.DIMENSIONS)")
    return tuple(out)


@functools.cache
def dimension_names() -> frozenset[str]:
    """Every dimension name a results file may hold (the names of its dimension-scale
    datasets, which readers skip: they are not declared datasets)."""
    return frozenset((*symbol_dimensions().values(), *COMPONENTS,
                      *DERIVED, *RESERVED))


def component_dim(name: str) -> bool:
    """Whether dimension ``name`` is a fixed-size one written at the root."""
    return name in COMPONENTS


def component_values(name: str):
    """Coordinate values of a fixed-size dimension (a tuple), or its size (an int: a
    dimension without coordinate values)."""
    return COMPONENTS[name][0]


def component_meaning(name: str) -> str:
    return COMPONENTS[name][1]


def long_name(it) -> str:
    """The dataset's ``long_name`` attribute: a few words saying what it is."""
    return _long_name(it.scope, it.name)


@functools.lru_cache(maxsize=None)
def _long_name(scope: str, name: str) -> str:
    table = LONG_NAMES
    text = table.get(f"{scope}/{name}")
    if text is None:
        group, _, rest = name.partition("/")
        e = element_name(group)
        text = table.get(f"<any>/<group>/{rest}") if e and rest else None
        if text is not None:
            text = text.format(e=e)
    if text is None:                          # undeclared: words of the path
        text = name.replace("/", " ").replace("_", " ")
    return text


def coordinates(names, name: str, its_dims: tuple) -> list[str]:
    """The coordinate datasets (:data:`~poise.results.COORDINATE_NAMES`) among
    ``names`` (``{name: dims}`` of one group) that dataset ``name`` with dimensions ``its_dims``
    lists in its ``coordinates`` attribute: those sharing one of its dimensions."""
    if name in COORDINATE_NAMES:
        return []
    return [c for c in COORDINATE_NAMES
            if c in names and set(names[c]) & set(its_dims)]


def group_coordinates(names) -> list[str]:
    """The coordinate datasets among ``names`` (one group's datasets), written as the group's
    ``coordinates`` attribute: xarray then reads them as coordinates even where no dataset of
    the group refers to them (``/model/forces``: ids and labels only)."""
    return [c for c in COORDINATE_NAMES if c in names]
