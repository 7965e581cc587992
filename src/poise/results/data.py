"""In-memory results of a run, mirroring the HDF5 layout one to one.

A :class:`RunResult` holds one :class:`AnalysisResult` per ``Simulate`` command. Each analysis
stores its datasets in a flat dict keyed by the HDF5 path *relative to its group*
(``"bodies/position"``, ``"iterations/imbalance"``, ...), so that new capabilities add datasets
without touching the writer. ``docs/results-format.md`` documents every key.

Conventions: leading axis F = output frames; B bodies; J joints; R requests. Lengths, forces and
torques are in the deck's units; angles in radians.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from poise.elements import rotation as rot
from poise.results.schema import declared_item, unit_string
from poise.results.layout import analysis_datasets
from poise.solvers.record import STATUS_CONVERGED, STATUS_FAILED, AnalysisHeader, AnalysisRecord


@dataclass(frozen=True, eq=False)
class AnalysisResult(AnalysisHeader):
    """Result of one ``Simulate`` command: the :class:`~poise.solvers.record.AnalysisHeader`
    (index, analysis_type, method, status, message, settings), ``datasets`` (path relative to
    the analysis group -> array) and group ``attrs``, with readers. String arrays in
    ``datasets`` are numpy ``str_`` arrays; the writer stores them as variable-length UTF-8.
    """

    datasets: dict[str, np.ndarray] = field(default_factory=dict)
    attrs: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, record: AnalysisRecord) -> "AnalysisResult":
        """The result of a solver's record, laid out by :mod:`poise.results.layout`."""
        if isinstance(record, cls):
            return record
        datasets, attrs = analysis_datasets(record)
        return cls(index=record.index, analysis_type=record.analysis_type,
                   method=record.method, status=record.status, message=record.message,
                   settings=record.settings, datasets=datasets, attrs=attrs)

    @property
    def n_frames(self) -> int:
        t = self.datasets.get("time")
        return 0 if t is None else int(len(t))

    @property
    def time(self) -> np.ndarray:
        """Time of each output frame (F,) [time unit]; 0 for a plain static analysis."""
        return np.asarray(self.datasets.get("time", np.zeros(0)))

    def __repr__(self) -> str:
        groups = sorted({k.split("/")[0] for k in self.datasets if "/" in k})
        return (f"<AnalysisResult {self.index}: {self.analysis_type} {self.method} "
                f"{self.status}, {self.n_frames} frame{'s' * (self.n_frames != 1)}; groups: "
                f"{', '.join(groups) or 'none'}>")

    def settings_json(self) -> str:
        return json.dumps(self.settings, sort_keys=True, default=str)

    # ------------------------------------------------------------------ accessors
    # Thin reads of the datasets by element id. ``frame``: an index (default -1, the last
    # frame) or None for every frame (leading axis F).
    def _row(self, group: str, ident) -> int:
        """Row of element ``ident`` (its id, or its deck label) in ``group``'s datasets."""
        ids = np.asarray(self.datasets.get(f"{group}/id", np.zeros(0, int)))
        if isinstance(ident, str):
            labels = [str(x) for x in np.asarray(self.datasets.get(f"{group}/label", []))]
            hit = [k for k, lab in enumerate(labels) if lab == ident]
            if len(hit) != 1:
                raise KeyError(f"{'no' if not hit else 'more than one'} {group[:-1]} labelled "
                               f"{ident!r} in analysis {self.index}; labels: "
                               f"{', '.join(repr(x) for x in labels if x) or 'none'}")
            return hit[0]
        hit = np.nonzero(ids == int(ident))[0]
        if not len(hit):
            raise KeyError(f"no {group[:-1]} with id {ident} in analysis {self.index}; ids: "
                           f"{', '.join(str(int(i)) for i in ids) or 'none'}")
        return int(hit[0])

    def _body(self, key: str, body: int, frame):
        d = self.datasets.get(key)
        if d is None:             # a file written before the dataset existed: derive it
            derive = {"bodies/euler_parameters": rot.euler_parameters,
                      "bodies/euler_313": rot.euler_313}.get(key)
            if derive is None or "bodies/orientation" not in self.datasets:
                raise KeyError(f"{key} is not in analysis {self.index} (a results file "
                               f"written by an older poise?)")
            d = derive(self.datasets["bodies/orientation"])
        v = np.asarray(d)[:, self._row("bodies", body)]
        return v if frame is None else v[frame]

    def position(self, body: int, frame=-1) -> np.ndarray:
        """CG marker origin (3,) of body ``body`` (id), global axes [length]."""
        return self._body("bodies/position", body, frame)

    def orientation(self, body: int, frame=-1) -> np.ndarray:
        """Rotation matrix (3, 3), the CG marker axes as columns in global components."""
        return self._body("bodies/orientation", body, frame)

    def euler_parameters(self, body: int, frame=-1) -> np.ndarray:
        """Euler parameters ``(e0, e1, e2, e3)``, e0 >= 0, of the orientation."""
        return self._body("bodies/euler_parameters", body, frame)

    def euler_313(self, body: int, frame=-1) -> np.ndarray:
        """Body-fixed 3-1-3 angles ``(psi, theta, phi)`` [rad] of the orientation."""
        return self._body("bodies/euler_313", body, frame)

    def rotation_from_input(self, body: int, frame=-1) -> np.ndarray:
        """Continuous rotation vector (3,) from the input orientation [rad], turns counted."""
        return self._body("bodies/rotation_from_input", body, frame)

    def rotation_angle(self, body: int, frame=-1, axis=None):
        """Continuous rotation angle [rad] from the input orientation about ``axis`` ("x",
        "y", "z" or a 3-vector, global): the component of :meth:`rotation_from_input` along
        it. ``axis=None``: the global axis with the largest component over the frames read
        (for a body turning about a fixed global axis, its signed accumulated angle)."""
        v = np.asarray(self.rotation_from_input(body, frame))
        if axis is None:
            k = int(np.argmax(np.abs(v.reshape(-1, 3)).max(axis=0)))
            return v[..., k]
        if isinstance(axis, str):
            u = np.eye(3)["xyz".index(axis.lower())]
        else:
            u = np.asarray(axis, float) / np.linalg.norm(axis)
        return v @ u

    def reaction(self, joint, frame=-1, group: str = "joints"):
        """``(force, torque)`` of element ``joint`` (id or deck label) of ``group``
        (``joints``, ``jprims``, ``motions``, ``forces``, ...): on the I body at the I marker,
        global axes."""
        k = self._row(group, joint)
        F = np.asarray(self.datasets[f"{group}/force"])[:, k]
        T = np.asarray(self.datasets[f"{group}/torque"])[:, k]
        return (F, T) if frame is None else (F[frame], T[frame])

    def request(self, request, channel, frame=-1):
        """Channel of ``Post_Request`` ``request`` (id or deck label): 1..8, or its name as the file's
        ``requests/channel`` gives it (``DM DX DY DZ YAW PITCH ROLL`` for displacement
        requests, ``FM FX FY FZ TM TX TY TZ`` for force requests, ``expr1``..``expr8``;
        case-insensitive; ``f1``..``f8`` also name channels 1..8)."""
        row = self._row("requests", request)
        names = self.datasets.get("requests/channel")
        names = None if names is None else [str(n) for n in np.asarray(names)[row]]
        c = _channel_index(channel, names)
        v = np.asarray(self.datasets["requests/values"])[:, row, c]
        return v if frame is None else v[frame]


