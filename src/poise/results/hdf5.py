"""HDF5 results writer and reader.

Layout (documented dataset by dataset in ``docs/results-format.md``)::

    /                       attrs: format, format_version, poise_version, deck, deck_sha256,
                                   status, units, active_effects, command
    /model/...              RunResult.model_datasets
    /timings                attrs: wall time per phase [s] (the only non-reproducible values)
    /counts                 attrs: residual/Jacobian/factorisation counts
    /warnings               (W,) variable-length UTF-8 strings
    /analysis_000           attrs: analysis_type, method, status, message, settings (JSON), + attrs
        time, bodies/..., joints/..., frames/..., iterations/..., ...
    /axis, /analysis_000/frame, ...   netCDF-4 dimension scales (poise.results.h5objects)

Determinism: the same :class:`~poise.results.data.RunResult` always produces the same bytes.
Objects are written in sorted name order, datasets are contiguous (no chunking, no
compression, no filters), object modification times are not recorded (``track_times=False``),
link/attribute creation order is not tracked (HDF5 iterates by name), and the file uses the
default ``libver="earliest"`` object-header format, which stores no timestamps. No ``created``
attribute exists; wall-clock timings live only in ``/timings`` attributes.

Atomicity: the file is built in memory, written to ``.<name>.tmp-<pid>@<host>`` in the destination
directory, fsync'ed, then renamed over the final name with :func:`os.replace`. Any exception removes the
temp file. A process killed mid-write can leave only the hidden temp file, never a partial file
under the final name (:mod:`poise.core.atomic`, which also refuses outputs that are not regular files
or that are the deck itself).
"""
from __future__ import annotations

import json
import os
import time
from typing import Any

import h5py
import numpy as np

from poise.core.atomic import atomic_output
from poise.core.errors import require_file
from poise.core.version import __version__
from poise.results import schema
from poise.results.data import AnalysisResult, RunResult
from poise.results.h5objects import STR as _STR
from poise.results.h5objects import attr_value as _attr_value
from poise.results.h5objects import Dimensions
from poise.results.h5objects import create_dataset as _create_dataset  # noqa: F401 (tests)
from poise.results.h5objects import to_array as _to_array
from poise.results.summary import summarize
from poise.results.usable import ResultsFormatError, check_usable

FORMAT = "poise-results"
FORMAT_VERSION = 1



# ResultsFormatError: the file is not a (usable) poise results file, exit 2 (results/usable.py)


# --------------------------------------------------------------------------------------------
# conversion helpers
# --------------------------------------------------------------------------------------------

def _set_attrs(obj: h5py.HLObject, attrs: dict[str, Any], where: str, scope: str) -> None:
    for key in sorted(attrs):
        schema.declared_item(scope, "attr", key, f"{where}@{key}")
        v = _attr_value(attrs[key], f"{where}@{key}")
        if v is not None:
            obj.attrs[key] = v


def _check_relpath(key: str, where: str) -> list[str]:
    parts = key.split("/")
    if not key or key.startswith("/") or any(p in ("", ".", "..") for p in parts):
        raise ValueError(f"{where}: invalid dataset path {key!r} (must be relative, e.g. 'bodies/id')")
    return parts


def _scope(where: str) -> str:
    """The schema scope of the group at ``where`` ("", "/model", "/analysis_NNN")."""
    return "model" if where == "/model" else "analysis" if where.startswith("/analysis_") \
        else "root"


def _prepare(datasets: dict[str, Any], where: str) -> list[tuple[str, Any, np.ndarray]]:
    """``(key, declaration, array)`` of every dataset of ``datasets`` in sorted order, each
    declared in :mod:`poise.results.schema` (else
    :class:`~poise.results.schema.UndeclaredError`) with the declared dtype and rank."""
    scope = _scope(where)
    out = []
    for key in sorted(datasets):
        _check_relpath(key, where)
        item = schema.declared_item(scope, "dataset", key, f"{where}/{key}")
        arr = _to_array(datasets[key], f"{where}/{key}")
        schema.check_array(item, arr, f"{where}/{key}")
        out.append((key, item, arr))
    return out


