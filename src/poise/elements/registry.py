"""The element registry: every element type declared once, every element table derived from it.

An element module of this package declares ``ELEMENTS = (ElementType(...), ...)``: its deck
tags, its ``compile(spec, ctx)``, the kernel families it builds and its capabilities (tileable
across frames, potential energy, output groups, reaction channels exposed to expressions, time
dependence, finite-difference Jacobian cases). Modules are found by walking the package, so a new
element type is one new module. Derived here: the compile order (the declared layout ``rank``,
checked against the declared data dependencies ``needs``), the batching whitelist, the reaction
tables of expressions, the output groups of ``poise sweep --output`` and of the results schema,
the supported joint types, the FD test cases, which compiled families make the solution depend
on time (:func:`time_sources`) and which add potential energy (:func:`energy_terms`).
"""
from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass, field
from functools import cache
from typing import Callable

import numpy as np

import poise.elements as pkg


@dataclass(frozen=True)
class FDCase:
    """A finite-difference Jacobian check (tests/kernels/test_jacobians.py): ``elements`` are added to a
    random two-body deck once per marker pair of ``pairs`` (I, J marker ids of that deck; the
    element's own marker attribute names in ``marker_attrs``; an element without markers, such
    as gravity: ``pairs=((),), marker_attrs=()``, added once without an id)."""

    name: str
    elements: tuple                       # ((tag, attrs), ...)
    pairs: tuple = ((21, 31), (32, 11))   # body-body, body-ground
    marker_attrs: tuple = ("i_marker_id", "j_marker_id")
    point_b: tuple = (False, True)        # second body rigid / a point body
    seed: tuple | None = None             # stable_seed arguments (default: (name, point_b))
    opposite_z: bool = False              # J marker z axis turned against I's (CV joints)


# ------------------------------------------------------------------ declared capabilities
# ``ElementType.potential_energy``: how a compiled family of the type adds to the model's potential
# energy, ``fn(fam, frame) -> array | None``. ``frame`` offers ``kinematics(fam)`` (slot
# vectors), ``ctx`` (time, angles) and ``on_ground(fam)`` (n, K) (see poise.model.evaluate);
# the energy is the sum of the array; None means the model has no potential energy (NaN).
def workless(fam, frame):
    """Constraints only: an ideal reaction does no work, nothing is added (the energy pass
    skips these types)."""
    return 0.0


def not_conservative(fam, frame):
    """Forces with no potential (expression and user forces, scalar-equation rows): the model's
    potential energy is NaN (MKEAM's descent measure and restart rule, ``--require-stable``)."""
    return None


def kernel_potential(fam, frame):
    """The kernel's own ``potential_energy(kin, ctx[, on_ground])`` (None where the family has
    none or its law has no potential at these parameters)."""
    fn = getattr(fam, "potential_energy", None)
    if fn is None:
        return None
    kin = frame.kinematics(fam)
    if getattr(fam, "potential_needs_ground", False):
        return fn(kin, frame.ctx, on_ground=frame.on_ground(fam))
    return fn(kin, frame.ctx)


# ``ElementType.time_dependent``: ``fn(fam) -> list[str]``, the deck places through which a compiled
# family makes the solution depend on the analysis time (empty: it does not); the model depends
# on time when any family names one (quasi-static runs of a time-independent scene are solved
# once and replicated).
def static(fam) -> list:
    """The type's elements never read the analysis time."""
    return []


def expressions_of_time(fam) -> list:
    """The first expression reading TIME (directly or through variables, splines, ...) of each
    of the family's compiled expression batches (``fam.batches``)."""
    return batch_time_sources(getattr(fam, "batches", ()))


def batch_time_sources(batches) -> list:
    """``file:line: <Tag id=..> attr`` of the first TIME-reading expression of each batch."""
    out = []
    for b in batches:
        if b is not None and b.depends_on_time:
            e = b.exprs[int(np.argmax(b.time_mask))]
            loc = getattr(e, "loc", None)
            out.append(loc.prefix(getattr(e, "attr", None)).rstrip(":")
                       if loc is not None else "an expression of TIME")
    return out