_CHANNELS = {**{n: i for i, n in enumerate(("dm", "dx", "dy", "dz", "", "yaw", "pitch", "roll"))
                if n},
             **{n: i for i, n in enumerate(("fm", "fx", "fy", "fz", "tm", "tx", "ty", "tz"))},
             **{f"{p}{i + 1}": i for p in ("f", "expr") for i in range(8)}}


def _channel_index(channel, names=None) -> int:
    """0-based channel of ``channel`` (1..8 or a name); ``names``: the request's own channel
    names (``requests/channel``), searched first."""
    if isinstance(channel, str):
        key = channel.strip().lower()
        if names:
            hit = [k for k, n in enumerate(names) if n and n.lower() == key]
            if hit:
                return hit[0]
        if key in _CHANNELS and (not names or key.startswith(("f", "expr"))
                                 and key[-1].isdigit()):
            return _CHANNELS[key]
    elif int(channel) == channel and 1 <= int(channel) <= 8:
        return int(channel) - 1
    known = [n for n in names if n] if names else [n.upper() for n in _CHANNELS]
    raise KeyError(f"request channel {channel!r}; expected 1..8 or one of {', '.join(known)}")


@dataclass
class RunResult:
    """Result of running every analysis of one deck.

    Attributes
    ----------
    deck : str
        Deck path as given.
    deck_sha256 : str
    units : str
        Description of the deck's units, e.g. ``"force=NEWTON mass=KILOGRAM length=MILLIMETER time=SECOND"``.
    active_effects : list[str]
        Element families compiled and evaluated for this deck (e.g. ``["gravity", "revolute",
        "spring_translational"]``).
    command : str
        The command line (or API call) that produced the run.
    analyses : list[AnalysisResult]
    model_datasets : dict[str, numpy.ndarray]
        Datasets under ``/model`` (ids, labels, masses, dof counts ...).
    timings : dict[str, float]
        Wall time per phase in seconds (``parse``, ``compile``, ``solve``, ``write``, ...).
    counts : dict[str, int]
        Residual / Jacobian / factorisation counts summed over the run.
    warnings : list[str]
        Located warnings emitted while reading/compiling the deck.
    attrs : dict[str, Any]
        Extra root attributes (e.g. ``run_overrides``, ``sweep_case_hash`` written by
        ``poise batch``/``poise sweep``); may not clash with the reserved root attributes.
    """

    deck: str
    deck_sha256: str
    units: str = ""
    active_effects: list[str] = field(default_factory=list)
    command: str = ""
    analyses: list[AnalysisResult] = field(default_factory=list)
    model_datasets: dict[str, np.ndarray] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def status(self) -> str:
        if self.analyses and all(a.converged for a in self.analyses):
            return STATUS_CONVERGED
        return STATUS_FAILED

    @property
    def exit_code(self) -> int:
        return 0 if self.status == STATUS_CONVERGED else 1

    # ------------------------------------------------------------------ accessors
    # Same reads as AnalysisResult's, on analysis ``analysis`` (default the last); bodies by id
    # or label (``/model/bodies/label``).
    def body_id(self, body) -> int:
        """The id of body ``body`` (an id, or a label)."""
        if isinstance(body, str):
            labels = [str(x) for x in np.asarray(self.model_datasets.get("bodies/label", []))]
            ids = np.asarray(self.model_datasets.get("bodies/id", []))
            hit = [int(i) for i, l in zip(ids, labels) if l == body]
            if len(hit) != 1:
                raise KeyError(f"{'no' if not hit else 'more than one'} body labelled {body!r}; "
                               f"labels: {', '.join(map(repr, labels)) or 'none'}")
            return hit[0]
        return int(body)

    def position(self, body, frame=-1, analysis: int = -1):
        return self.analyses[analysis].position(self.body_id(body), frame)

    def orientation(self, body, frame=-1, analysis: int = -1):
        return self.analyses[analysis].orientation(self.body_id(body), frame)

    def euler_parameters(self, body, frame=-1, analysis: int = -1):
        return self.analyses[analysis].euler_parameters(self.body_id(body), frame)

    def euler_313(self, body, frame=-1, analysis: int = -1):
        return self.analyses[analysis].euler_313(self.body_id(body), frame)

    def rotation_from_input(self, body, frame=-1, analysis: int = -1):
        return self.analyses[analysis].rotation_from_input(self.body_id(body), frame)

    def rotation_angle(self, body, frame=-1, axis=None, analysis: int = -1):
        return self.analyses[analysis].rotation_angle(self.body_id(body), frame, axis)

    def reaction(self, joint, frame=-1, group: str = "joints", analysis: int = -1):
        """``(force, torque)`` of joint ``joint`` (id or label; ``group="forces"``,
        ``"motions"``, ... for other elements) on its I body at the I marker, global axes."""
        return self.analyses[analysis].reaction(joint, frame, group)

    def request(self, request, channel, frame=-1, analysis: int = -1):
        """Channel ``channel`` (1..8 or a name such as ``"FX"``) of ``Post_Request``
        ``request`` (id or label)."""
        return self.analyses[analysis].request(request, channel, frame)

    @property
    def time(self) -> np.ndarray:
        """Output times (F,) of the last analysis [time unit] (``analyses[k].time`` for
        another)."""
        return self.analyses[-1].time if self.analyses else np.zeros(0)

    def to_xarray(self, group: str | None = None, analysis: int | None = None):
        """The results as labelled arrays (needs ``pip install 'poise[xarray]'``).

        No arguments: an ``xarray.DataTree`` with the results file's layout (``/model``,
        ``/analysis_000/joints``, ...; the groups, names, dimensions, coordinates, units and
        long names of ``xarray.open_datatree(file, engine="h5netcdf")``), plus the analysis'
        ``time`` coordinate on each group with frames and indexes on ``time``, ``id`` and
        ``label``. ``group="joints"`` (``"bodies"``, ``"frames"``, ``"model/bodies"``, ...):
        that group of analysis ``analysis`` (default the last) as an ``xarray.Dataset``, e.g.
        ``r.to_xarray("joints").force.sel(label="Wrist pin")``. ``analysis=k`` alone: that
        analysis' node of the tree."""
        from poise.results import labelled      # lazy: the optional extra poise[xarray]
        tree = labelled.to_datatree(self)
        if group is None and analysis is None:
            return tree
        path = labelled.group_path(self, group, -1 if analysis is None else analysis)
        try:
            node = tree[path]
        except KeyError:
            raise KeyError(f"no group {path} in the results; groups: "
                           f"{', '.join(n.path for n in tree.subtree if n.path != '/')}"
                           ) from None
        return node if group is None else labelled.trim(node.to_dataset())

    def to_dataframe(self, group: str = "frames", analysis: int = -1):
        """A ``pandas.DataFrame`` with one row per frame of analysis ``analysis``: ``frames``
        (status, iterations, imbalance, stability, ...) or an element group's per-frame
        datasets (columns ``(quantity, element, component)``); units in ``df.attrs["units"]``
        (:func:`poise.results.labelled.to_dataframe`; needs ``poise[xarray]``)."""
        from poise.results import labelled      # lazy: the optional extra poise[xarray]
        return labelled.to_dataframe(self, group, analysis)

    def __repr__(self) -> str:
        an = "; ".join(f"{a.index}: {a.analysis_type} {a.method} {a.status}, {a.n_frames} "
                       f"frame{'s' * (a.n_frames != 1)}" for a in self.analyses)
        return (f"<RunResult {self.deck!r}: {self.status}; analyses [{an}]; "
                f"units {self.units or '?'}>")

    def unit(self, path: str) -> str:
        """The unit of dataset ``path`` in this run's units, as its ``units`` attribute in
        the file says (``"bodies/position"`` -> ``"mm"``; ``"model/bodies/mass"`` for
        ``/model``): from the results schema, so results read from older files have it too."""
        scope, name = ("model", path[6:]) if path.startswith("model/") else ("analysis", path)
        return unit_string(declared_item(scope, "dataset", name, path).unit, self.units)