def _write_datasets(group: h5py.Group, items: list, where: str, dims: Dimensions) -> None:
    """Every prepared dataset (:func:`_prepare`) with its ``units`` attribute (in the units of
    the file's root ``units`` attribute, written first), ``long_name``, ``coordinates`` (the
    group's id/label datasets sharing a dimension) and dimension scales."""
    units = group.file.attrs.get("units", "")
    groups: dict[tuple, h5py.Group] = {(): group}   # opened subgroups (one lookup per group)
    members: dict[tuple, dict] = {}                 # subgroup -> {dataset name: dims}
    for key, _item, _ in items:
        parts = key.split("/")
        members.setdefault(tuple(parts[:-1]), {})[parts[-1]] = dims.dims[where][key][0]
    for key, item, arr in items:
        parts = key.split("/")
        parent = group
        for k in range(1, len(parts)):
            path = tuple(parts[:k])
            parent = groups.get(path)
            if parent is None:
                parent = groups[path] = groups[path[:-1]].require_group(parts[k - 1])
        attrs = {"long_name": schema.long_name(item)}
        coords = schema.coordinates(members[tuple(parts[:-1])], parts[-1],
                                    dims.dims[where][key][0])
        if coords:
            attrs["coordinates"] = " ".join(coords)
        # contiguous layout, no filters, no timestamps: identical input -> identical bytes
        dsid = _create_dataset(parent, parts[-1], arr, schema.unit_string(item.unit, units),
                               attrs)
        dims.attach(dsid, where, key)
    for sub, names in members.items():        # netCDF: the group's coordinates, all of them
        coords = schema.group_coordinates(names)
        if sub and coords:
            groups[sub].attrs["coordinates"] = " ".join(coords)


def _write_file(result: RunResult, path: str) -> None:
    """Build the file in memory (HDF5 core driver, no backing store), then write its image to
    ``path`` with plain Python I/O: a full disk or a failing device is one clean ``OSError``
    (HDF5 cannot report a failed write while closing a file, and crashes on the half-written
    file afterwards)."""
    with open(path, "wb") as out:          # the name is claimed and writability checked first
        out.write(_file_image(result, path))


def _file_image(result: RunResult, name: str) -> bytes:
    t_start = time.perf_counter()
    with h5py.File(name, "w", driver="core", backing_store=False) as f:
        root_attrs = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "poise_version": __version__,
            "deck": str(result.deck),
            "deck_sha256": str(result.deck_sha256),
            "status": result.status,
            "units": str(result.units),
            "active_effects": [str(e) for e in result.active_effects],
            "command": str(result.command),
        }
        extra = getattr(result, "attrs", None) or {}
        clash = set(extra) & set(root_attrs)
        if clash:
            raise ValueError(f"/: attrs {sorted(clash)} clash with reserved root attributes")
        _set_attrs(f, {**extra, **root_attrs}, "/", "root")

        groups = [("/model", result.model_datasets), ("", {"warnings": np.array(
            [str(w) for w in result.warnings], dtype=object).astype(_STR)})]
        analyses = sorted(result.analyses, key=lambda a: a.index)
        groups += [("/" + analysis_group_name(a.index), a.datasets) for a in analyses]
        prepared = {where: _prepare(ds, where) for where, ds in groups}
        dims = Dimensions(f, prepared)

        model = f.create_group("model")
        dims.define(model, "/model", prepared["/model"])
        _write_datasets(model, prepared["/model"], "/model", dims)

        timings = f.create_group("timings")       # attributes set last (with the write time)
        counts = f.create_group("counts")
        _set_attrs(counts, {k: int(v) for k, v in result.counts.items()}, "/counts", "counts")

        dims.define(f, "", prepared[""])
        _write_datasets(f, prepared[""], "", dims)

        for a in analyses:
            name = analysis_group_name(a.index)
            g = f.create_group(name)
            base = {
                "analysis_type": str(a.analysis_type),
                "method": str(a.method),
                "status": str(a.status),
                "message": str(a.message),
                "settings": a.settings_json(),
            }
            if "time" in a.datasets:
                base["coordinates"] = "time"      # netCDF: the coordinate of `frame`
            clash = set(base) & set(a.attrs)
            if clash:
                raise ValueError(f"/{name}: attrs {sorted(clash)} clash with reserved attributes")
            _set_attrs(g, {**a.attrs, **base}, f"/{name}", "analysis")
            dims.define(g, f"/{name}", prepared[f"/{name}"])
            _write_datasets(g, prepared[f"/{name}"], f"/{name}", dims)

        # the write time covers everything but closing, fsync and rename of this file
        tim = {k: float(v) for k, v in result.timings.items() if k != "write"}
        tim["write"] = time.perf_counter() - t_start
        _set_attrs(timings, tim, "/timings", "timings")
        f.flush()
        return f.id.get_file_image()


def analysis_group_name(index: int) -> str:
    return f"analysis_{int(index):03d}"


