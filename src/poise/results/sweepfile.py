"""The sweep file (``OUT_DIR/sweep.h5``): one netCDF-4 dataset with a ``case`` dimension.

:class:`SweepWriter` creates every variable up front at its full size (the number of cases
is known), chunked along ``case``, and writes the rows of each finished chunk of cases where
they belong, in any order: memory stays at one chunk. Only what
:mod:`poise.results.schema_sweep` declares is written, with its dtype, rank, ``units``,
``long_name`` and dimensions; the swept parameters and ``time``/``analysis`` are listed as
coordinates. The caller writes into a temporary file and renames it when done
(:mod:`poise.core.atomic`); crash recovery is the caller's journal of finished chunks
(:mod:`poise.app.sweep_journal`), never a half-written HDF5 file. :func:`read_header` and
:func:`read_rows` read a finished file back (a later sweep reusing its cases, the index);
:func:`open_sweep` opens it as an ``xarray.Dataset``.
"""
from __future__ import annotations

import json
import os

import h5py
import numpy as np

from poise.core.errors import require_file
from poise.core.extras import require
from poise.core.version import __version__
from poise.results import schema
from poise.results import schema_sweep as ss
from poise.results.h5objects import STR, Dimensions, attr_value

#: bytes per HDF5 chunk (along ``case``)
CHUNK_BYTES = 1 << 16


