"""Low-level HDF5 objects of a results file: arrays to storable arrays, contiguous datasets
written through h5py's low-level API, and the netCDF-4 dimension scales.

A netCDF-4 dimension is an HDF5 dimension scale in the group that defines it; the datasets of
that group and of its subgroups attach to it (``DIMENSION_LIST``), which is what
``h5netcdf``/``xarray`` read as named dimensions. The names come from the schema
(:mod:`poise.results.schema_dims`).
"""
from __future__ import annotations

import functools
import json
from typing import Any

import h5py
import numpy as np

from poise.results import schema

STR = h5py.string_dtype("utf-8")


def to_array(value: Any, what: str) -> np.ndarray:
    """Convert a dataset value to an array HDF5 can store deterministically."""
    arr = np.asarray(value)
    kind = arr.dtype.kind
    if kind in "US" or (kind == "O" and all(isinstance(x, (str, bytes)) for x in arr.flat)):
        out = np.empty(arr.shape, dtype=STR)
        for idx, x in np.ndenumerate(arr):
            out[idx] = x.decode("utf-8") if isinstance(x, bytes) else str(x)
        return out
    if kind in "biuf":
        return arr
    raise TypeError(f"{what}: cannot store dtype {arr.dtype} in HDF5 results")



def attr_value(value: Any, what: str) -> Any:
    """Convert an attribute value; ``None`` means "do not write"."""
    if value is None:
        return None
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return np.bool_(value)
    if isinstance(value, (int, np.integer)):
        return np.int64(value)
    if isinstance(value, (float, np.floating)):
        return np.float64(value)
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True, default=str)
    if isinstance(value, (list, tuple, np.ndarray)):
        arr = np.asarray(value) if len(value) else np.asarray(value, dtype=STR)
        if arr.dtype.kind == "O" and not all(isinstance(x, (str, bytes)) for x in arr.flat):
            return json.dumps(list(value), sort_keys=True, default=str)
        return to_array(arr, what)
    return str(value)


@functools.cache
def _dcpl():
    """The dataset-creation property list every results dataset shares (built once)."""
    from h5py import h5p
    dcpl = h5p.create(h5p.DATASET_CREATE)
    dcpl.set_obj_track_times(False)
    dcpl.set_attr_creation_order(0)
    return dcpl


@functools.cache
def _units_type():
    """(datatype, dataspace) of a ``units`` attribute: a scalar variable-length UTF-8 string,
    as ``ds.attrs["units"] = "mm"`` would write it."""
    from h5py import h5s, h5t
    return h5t.py_create(STR, logical=1), h5s.create(h5s.SCALAR)


def create_dataset(parent: h5py.Group, name: str, arr: np.ndarray, units: str | None = None,
                    attrs: dict | None = None):
    """A contiguous dataset through h5py's low-level API; returns its id.

    The bytes equal ``parent.create_dataset(name, data=arr, dtype=arr.dtype,
    track_times=False)`` (same creation property list: no chunks, no filters, no timestamps,
    attribute creation order not tracked; same datatype and dataspace calls; default
    link-creation list), but the property list is built once per process (:func:`_dcpl`)
    instead of once per dataset: a small deck's results file has ~50 datasets, and the
    high-level call cost ~0.25 ms each. ``units`` and ``attrs`` (text) become scalar UTF-8
    string attributes.
    """
    from h5py import h5d, h5s, h5t
    if not arr.flags.c_contiguous:     # (np.ascontiguousarray would make 0-d arrays 1-d)
        arr = arr.copy(order="C")
    dsid = h5d.create(parent.id, name.encode("utf-8"), h5t.py_create(arr.dtype, logical=1),
                      h5s.create_simple(arr.shape), dcpl=_dcpl())
    dsid.write(h5s.ALL, h5s.ALL, arr)
    text = dict(attrs or {})
    if units is not None:
        text["units"] = units
    for k in sorted(text):
        _text_attr(dsid, k, text[k])
    return dsid


