"""A run's results as labelled arrays: an xarray ``DataTree``, one ``Dataset`` per group, and
per-frame pandas tables (``RunResult.to_xarray`` / ``to_dataframe``; extra ``poise[xarray]``).

Built from the schema, not through a file: the same groups, names, dimensions, coordinates and
``units``/``long_name`` attributes as ``xarray.open_datatree(file, engine="h5netcdf")`` of the
written results file gives. For convenience it adds what a file cannot hold: each group with
a ``frame`` dimension gets the analysis' ``time`` coordinate, and ``time``, ``id`` and ``label``
are indexed, so ``.sel(label="Wrist pin")`` and ``.sel(time=0.5, method="nearest")`` work.
"""
from __future__ import annotations

import numpy as np

from poise.core.extras import require
from poise.core.version import __version__
from poise.results import schema
from poise.results.h5objects import attr_value, dataset_dims

_FEATURE = "labelled arrays (RunResult.to_xarray, to_dataframe)"


def _xr():
    require("xarray", _FEATURE)
    import xarray as xr          # lazy: an optional extra
    return xr


def _variable(xr, it, arr, dims, units: str):
    arr = np.asarray(arr)
    if arr.dtype.kind in "OSU":
        arr = arr.astype(str)
    return xr.Variable(dims, arr, {"units": schema.unit_string(it.unit, units),
                                   "long_name": schema.long_name(it)})


def _attrs(attrs: dict) -> dict:
    out = {}
    for k in sorted(attrs):
        v = attr_value(attrs[k], k)
        if v is not None:
            out[k] = v.astype(str) if isinstance(v, np.ndarray) and v.dtype.kind == "O" else v
    return out


def _nodes(xr, datasets: dict, scope: str, where: str, units: str, attrs: dict) -> dict:
    """``{node path: Dataset}`` of one scope group (``""``, ``/model``, ``/analysis_NNN``)."""
    members: dict[str, dict] = {}
    items = [(key, schema.declared_item(scope, "dataset", key, f"{where}/{key}"),
              np.asarray(datasets[key])) for key in sorted(datasets)]
    dims = dataset_dims(items)
    for key, it, arr in items:
        parent, _, name = key.rpartition("/")
        members.setdefault(parent, {})[name] = (it, arr, dims[key][0])
    out = {where or "/": xr.Dataset(attrs=attrs)}
    for parent, vs in members.items():
        coords = set(schema.group_coordinates(vs)) if parent else set()
        if scope == "analysis" and not parent and "time" in vs:
            coords.add("time")
        var = {n: _variable(xr, it, a, d, units) for n, (it, a, d) in vs.items()}
        path = f"{where}/{parent}" if parent else (where or "/")
        ds = xr.Dataset({n: v for n, v in var.items() if n not in coords},
                        coords={n: v for n, v in var.items() if n in coords},
                        attrs=out[path].attrs if path in out else {})
        out[path] = ds
    return out


def to_datatree(result, convenient: bool = True):
    """The whole run as an ``xarray.DataTree`` (the file's layout; ``convenient``: with the
    ``time`` coordinate on every group with frames and the indexes of the module docstring)."""
    xr = _xr()
    units = str(result.units)
    root_attrs = {**(result.attrs or {}), "format": "poise-results", "format_version": 1,
                  "poise_version": __version__, "deck": str(result.deck),
                  "deck_sha256": str(result.deck_sha256), "status": result.status,
                  "units": units, "active_effects": [str(e) for e in result.active_effects],
                  "command": str(result.command)}
    tree = _nodes(xr, {"warnings": np.asarray([str(w) for w in result.warnings], dtype=str)},
                  "root", "", units, _attrs(root_attrs))
    tree.update(_nodes(xr, result.model_datasets, "model", "/model", units, {}))
    tree["/timings"] = xr.Dataset(attrs=_attrs(dict(result.timings)))
    tree["/counts"] = xr.Dataset(attrs=_attrs(dict(result.counts)))
    used: set[str] = set()
    for a in sorted(result.analyses, key=lambda a: a.index):
        where = f"/analysis_{int(a.index):03d}"
        attrs = {**a.attrs, "analysis_type": str(a.analysis_type), "method": str(a.method),
                 "status": str(a.status), "message": str(a.message),
                 "settings": a.settings_json()}
        nodes = _nodes(xr, a.datasets, "analysis", where, units, _attrs(attrs))
        if convenient and "time" in a.datasets:
            time = nodes[where]["time"].variable
            for path, ds in nodes.items():
                if path != where and "frame" in ds.dims and "time" not in ds.variables:
                    nodes[path] = ds.assign_coords(time=time).set_xindex("time")
        tree.update(nodes)
    for ds in tree.values():
        used |= {d for d in ds.dims if schema.component_dim(d)}
    root = tree["/"]
    for name in sorted(used):
        values = schema.component_values(name)
        if not isinstance(values, int):
            arr = np.asarray(values)
            root = root.assign_coords({name: xr.Variable(
                name, arr.astype(str) if arr.dtype.kind == "U" else arr,
                {"units": "" if arr.dtype.kind == "U" else "1",
                 "long_name": schema.component_meaning(name)})})
    tree["/"] = root
    if convenient:
        tree = {p: _indexed(ds) for p, ds in tree.items()}
    return xr.DataTree.from_dict(tree)


def _indexed(ds):
    """``id`` and ``label`` indexed (``time`` only where :func:`to_datatree` copied it: an
    index in an analysis node would be inherited and hide ``steps/time``)."""
    for name in ("id", "label"):
        if name in ds.coords and ds[name].ndim == 1 and name not in ds.indexes \
                and ds[name].dims[0] != name:
            ds = ds.set_xindex(name)
    return ds