class SweepWriter:
    """Write a sweep file at ``path`` (see module doc).

    ``params``: ``[(key, kind, values)]`` of the swept parameters (``values``: one per case);
    ``outputs``: ``[(text, source Item)]`` of the ``--output`` variables (the results
    declaration of ``<group>/<dataset>``); ``time``/``analysis``: the planned frames;
    ``attrs``: the root attributes (declared in the schema)."""

    def __init__(self, path: str, n: int, time, analysis, params, outputs, attrs: dict,
                 files: bool = False):
        self.n = int(n)
        self.f = h5py.File(path, "w", libver=("earliest", "v110"))
        self.long: dict[str, str] = {}
        self.units = str(attrs.get("units", ""))
        f = self.f
        fixed = ss.fixed()
        self.items = {name: it for (kind, name), it in fixed.items() if kind == "dataset"
                      and (name != "file" or files)}
        for text, source in outputs:
            self.items[text] = ss.output_item(text, source)
        self.output_dims = {text: ("case", "frame", *schema.dims(source)[2:])
                            for text, source in outputs}
        scale = f.create_dataset("case", data=np.arange(self.n, dtype=np.int64))
        scale.make_scale("case")
        self._describe(scale, fixed[("dataset", "case")])
        Dimensions.pure_dimension(f, "frame", len(time))
        self.scales = {"case": scale, "frame": f["frame"]}
        self.long = {text: schema.long_name(source) for text, source in outputs}
        coords = []
        for key, kind, values in params:
            it = ss.parameter_item(key, kind)
            self.long[key] = f"swept parameter {key}"
            arr = _storable(values, it.dtype)
            schema.check_array(it, arr, f"sweep file {key}")
            ds = f.create_dataset(key, data=arr, dtype=STR if it.dtype == "str" else None)
            self._describe(ds, it)
            ds.dims[0].attach_scale(scale)
            coords.append(key)
        for name, values in (("time", time), ("analysis", analysis)):
            it = fixed[("dataset", name)]
            arr = np.asarray(values, float if name == "time" else np.int64)
            ds = f.create_dataset(name, data=arr.reshape(len(time)))
            self._describe(ds, it)
            ds.dims[0].attach_scale(self.scales["frame"])
            coords.append(name)
        self.coordinates = " ".join(coords)
        for name, it in self.items.items():
            if name in ("case", "time", "analysis"):
                continue
            self._create(name, it)
        root = {"format": ss.FORMAT, "format_version": ss.FORMAT_VERSION,
                "poise_version": __version__, **attrs, "n_cases": self.n, "n_done": 0,
                "complete": False, "coordinates": self.coordinates}
        self.set_attrs(root)

    # ------------------------------------------------------------------------ creation
    def _describe(self, ds, it) -> None:
        ds.attrs["units"] = schema.unit_string(it.unit, self.units)
        ds.attrs["long_name"] = self.long.get(it.name) or schema.long_name(it)

    def _dims(self, name: str, it) -> tuple:
        return self.output_dims.get(name) or schema.dims(it)

    def _create(self, name: str, it) -> None:
        dims = self._dims(name, it)
        shape = (self.n, *[len(self.f["time"]) if d == "frame" else _size(d)
                           for d in dims[1:]])
        dtype = {"float": np.float64, "int": np.int64, "bool": np.bool_}.get(it.dtype, STR)
        row = int(np.prod(shape[1:], dtype=np.int64)) * (16 if dtype is STR else
                                                         np.dtype(dtype).itemsize)
        rows = max(1, min(self.n, CHUNK_BYTES // max(1, row)))
        fill = {"float": np.nan, "int": ss.NO_INT, "bool": False}.get(it.dtype)
        kw = {} if fill is None else {"fillvalue": fill}
        ds = self.f.create_dataset(name, shape=shape, dtype=dtype,
                                   chunks=(rows, *shape[1:]) if self.n else None, **kw)
        self._describe(ds, it)
        if dims[0] == "case" and name not in ("case",):
            ds.attrs["coordinates"] = self.coordinates
        for k, d in enumerate(dims):
            ds.dims[k].attach_scale(self._scale(d))

    def _scale(self, d: str):
        s = self.scales.get(d)
        if s is None:                       # a fixed-size dimension (axis, channel, ...)
            values = schema.component_values(d)
            if isinstance(values, int):
                Dimensions.pure_dimension(self.f, d, values)
                s = self.f[d]
            else:
                arr = np.asarray(values)
                s = self.f.create_dataset(d, data=arr.astype(object) if arr.dtype.kind == "U"
                                          else arr, dtype=STR if arr.dtype.kind == "U" else None)
                s.attrs["units"] = "" if arr.dtype.kind == "U" else "1"
                s.attrs["long_name"] = schema.component_meaning(d)
                s.make_scale(d)
            self.scales[d] = s
        return s

    def set_attrs(self, attrs: dict) -> None:
        for k in sorted(attrs):
            it = ss.fixed().get(("attr", k))
            if it is None:
                raise schema.UndeclaredError(f"sweep file @{k}: attribute not declared in the "
                                             f"results schema (poise.results.schema_sweep)")
            v = attr_value(attrs[k], k)
            if v is not None:
                self.f.attrs[k] = v

    # ------------------------------------------------------------------------ rows
    def write(self, rows: dict) -> None:
        """Write the rows ``rows`` (``{"case": case numbers, variable: values}``, one entry per
        case, any order) where they belong."""
        cases = np.asarray(rows["case"], np.int64)
        if not len(cases):
            return
        order = np.argsort(cases, kind="stable")
        cases = cases[order]
        runs = _runs(cases)
        for name, it in self.items.items():
            if name in ("case", "time", "analysis") or name not in rows:
                continue
            arr = _storable(np.asarray(rows[name])[order], it.dtype)
            schema.check_array(_rank(it, self._dims(name, it)), arr, f"sweep file {name}")
            ds = self.f[name]
            for a, b, k in runs:           # contiguous runs: one slice write each
                ds[a:b] = arr[k:k + b - a]

    def close(self, n_done: int | None = None, extra: dict | None = None) -> None:
        """Finish the file: ``n_done``/``complete`` and ``extra`` root attributes."""
        if self.f is None:
            return
        try:
            if n_done is not None:
                self.set_attrs({"n_done": int(n_done), "complete": int(n_done) == self.n,
                                **(extra or {})})
        finally:
            self.f.close()
            self.f = None


def _size(d: str) -> int:
    v = schema.component_values(d)
    return v if isinstance(v, int) else len(v)


def _rank(it, dims):
    """``it`` with its full rank (an output's trailing axes) for :func:`schema.check_array`."""
    from dataclasses import replace
    return it if len(it.shape) == len(dims) else replace(it, shape=(*it.shape, *dims[len(
        it.shape):]))


def _runs(cases: np.ndarray) -> list[tuple[int, int, int]]:
    """``(start, stop, offset)`` of the contiguous runs of sorted case numbers."""
    cut = np.nonzero(np.diff(cases) != 1)[0] + 1
    starts = np.concatenate([[0], cut])
    stops = np.concatenate([cut, [len(cases)]])
    return [(int(cases[s]), int(cases[s]) + int(e - s), int(s)) for s, e in zip(starts, stops)]


def _storable(values, dtype: str) -> np.ndarray:
    arr = np.asarray(values)
    if dtype == "str" or dtype == "json":
        out = np.empty(arr.shape, dtype=object)
        for idx, x in np.ndenumerate(arr):
            out[idx] = x.decode("utf-8") if isinstance(x, bytes) else ("" if x is None
                                                                       else str(x))
        return out
    if dtype == "bool":
        return arr.astype(bool)
    if dtype == "int":
        return arr.astype(np.int64)
    return arr.astype(float)


# ---------------------------------------------------------------------------- reading
def read_header(path: str) -> dict | None:
    """The root attributes of the sweep file ``path`` (JSON attributes decoded), its
    ``outputs`` and the parameter keys, or None when it is not a readable complete-or-partial
    poise sweep file."""
    try:
        with h5py.File(path, "r") as f:
            a = {k: _py(v) for k, v in f.attrs.items()}
            if a.get("format") != ss.FORMAT or a.get("format_version") != ss.FORMAT_VERSION:
                return None
            for k in ("parameters", "overrides", "outputs", "ignored"):
                if isinstance(a.get(k), str):
                    a[k] = json.loads(a[k])
            a["n_frames"] = int(f["time"].shape[0])
            a["variables"] = sorted(f.keys())
            return a
    except (OSError, ValueError, KeyError, TypeError):
        return None


def read_rows(path: str, start: int, stop: int, names) -> dict[str, np.ndarray]:
    """``{name: values[start:stop]}`` of the variables ``names`` (strings as ``str``)."""
    out = {}
    with h5py.File(path, "r") as f:
        for name in names:
            ds = f[name]
            if h5py.check_string_dtype(ds.dtype) is not None:
                out[name] = np.asarray(ds.asstr()[start:stop], dtype=object)
            else:
                out[name] = ds[start:stop]
    return out


def _py(v):
    if isinstance(v, bytes):
        return v.decode("utf-8")
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def open_sweep(path):
    """The sweep file at ``path`` as an ``xarray.Dataset`` (opened lazily with h5netcdf):
    dimension ``case`` with the swept parameters as coordinates, ``frame`` with ``time`` and
    ``analysis`` (needs ``poise[xarray]``). A missing file raises ``FileNotFoundError``."""
    require("xarray", "opening a sweep file as a labelled dataset")
    require_file(path, "sweep file")
    import xarray as xr                   # lazy: an optional extra
    return xr.open_dataset(os.fspath(path), engine="h5netcdf")