@dataclass(frozen=True)
class OutputGroup:
    """An element group of the results file (``<analysis>/<name>/*``, and ``/model/<name>/id``
    and ``label`` when ``model_ids``), declared once by the element types that fill it: the
    results schema derives the group's datasets from it (:mod:`poise.results.schema_items`).

    ``symbol``: its shape symbol (``results_format.md``, *Conventions*); ``dimension``: the
    netCDF dimension of that symbol, ``noun``: one element of the group (long names,
    :mod:`poise.results.schema_dims`); ``what``: the elements it holds (documentation);
    ``tags``: deck tags whose ids it holds (None: several, by element); ``datasets``: its
    per-analysis datasets; ``load``: for a reaction group (``force``/``torque`` from the
    element loads), what ``force`` is.
    """

    name: str
    symbol: str
    dimension: str
    noun: str
    what: str
    tags: tuple | None = None
    datasets: tuple = ("id", "label", "force", "torque")
    load: str = ""
    model_ids: bool = True


@dataclass(frozen=True)
class ElementType:
    """One registered element type (see the module docstring).

    ``types``: values of the ``type`` attribute this entry claims inside a tag another entry
    compiles (e.g. ``SCREW`` of ``Constraint_Joint``); the owner of the tag skips them.
    ``rank``: the type's place in the model layout (its constraint rows, families, scalar
    unknowns and the owners it adds to shared output groups follow those of lower ranks);
    ``needs``: the types whose compile results it reads (elements routed to it,
    :meth:`poise.elements.context.CompileContext.route`): a data dependency, which the rank
    must respect. Types compile in rank order.
    ``outputs``: the :class:`OutputGroup` s it fills.
    ``reactions``: element-force function (``BUSH``) -> (output group, deck tags);
    ``reaction_aliases``: ``ELEMENTAL_FORCE`` ``elem_type`` spellings -> function.
    ``fd_tests``: where the FD Jacobian check lives when it needs more than :class:`FDCase`.
    ``potential_energy`` and ``time_dependent`` (required, keyword-only): the functions above
    or the type's own, applied to each compiled family of the type's ``kernels``.
    """

    name: str
    tags: tuple
    compile: Callable
    rank: int = field(kw_only=True)
    needs: tuple = ()
    types: tuple = ()
    kernels: Callable = tuple            # () -> family classes (lazy: kernels import late)
    tileable: Callable = tuple           # () -> the kernels batched across frames
    potential_energy: Callable = field(kw_only=True)
    time_dependent: Callable = field(kw_only=True)
    outputs: tuple = ()
    reactions: dict = field(default_factory=dict)
    reaction_aliases: dict = field(default_factory=dict)
    fd_cases: Callable = tuple           # () -> FDCase instances
    fd_tests: str = ""


@cache
def element_types() -> tuple[ElementType, ...]:
    """All registered element types in compile order (layout rank)."""
    found: dict[str, ElementType] = {}
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        mod = importlib.import_module(f"{pkg.__name__}.{info.name}")
        for et in getattr(mod, "ELEMENTS", ()):
            if et.name in found:
                raise RuntimeError(f"element type {et.name!r} registered twice")
            found[et.name] = et
    return compile_order(found)


