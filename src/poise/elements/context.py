"""What element compilers build on: the resolved geometry and the typed compile context.

``compile(spec, ctx)`` of every registered element type (:mod:`poise.elements.registry`) reads
the markers and bodies the model compiler resolved (:class:`Geometry`, read-only) and adds what
it builds through the typed methods of :class:`CompileContext`: constraint rows, families,
output groups, continuous angles, scalar unknowns, reaction channels, frame hooks, elements
routed to a later compiler (:meth:`CompileContext.route`). Nothing else is shared between
compilers. :meth:`CompileContext.result` hands the model compiler one :class:`CompileResult`.
This package stays below ``poise.model``: the model compiler builds the :class:`Geometry`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from poise.core.errors import ProblemCollector
from poise.deck.spec import DeckSpec, Element, Expr
from poise.elements.base import GLOBAL
from poise.elements.rows import RowTable, element_where

__all__ = ["GLOBAL", "CompileContext", "CompileResult", "Geometry", "MarkerPoses", "num"]


def num(el: Element, name: str, default=None, pc: ProblemCollector | None = None):
    v = el.attrs.get(name, default)
    if isinstance(v, Expr):
        if pc is not None:
            pc.error(el.loc, f"expression {v.text!r} is not supported here yet; expected a number",
                     name)
        return default if default is not None else 0.0
    return v


class MarkerPoses:
    """Marker id -> (origin (3,), axes (3, 3)) at the input configuration, global components
    (a read-only mapping over the arrays of all markers, ``P[row[id]]``, ``R[row[id]]``)."""

    __slots__ = ("row", "P", "R")

    def __init__(self, row: dict, P: np.ndarray, R: np.ndarray):
        self.row, self.P, self.R = row, P, R

    def __getitem__(self, mid):
        k = self.row[mid]
        return self.P[k], self.R[k]

    def get(self, mid, default=None):
        try:
            k = self.row.get(mid)
        except TypeError:                     # an unhashable id value
            return default
        return default if k is None else (self.P[k], self.R[k])

    def __contains__(self, mid) -> bool:
        try:
            return mid in self.row
        except TypeError:
            return False

    def __iter__(self):
        return iter(self.row)

    def __len__(self) -> int:
        return len(self.row)

    def keys(self):
        return self.row.keys()

    def items(self):
        return ((mid, (self.P[k], self.R[k])) for mid, k in self.row.items())


@dataclass(frozen=True, eq=False)
class Geometry:
    """Markers and bodies as the model compiler resolved them, before any element compiles.

    ``marker_index``: deck marker id -> compiled marker index (0: the global frame);
    ``poses``: deck marker id -> input origin and axes (global); ``marker_elements``: the
    ``Reference_Marker`` elements, compiled index ``k + 1``; ``marker_on_ground`` (nm,): the
    compiled marker carries no coordinates (index 0, the global frame, included);
    ``body_index``: moving body id -> body index; ``body_cg`` (nb,): compiled index of each
    moving body's CG marker; ``body_mass`` (nb,): effective masses; ``L``: the model size.
    """

    marker_index: dict
    poses: MarkerPoses
    marker_elements: tuple
    marker_on_ground: np.ndarray
    body_index: dict
    body_cg: np.ndarray
    body_mass: np.ndarray
    L: float

    def initial_kinematics(self):
        """Marker origins (nm, 3) and axes (nm, 3, 3) by compiled index at the input
        configuration (index 0: the global frame)."""
        nm = len(self.marker_elements) + 1
        P = np.zeros((nm, 3))
        A = np.tile(np.eye(3), (nm, 1, 1))
        for k, e in enumerate(self.marker_elements):
            P[k + 1], A[k + 1] = self.poses[e.id]
        return P, A


@dataclass(frozen=True, eq=False)
class CompileResult:
    """Everything the element compilers built, in compile order (:meth:`CompileContext.result`):
    the model compiler lays it out and builds the frozen model from it in one step.

    ``frame_hooks``: ``hook(model, state) -> {path: array}``; a hook with a ``bind(model)``
    method is bound to the finished model first. ``reaction_channels``: the
    :class:`poise.elements.reaction_feed.ReactionChannels` of forces reading reactions, or None.
    ``element_markers``: ``(tag, id) -> (I, J)`` compiled marker indices of a deck element.
    """

    rows: tuple
    families: tuple
    outputs: dict
    angles: tuple
    extra_names: tuple
    extra0: tuple
    frame_hooks: tuple
    reaction_channels: object
    effects: tuple
    user_routines: tuple
    input_files: dict
    element_markers: Callable


class CompileContext:
    """The typed interface of element compilers (see the module docstring).

    Element compilers are the ``compile(spec, ctx)`` of the registered element types, run in
    dependency order; each only runs work for elements present in the deck.
    """

    def __init__(self, spec: DeckSpec, geometry: Geometry, pc: ProblemCollector,
                 user_code: str = "refuse"):
        self.spec = spec
        self.geometry = geometry
        self.pc = pc
        self.user_code = user_code          # "run" | "refuse" | "skip" (compile_model)
        self._rows = RowTable()      # one entry per element, codes per row (no dict per row)
        self._families: list = []
        self._outputs: dict = {}
        self._angles: list[tuple[int, int, int]] = []
        self._extra_names: list[str] = []
        self._extra0: list[float] = []
        self._frame_hooks: list = []
        self._routes: dict[str, list] = {}
        self._scalars: dict = {}
        self._channels: list[tuple] = []
        self._channel_index: dict = {}
        self._feed = None
        self._effects: list[str] = []
        self._user_routines: list[dict] = []
        self._input_files: dict[str, str] = {}
        self._by_id: dict = {}
        self._last_by_id: dict = {}
        self._resolver = None
        self._element_markers = _ElementMarkers(self)

    # ------------------------------------------------------------------ read: geometry
    @property
    def L(self) -> float:
        return self.geometry.L

    def marker(self, el, attr, required=True) -> int:
        """Compiled index of the marker ``el.attrs[attr]`` (the global frame, with a located
        problem, when it is missing and ``required`` or does not exist)."""
        mid = el.attrs.get(attr)
        if mid is None:
            if required:
                self.pc.error(el.loc, "missing marker reference; expected a marker id", attr)
            return GLOBAL
        index = self.geometry.marker_index
        try:
            k = index.get(mid)
        except TypeError:
            k = None
        if k is None:
            self.pc.error(el.loc, f"marker {mid} does not exist; expected a Reference_Marker id",
                          attr)
            return GLOBAL
        return k

    def marker_pose(self, mid):
        """Input origin and axes of deck marker ``mid``, or None."""
        return self.geometry.poses.get(mid)

    def marker_body(self, mid):
        """The ``body_id`` attribute of deck marker ``mid`` (None if there is no such marker)."""
        e = self.element("Reference_Marker", mid)
        return None if e is None else e.attrs.get("body_id")

    def moving_marker(self, mid) -> bool:
        """Deck marker ``mid`` exists and is on a moving body."""
        return self.marker_body(mid) in self.geometry.body_index

    def element(self, tag: str, eid):
        """First model element ``tag`` with id ``eid`` (None if there is none)."""
        d = self._by_id.get(tag)
        if d is None:
            d = self._by_id[tag] = {}
            for e in self.spec.elements(tag):
                d.setdefault(e.id, e)
        try:
            return d.get(eid)
        except TypeError:          # unhashable id value
            return None

    def elements_by_id(self, tag: str) -> dict:
        """``{id: element}`` of ``tag`` (the last element of an id wins); do not modify."""
        d = self._last_by_id.get(tag)
        if d is None:
            d = self._last_by_id[tag] = {e.id: e for e in self.spec.elements(tag)}
        return d

    # ------------------------------------------------------------------ write: the model
    def add_row(self, el, equation: str, kind: str, group: str, owner: int) -> int:
        """A constraint row (``kind`` ``trans`` | ``rot``) of deck element ``el``, owned by
        instance ``owner`` of output group ``group``; returns its global index."""
        return self._rows.append(el, equation, kind, group, owner)

    def add_family(self, fam) -> None:
        self._families.append(fam)

    def angle(self, I: int, J: int, axis: int) -> int:
        """Register a continuous angle of marker I about marker J's axis (0 x, 1 y, 2 z; 3 the
        rack-and-pinion angle); returns its index into ``State.angle``."""
        self._angles.append((I, J, axis))
        return len(self._angles) - 1

    def add_extra(self, name: str, initial: float = 0.0) -> int:
        """Register a scalar unknown (appended after the bodies' coordinates); returns its index
        into ``State.extra``. ``name`` labels it in messages (e.g. ``"<Control_Diff id=3> y"``).
        Families read it through ``Family.scols``."""
        self._extra_names.append(name)
        self._extra0.append(float(initial))
        return len(self._extra_names) - 1

    def scalar_unknown(self, key, name: str, initial: float) -> int:
        """The scalar unknown registered under ``key`` (e.g. ``("diff", 3)``), registered now
        with ``name`` and ``initial`` on first use."""
        k = self._scalars.get(key)
        if k is None:
            k = self._scalars[key] = self.add_extra(name, initial)
        return k

    def output(self, group: str, tag, ids) -> None:
        """Output group ``group`` holds the elements ``ids`` (``tag``: one tag, or one per
        element); a group another type started is an error (use :meth:`extend_output`)."""
        if group in self._outputs:
            raise RuntimeError(f"output group {group!r} set twice")
        self._outputs[group] = dict(tag=tag, ids=np.asarray(ids, int))

    def extend_output(self, group: str, tags, ids) -> int:
        """Append the elements ``ids`` (``tags``: one tag per element, or one tag when the group
        has one) to output group ``group``; returns the owner index of the first."""
        o = self._outputs.get(group)
        ids = np.asarray(ids, int)
        if o is None:
            self._outputs[group] = dict(tag=tags, ids=ids)
            return 0
        first = len(o["ids"])
        tag = o["tag"]
        if np.ndim(tag) == 0 and np.ndim(tags) == 0 and str(tag) == str(tags):
            new_tag = tag
        else:
            old = [str(tag)] * first if np.ndim(tag) == 0 else list(tag)
            add = [str(tags)] * len(ids) if np.ndim(tags) == 0 else list(tags)
            new_tag = np.array(old + add)
        self._outputs[group] = dict(tag=new_tag,
                                    ids=np.concatenate([o["ids"], ids]).astype(int))
        return first

    def output_ids(self, group: str) -> np.ndarray:
        """The element ids of output group ``group`` so far (empty if none)."""
        o = self._outputs.get(group)
        return np.zeros(0, int) if o is None else o["ids"]

    def effect(self, name: str) -> None:
        """Name an active effect (the results' ``active_effects``, first mention kept)."""
        self._effects.append(name)

    def add_frame_hook(self, hook) -> None:
        """A per-frame output ``hook(model, state) -> {path: array}`` (a ``bind(model)``
        method: bound to the finished model first)."""
        self._frame_hooks.append(hook)

    def route(self, to: str, item) -> None:
        """Hand ``item`` to the element type ``to``, which compiles it later
        (:meth:`routed`): e.g. an expression force whose row the force compiler numbered."""
        self._routes.setdefault(to, []).append(item)

    def routed(self, name: str) -> tuple:
        """The items routed to the element type ``name`` (in routing order)."""
        return tuple(self._routes.get(name, ()))

    def register_channel(self, key: tuple) -> int:
        """Index of the reaction channel ``key`` (registered on first use)."""
        k = self._channel_index.get(key)
        if k is None:
            k = self._channel_index[key] = len(self._channels)
            self._channels.append(key)
        return k

    @property
    def channels(self) -> tuple:
        """The reaction channels registered so far."""
        return tuple(self._channels)

    def set_reaction_channels(self, channels) -> None:
        """The reaction channels forces read (:class:`poise.elements.reaction_feed.
        ReactionChannels`), evaluated inside every evaluation."""
        if self._feed is not None:
            raise RuntimeError("reaction channels set twice")
        self._feed = channels

    def user_routine(self, described: dict, path=None, digest: str | None = None) -> None:
        """Record a Python user routine the deck names (and the script read, by SHA-256)."""
        self._user_routines.append(described)
        if path is not None:
            self._input_files[str(path)] = digest

    def resolver(self, where: str = "forces", reactions: bool = False):
        """The expression resolver of this model (``poise/expr/CONTRACT.md``) for expressions
        of ``where`` (messages), reading reaction channels when ``reactions``; one resolver
        state for all compilers, so scalar unknowns and channels are registered once."""
        from poise.elements.resolver import ModelResolver     # lazy: resolver reads the registry
        if self._resolver is None:
            self._resolver = ModelResolver(self.spec, self)
        return self._resolver.use(where, reactions)

    def element_markers(self, tag, id):
        """(I, J) compiled marker indices of a deck element (J = global frame when absent)."""
        return self._element_markers(tag, id)

    # ------------------------------------------------------------------ the result
    def result(self) -> CompileResult:
        """What the compilers built (problems raised first)."""
        self.pc.raise_if_any()
        unknown = set(self._routes) - set(self._routes_taken())
        if unknown:
            raise RuntimeError(f"items routed to {sorted(unknown)}, which no element type "
                               "compiles")
        return CompileResult(
            rows=self._rows.freeze(), families=tuple(self._families), outputs=dict(self._outputs),
            angles=tuple(self._angles), extra_names=tuple(self._extra_names),
            extra0=tuple(self._extra0), frame_hooks=tuple(self._frame_hooks),
            reaction_channels=self._feed, effects=tuple(dict.fromkeys(self._effects)),
            user_routines=tuple(self._user_routines), input_files=dict(self._input_files),
            element_markers=self._element_markers)

    def close(self) -> None:
        """Drop the expression resolver (it refers back to this context: a reference cycle
        that would keep the parsed deck alive until a cyclic collection)."""
        self._resolver = None

    def _routes_taken(self):
        from poise.elements.registry import element_types          # lazy: registry imports us
        return {et.name for et in element_types()}


class _ElementMarkers:
    """``(tag, id) -> (I, J)`` of deck elements, kept after compilation (reaction channels)."""

    __slots__ = ("_spec", "_index", "_by")

    def __init__(self, ctx: CompileContext):
        self._spec, self._index, self._by = ctx.spec, ctx.geometry.marker_index, {}

    def __call__(self, tag, id):
        d = self._by.get(tag)
        if d is None:
            d = self._by[tag] = {}
            for e in self._spec.elements(tag):
                d.setdefault(e.id, e)
        el = d.get(id)
        if el is None:
            return GLOBAL, GLOBAL
        a = el.attrs
        if "joint_id" in a and "i_marker_id" not in a:
            return self("Constraint_Joint", a["joint_id"])
        i = a.get("i_marker_id", a.get("marker_id"))
        j = a.get("j_marker_id", a.get("j_floating_marker_id"))
        mi = self._index.get(i, GLOBAL) if i is not None else GLOBAL
        mj = self._index.get(j, GLOBAL) if j is not None else GLOBAL
        return mi, mj


def row_equation(row_info, r) -> tuple[str, str]:
    """``(row_where(row_info[r]), its equation)`` of constraint row ``r`` (a
    :class:`~poise.elements.rows.RowTable` gives them without the row's dictionary)."""
    fast = getattr(row_info, "where_equation", None)
    if fast is not None:
        return fast(r)
    ri = row_info[r]
    return row_where(ri), ri["equation"]


def row_where(ri: dict) -> str:
    """``FILE:LINE: <Tag id=N>`` (or ``FILE:LINE: JOINT/3`` for an Adams dataset) of a
    constraint row's element."""
    w = ri.get("where")
    return w if w else element_where(ri["tag"], ri["id"], ri["line"], ri["file"])