def group_path(result, group: str | None, analysis) -> str:
    """The tree path of ``group`` (``"joints"``, ``"frames"``, ``"model/bodies"``; None: the
    analysis itself) of analysis ``analysis`` (a position in ``result.analyses``)."""
    if group is not None and (group == "model" or group.startswith("model/")):
        return "/" + group
    try:
        a = result.analyses[analysis]
    except IndexError:
        raise IndexError(f"analysis {analysis} out of range: the run has "
                         f"{len(result.analyses)} analyses") from None
    where = f"/analysis_{int(a.index):03d}"
    return where if not group else f"{where}/{group.strip('/')}"


def to_dataframe(result, group: str = "frames", analysis: int = -1):
    """One row per frame of analysis ``analysis`` (index ``frame``, column ``time`` first).

    ``group="frames"``: the per-frame datasets of ``frames/*`` (status, iterations, imbalance,
    stability, ...) as columns. An element group (``"bodies"``, ``"joints"``, ``"requests"``,
    ...): columns ``(quantity, element, component)`` (a ``pandas.MultiIndex``), the element
    being its deck label where the group's labels are unique and non-empty, else its id. Units
    are in ``DataFrame.attrs["units"]`` (quantity -> unit)."""
    _xr()
    import pandas as pd                   # lazy: an optional extra
    a = result.analyses[analysis]
    d = a.datasets
    if "time" not in d:
        raise KeyError(f"analysis {a.index} has no frames")
    prefix = group.strip("/") + "/"
    per_frame = [k for k in sorted(d) if k.startswith(prefix) and "/" not in k[len(prefix):]
                 and np.ndim(d[k]) >= 1 and schema.dims(schema.declared_item(
                     "analysis", "dataset", k, k))[0] == "frame"]
    if not per_frame:
        raise KeyError(f"no per-frame datasets in group {group!r} of analysis {a.index}; "
                       f"groups: {', '.join(sorted({k.split('/')[0] for k in d if '/' in k}))}")
    index = pd.RangeIndex(len(d["time"]), name="frame")
    cols, units = {("time",) : np.asarray(d["time"])}, {"time": result.unit("time")}
    elements = _element_keys(d, group)
    for k in per_frame:
        q = k[len(prefix):]
        it = schema.declared_item("analysis", "dataset", k, k)
        units[q] = result.unit(k)
        arr = np.asarray(d[k])
        if elements is None:          # frames/*: one column, or one per component
            if arr.ndim == 1:
                cols[(q,)] = arr
            elif arr.ndim == 2 and schema.component_dim(schema.dims(it)[1]):
                for c, v in zip(_components(it, 1, arr.shape[1]), np.moveaxis(arr, 1, 0)):
                    cols[(f"{q}.{c}",)] = v
            continue
        if arr.ndim < 2 or schema.dims(it)[1] != _element_dim(d, group):
            cols[(q, "", "")] = arr if arr.ndim == 1 else arr.reshape(len(arr), -1)[:, 0]
            continue
        comps = [""]
        for ax in range(2, arr.ndim):      # trailing axes: x, y, z; xx, xy, ... (3x3)
            comps = [a + b for a in comps for b in _components(it, ax, arr.shape[ax])]
        flat = arr.reshape(arr.shape[0], arr.shape[1], -1)
        names = np.asarray(d.get(f"{group}/channel", [])) if "channel" in schema.dims(it) \
            else None
        for e, key in enumerate(elements):
            for c, comp in enumerate(comps):
                if names is not None and names.ndim == 2 and str(names[e, c]):
                    comp = str(names[e, c])      # a request's own channel names
                cols[(q, key, comp)] = flat[:, e, c]
    if elements is None:
        df = pd.DataFrame({k[0]: v for k, v in cols.items()}, index=index)
    else:
        cols = {(("time", "", "") if k == ("time",) else k): v for k, v in cols.items()}
        df = pd.DataFrame(cols, index=index)
        df.columns = pd.MultiIndex.from_tuples(df.columns,
                                               names=["quantity", "element", "component"])
    df.attrs["units"] = units
    return df


def trim(ds):
    """``ds`` without the inherited fixed-size coordinates (``axis``, ``stage``, ...) that none
    of its other variables uses."""
    used = {d for n, v in ds.variables.items() if not schema.component_dim(str(n))
            for d in v.dims}
    return ds.drop_vars([n for n in ds.coords if schema.component_dim(str(n))
                         and n not in used])


def _element_dim(d: dict, group: str) -> str | None:
    key = f"{group}/id"
    if key not in d:
        return None
    return schema.dims(schema.declared_item("analysis", "dataset", key, key))[0]


def _element_keys(d: dict, group: str) -> list | None:
    """Column keys of the group's elements: labels when unique and non-empty, else ids."""
    if f"{group}/id" not in d:
        return None
    ids = [int(i) for i in np.asarray(d[f"{group}/id"]).ravel()]
    labels = [str(x) for x in np.asarray(d.get(f"{group}/label", [""] * len(ids))).ravel()]
    if all(labels) and len(set(labels)) == len(labels):
        return labels
    return ids


def _components(it, axis: int, n: int) -> list:
    name = schema.dims(it)[axis]
    if schema.component_dim(name):
        values = schema.component_values(name)
        if not isinstance(values, int):
            return [str(v) for v in values][:n]
    return [str(k) for k in range(n)]