def _text_attr(oid, name: str, value: str) -> None:
    from h5py import h5a
    tid, space = _units_type()
    h5a.create(oid, name.encode("utf-8"), tid, space).write(np.array(value, dtype=STR))


_NOT_A_VARIABLE = b"This is a netCDF dimension but not a netCDF variable."


class Dimensions:
    """The dimension scales of one results file (netCDF-4: a dimension is an HDF5 dimension
    scale in the group that defines it; datasets of that group and its subgroups attach to
    it). Fixed-size dimensions (``axis``, ``stage``, ...) are created at the root with their
    coordinate values, symbol dimensions (``frame``, ``body``, ...) in each scope group."""

    def __init__(self, f: h5py.File, prepared: dict):
        self.scales: dict[tuple[str, str], Any] = {}     # (group path, dim) -> dataset id
        self.dims: dict[str, dict] = {}                  # group path -> dataset_dims()
        used = sorted({d for items in prepared.values() for _, it, _ in items
                       for d in schema.dims(it) if schema.component_dim(d)})
        for name in used:
            values = schema.component_values(name)
            if isinstance(values, int):
                self.scales[("", name)] = self.pure_dimension(f, name, values)
            else:
                arr = to_array(np.asarray(values), name)
                dsid = create_dataset(f, name, arr, "" if arr.dtype.kind == "O" else "1",
                                       {"long_name": schema.component_meaning(name)})
                from h5py import h5ds
                h5ds.set_scale(dsid, name.encode())
                self.scales[("", name)] = dsid

    @staticmethod
    def pure_dimension(group: h5py.Group, name: str, n: int):
        """A netCDF dimension that is not a variable (as netCDF-C writes it: float32, no data
        stored)."""
        from h5py import h5d, h5ds, h5s, h5t
        dsid = h5d.create(group.id, name.encode(), h5t.py_create(np.dtype("f4"), logical=1),
                          h5s.create_simple((n,)), dcpl=_dcpl())
        h5ds.set_scale(dsid, _NOT_A_VARIABLE + b"%10d" % n)
        return dsid

    def define(self, group: h5py.Group, where: str, items: list) -> None:
        """The symbol dimensions the datasets ``items`` of group ``where`` use, with their
        sizes (:func:`dataset_dims`)."""
        self.dims[where] = dataset_dims(items)
        sizes = {d: n for ds, shape in self.dims[where].values() for d, n in zip(ds, shape)
                 if not schema.component_dim(d)}
        for d in sorted(sizes):
            self.scales[(where, d)] = self.pure_dimension(group, d, sizes[d])

    def attach(self, dsid, where: str, key: str) -> None:
        from h5py import h5ds
        for k, d in enumerate(self.dims[where][key][0]):
            h5ds.attach_scale(dsid, self.scales[("" if schema.component_dim(d) else where, d)],
                              k)


def dataset_dims(items: list) -> dict[str, tuple[tuple, tuple]]:
    """``{key: (dimension names, shape)}`` of one scope group's prepared datasets ``items``
    (``(key, declaration, array)``). netCDF gives a dimension one size: a dataset whose axis
    disagrees with the size most datasets give it (a capability writing inconsistent shapes)
    gets the dimension ``<name>_<size>`` instead, so the file is still written and readable;
    :func:`poise.results.schema.conformance` reports the inconsistency."""
    from collections import Counter
    count: dict[str, Counter] = {}
    for _, it, arr in items:
        for d, n in zip(schema.dims(it), arr.shape):
            count.setdefault(d, Counter())[n] += 1
    size = {d: c.most_common(1)[0][0] for d, c in count.items()}
    out = {}
    for key, it, arr in items:
        names = tuple(d if n == size[d] or schema.component_dim(d) else f"{d}_{n}"
                      for d, n in zip(schema.dims(it), arr.shape))
        out[key] = (names, arr.shape)
    return out