def compile_order(found: dict) -> tuple:
    """The types of ``found`` (name -> type) by layout rank; a data dependency on an unknown
    type, two types of one rank, or a type whose rank does not follow the types it needs
    raise (the layout would otherwise depend on how compilers happen to be ordered)."""
    order = sorted(found.values(), key=lambda et: et.rank)
    ranks: dict = {}
    for et in order:
        if et.rank in ranks:
            raise RuntimeError(f"element types {ranks[et.rank]!r} and {et.name!r} have the "
                               f"same layout rank {et.rank}")
        ranks[et.rank] = et.name
        for n in et.needs:
            if n not in found:
                raise RuntimeError(f"element type {et.name!r} needs unknown {n!r}")
            if found[n].rank >= et.rank:
                raise RuntimeError(f"element type {et.name!r} (rank {et.rank}) needs "
                                   f"{n!r} (rank {found[n].rank}): a type's rank must follow "
                                   "the ranks of the types it needs")
    return tuple(order)


def get(name: str) -> ElementType:
    return next(et for et in element_types() if et.name == name)


@cache
def tileable_kernels() -> tuple:
    """Family classes batched across frames (:mod:`poise.model.frame_batch`)."""
    return tuple(k for et in element_types() for k in et.tileable())


@cache
def reaction_kinds() -> dict:
    """Element-force function -> (output group, deck tags) of expressions (``BUSH(id, ...)``)."""
    return {k: v for et in element_types() for k, v in et.reactions.items()}


@cache
def reaction_aliases() -> dict:
    """``ELEMENTAL_FORCE`` ``elem_type`` spelling -> element-force function."""
    out = {}
    for et in element_types():
        for k in et.reactions:
            out[k] = k
        out.update(et.reaction_aliases)
    return out


@cache
def output_groups() -> dict:
    """Output group -> deck tags whose ids it holds (None: any tag of the group)."""
    return {g.name: g.tags for g in group_declarations().values()}


@cache
def group_declarations() -> dict:
    """Output group name -> its :class:`OutputGroup` (types sharing a group declare the same
    one), in compile order."""
    out: dict = {}
    for et in element_types():
        for g in et.outputs:
            if out.setdefault(g.name, g) != g:
                raise RuntimeError(f"output group {g.name!r} declared twice differently "
                                   f"({et.name!r})")
    return out


def claimed_types(tag: str) -> dict:
    """``type`` values of ``tag`` compiled by another element type: type -> ElementType."""
    return {t: et for et in element_types() if tag in et.tags for t in et.types}


def fd_cases() -> list[FDCase]:
    return [c for et in element_types() for c in et.fd_cases()]


def kernel_types(types=None) -> dict:
    """Family class -> the element type declaring it among its ``kernels`` (``types``: the
    element types a model was compiled with, default all registered)."""
    out = {}
    for et in element_types() if types is None else types:
        for k in et.kernels():
            if out.setdefault(k, et) is not et:
                raise RuntimeError(f"kernel {k.__name__} declared by {out[k].name!r} and "
                                   f"{et.name!r}")
    return out


def type_of(fam, owners: dict | None = None) -> ElementType:
    """The element type of a compiled family (its class is a declared kernel); ``owners`` a
    :func:`kernel_types` table (default: of all registered types)."""
    et = (kernel_types() if owners is None else owners).get(type(fam))
    if et is None:
        raise RuntimeError(f"family {fam.name!r}: {type(fam).__name__} is not a declared kernel "
                           "of any element type")
    return et


def time_sources(families, owners: dict | None = None) -> list[str]:
    """The deck places through which ``families`` make the solution depend on time, by their
    element types' ``time_dependent`` (duplicates removed, order kept)."""
    owners = kernel_types() if owners is None else owners
    return list(dict.fromkeys(s for f in families
                              for s in type_of(f, owners).time_dependent(f)))


def energy_terms(families, owners: dict | None = None) -> tuple:
    """``(family index, fn)`` of the families that add potential energy: their type's
    ``potential_energy`` unless it is :func:`workless`; constraint families never (an ideal
    reaction does no work). In ``families`` order."""
    owners = kernel_types() if owners is None else owners
    out = []
    for i, f in enumerate(families):
        fn = type_of(f, owners).potential_energy
        if fn is not workless and not f.is_constraint:
            out.append((i, fn))
    return tuple(out)