def write_results(result: RunResult, path: str) -> None:
    """Write ``result`` to ``path`` atomically (:func:`poise.core.atomic.atomic_output`).

    The data go to ``.<name>.tmp-<pid>@<host>`` next to the target (``path``, or the file it links
    to); after a successful write and fsync the temp file is renamed to the target (replacing
    an existing file). On any exception the temp file is removed and the exception propagates;
    the target is then untouched. Refused (:class:`poise.core.errors.UsageError`): a path that exists
    and is not a regular file, and the deck itself (``result.deck``).
    """
    with atomic_output(path, (getattr(result, "deck", None),), hold_interrupts=True) as tmp:
        _write_file(result, tmp)


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------

def _py(value: Any) -> Any:
    """HDF5 attribute/dataset value -> plain JSON-friendly Python."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "OS":
            return [_py(x) for x in value.tolist()]
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _read_strings(ds: h5py.Dataset) -> np.ndarray:
    return np.asarray(ds.asstr()[()], dtype=object) if ds.shape else np.asarray(ds.asstr()[()])


def _read_dataset(ds: h5py.Dataset) -> np.ndarray:
    try:
        if h5py.check_string_dtype(ds.dtype) is not None:
            data = ds.asstr()[()]
            return np.asarray(data, dtype=str) if isinstance(data, np.ndarray) \
                else np.asarray(data)
        return ds[()]
    except (OSError, RuntimeError, KeyError, ValueError, UnicodeDecodeError) as e:  # damaged
        raise ResultsFormatError(f"{ds.file.filename}: not a usable poise results file: "
                                 f"{ds.name}: unreadable ({' '.join(str(e).split())[:200]})"
                                 ) from None


def _is_dimension(name: str) -> bool:
    """Whether the dataset ``name`` (relative to a scope group) is a netCDF dimension scale
    (``frame``, ``body``, ... : not a declared dataset)."""
    if "/" in name:
        return False
    base, _, n = name.rpartition("_")
    return name in schema.dimension_names() or (n.isdigit() and base in schema.dimension_names())


def _collect(group: h5py.Group) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}

    def visit(name: str, obj: Any) -> None:
        if isinstance(obj, h5py.Dataset) and not _is_dimension(name):
            out[name] = _read_dataset(obj)

    group.visititems(visit)
    return out


def open_checked(path: str) -> h5py.File:
    require_file(path, "results file")       # FileNotFoundError (exit 2 on the command line)
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise ResultsFormatError(f"{path}: not an HDF5 file ({e})") from None
    fmt = _py(f.attrs.get("format"))
    if fmt != FORMAT:
        f.close()
        sweep = "; a sweep file (one row per case): open it with poise.open_sweep(path) or " \
            "xarray.open_dataset(path, engine='h5netcdf')" if fmt == "poise-sweep" else ""
        raise ResultsFormatError(f"{path}: not a poise results file (format={fmt!r}){sweep}")
    version = _py(f.attrs.get("format_version"))
    if version != FORMAT_VERSION:
        f.close()
        raise ResultsFormatError(f"{path}: unsupported format_version {version!r} "
                                 f"(this poise reads {FORMAT_VERSION})")
    try:
        check_usable(f, path)        # metadata only: nothing read yet that could hurt
    except BaseException:
        f.close()
        raise
    return f


def _analysis_groups(f: h5py.File) -> list[tuple[int, h5py.Group]]:
    out = []
    for name in f:
        if name.startswith("analysis_") and isinstance(f[name], h5py.Group):
            try:
                out.append((int(name[len("analysis_"):]), f[name]))
            except ValueError:
                continue
    return sorted(out, key=lambda t: t[0])


_RESERVED = ("analysis_type", "method", "status", "message", "settings", "coordinates")
_ROOT_RESERVED = ("format", "format_version", "poise_version", "deck", "deck_sha256", "status",
                  "units", "active_effects", "command")


def read_results(path: str) -> RunResult:
    """Read a whole results file back into a :class:`RunResult` (inverse of write_results)."""
    with open_checked(path) as f:
        attrs = {k: _py(v) for k, v in f.attrs.items()}
        analyses = []
        for index, g in _analysis_groups(f):
            ga = {k: _py(v) for k, v in g.attrs.items()}
            analyses.append(AnalysisResult(
                index=index,
                analysis_type=ga.get("analysis_type", ""),
                method=ga.get("method", ""),
                status=ga.get("status", ""),
                message=ga.get("message", ""),
                settings=json.loads(ga.get("settings") or "{}"),
                datasets=_collect(g),
                attrs={k: v for k, v in ga.items() if k not in _RESERVED},
            ))
        warnings = [_py(x) for x in _read_strings(f["warnings"]).tolist()] if "warnings" in f else []
        return RunResult(
            deck=attrs.get("deck", ""),
            deck_sha256=attrs.get("deck_sha256", ""),
            units=attrs.get("units", ""),
            active_effects=list(attrs.get("active_effects", [])),
            command=attrs.get("command", ""),
            analyses=analyses,
            model_datasets=_collect(f["model"]) if "model" in f else {},
            timings={k: _py(v) for k, v in f["timings"].attrs.items()} if "timings" in f else {},
            counts={k: _py(v) for k, v in f["counts"].attrs.items()} if "counts" in f else {},
            warnings=warnings,
            attrs={k: v for k, v in attrs.items() if k not in _ROOT_RESERVED},
        )


def read_summary(path: str) -> dict:
    """Summary of a results file for ``poise show`` (plain JSON-serialisable dict).

    Keys: ``file``, ``format``, ``format_version``, ``poise_version``, ``deck``,
    ``deck_sha256``, ``status``, ``units``, ``active_effects``, ``command``, ``warnings``,
    ``timings``, ``counts``, ``model`` (dataset path -> shape) and ``analyses``: one dict per
    analysis with ``index``, ``group``, ``analysis_type``, ``method``, ``status``, ``message``,
    ``settings`` (dict), ``stability`` (class per frame, or ``None``), the fields of
    :class:`poise.results.summary.AnalysisSummary` (``frames``, ``iterations`` summed over the
    frames, ``imbalance`` / ``error`` the worst frame's with ``*_frame`` / ``*_time``,
    ``stability_class`` the worst over the frames with its counts and ``modes``, ...),
    ``reactions_unique`` (or ``None``), ``attrs`` (other attributes) and ``datasets``
    (path -> shape).

    Raises :class:`ResultsFormatError` when ``path`` is not a poise results file.
    """
    with open_checked(path) as f:
        out: dict[str, Any] = {"file": os.fspath(path)}
        for k in ("format", "format_version", "poise_version", "deck", "deck_sha256", "status",
                  "units", "active_effects", "command"):
            out[k] = _py(f.attrs.get(k))
        out["active_effects"] = list(out["active_effects"] or [])
        out["warnings"] = [_py(x) for x in _read_strings(f["warnings"]).tolist()] \
            if "warnings" in f else []
        out["timings"] = {k: _py(v) for k, v in f["timings"].attrs.items()} if "timings" in f else {}
        out["counts"] = {k: _py(v) for k, v in f["counts"].attrs.items()} if "counts" in f else {}

        def shapes(g: h5py.Group) -> dict[str, list[int]]:
            d: dict[str, list[int]] = {}
            g.visititems(lambda n, o: d.__setitem__(n, list(o.shape))
                         if isinstance(o, h5py.Dataset) and not _is_dimension(n) else None)
            return d

        out["model"] = shapes(f["model"]) if "model" in f else {}
        analyses = []
        for index, g in _analysis_groups(f):
            ga = {k: _py(v) for k, v in g.attrs.items()}
            try:
                settings = json.loads(ga.get("settings") or "{}")
            except ValueError:
                settings = {"_raw": ga.get("settings")}
            stability = None
            if "frames/stability" in g:
                stability = [_py(x) for x in _read_strings(g["frames/stability"]).tolist()]
            # the one summary (poise.results.summary), from the per-frame datasets only
            ds = {"time": g["time"][()]} if "time" in g else {}
            if "iterations/iteration" in g and "frames/iterations" not in g:
                ds["iterations/iteration"] = g["iterations/iteration"][()]
            for grp in ("frames", "modes"):
                if grp in g:
                    ds.update({f"{grp}/{k}": _read_dataset(v) for k, v in g[grp].items()
                               if isinstance(v, h5py.Dataset)})
            summ = summarize(AnalysisResult(
                index=index, analysis_type=ga.get("analysis_type", ""),
                method=ga.get("method", ""), status=ga.get("status", ""),
                message=ga.get("message", ""), datasets=ds, attrs=ga)).as_dict()
            analyses.append({
                **summ,
                "group": g.name,
                "settings": settings,
                "stability": stability,
                "reactions_unique": ga.get("reactions_unique"),
                "attrs": {k: v for k, v in ga.items()
                          if k not in _RESERVED and k != "reactions_unique"},
                "datasets": shapes(g),
            })
        out["analyses"] = analyses
        return out
