"""Is an HDF5 file a usable poise results file? Checked before any data of it is read.

``poise show``, ``plot`` and ``animate`` read files from anywhere: damaged (bit flips), edited
by hand or by another tool, or made to be hostile. :func:`check_usable` walks the file's
metadata (no data is read) and refuses, with :class:`ResultsFormatError` (exit 2)
``FILE: not a usable poise results file: /analysis_000/time: ...``:

* links to other files, soft links, virtual or externally stored datasets (poise writes none:
  reading them would open other files, e.g. ``/etc/passwd``), null dataspaces;
* a declared dataset (:mod:`poise.results.schema`) whose dtype kind, rank or fixed axis
  (``3`` of a position) differs from its declaration (a frame count that disagrees with the
  others is read: such a file is written rather than lost, and conformance names it);
* an analysis without ``time`` or ``bodies/position`` (every poise file has them), or whose
  ``settings`` attribute is not a JSON object;
* more data than the memory available (a dataset declaring 745 GiB is named, never
  allocated);
* anything HDF5 cannot read while walking it (damaged metadata), naming the object.

Undeclared objects (a newer poise, another tool's additions) are allowed; their size counts.
"""
from __future__ import annotations

import json
import os
import re

import h5py

from poise.core.errors import UsageError
from poise.results.schema import DTYPE_KINDS, lookup, shape_text

#: datasets every analysis group of a poise file has, whatever its method or age
_REQUIRED = ("time", "bodies/position")


class ResultsFormatError(UsageError, ValueError):
    """The file is not a (usable) poise results file: a usage error (exit 2); also a ValueError
    (what it was before)."""


class _Unusable(Exception):
    def __init__(self, where: str, what: str):
        super().__init__(f"{where}: {what}")


def check_usable(f: h5py.File, path) -> None:
    """Raise :class:`ResultsFormatError` when ``f`` (open, ``format`` checked) cannot be read
    as a poise results file (see the module doc)."""
    walk = _Walk()
    try:
        walk.group(f, "root", "")
        for inst, names in walk.analyses.items():
            for name in _REQUIRED:
                if name not in names:
                    raise _Unusable(inst, f"no dataset {name!r} (every poise analysis has one)")
        avail = _available_memory()
        if avail is not None and walk.nbytes > avail:
            where, size, shape = walk.largest
            raise _Unusable(where, f"declares {_gib(size)} of data (shape {shape}; "
                            f"{_gib(walk.nbytes)} in all), more than the {_gib(avail)} of "
                            "memory available")
    except _Unusable as e:
        raise ResultsFormatError(f"{os.fspath(path)}: not a usable poise results file: {e}") \
            from None
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as e:   # damaged metadata
        raise ResultsFormatError(f"{os.fspath(path)}: not a usable poise results file: "
                                 f"{walk.where or '/'}: unreadable "
                                 f"({' '.join(str(e).split())[:200]})") from None


class _Walk:
    def __init__(self):
        self.where = ""
        self.nbytes = 0
        self.largest = ("/", 0, ())
        self.analyses: dict[str, set] = {}

    def group(self, g: h5py.Group, scope: str, inst: str, rel: str = "") -> None:
        for name in g:
            self.where = f"{g.name.rstrip('/')}/{name}"
            link = g.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                raise _Unusable(self.where, f"a link to another file ({link.filename}:"
                                f"{link.path}); poise files have none")
            if isinstance(link, h5py.SoftLink):
                raise _Unusable(self.where, f"a soft link (to {link.path}); poise files have "
                                "none")
            obj = g[name]
            sub = f"{rel}{name}"
            if isinstance(obj, h5py.Group):
                if scope == "root" and re.fullmatch(r"analysis_\d{3}", name):
                    self._settings(obj)
                    self.analyses[self.where] = set()
                    self.group(obj, "analysis", self.where)
                elif scope == "root" and name == "model":
                    self.group(obj, "model", self.where)
                else:
                    self.group(obj, scope, inst, sub + "/")
            elif isinstance(obj, h5py.Dataset):
                self.dataset(obj, scope, inst, sub)

    def _settings(self, g: h5py.Group) -> None:
        text = g.attrs.get("settings")
        if text is None:
            return
        text = text.decode("utf-8", "replace") if isinstance(text, bytes) else str(text)
        try:
            ok = isinstance(json.loads(text), dict)
        except ValueError:
            ok = False
        if not ok:
            raise _Unusable(f"{g.name}@settings", "not a JSON object")

    def dataset(self, ds: h5py.Dataset, scope: str, inst: str, rel: str) -> None:
        where = self.where
        if ds.shape is None:
            raise _Unusable(where, "no data (a null dataspace)")
        if ds.is_virtual:
            raise _Unusable(where, "a virtual dataset (data in other files); poise writes none")
        if ds.external:
            raise _Unusable(where, "data stored in external files; poise writes none")
        size = int(ds.size) * int(ds.dtype.itemsize)
        self.nbytes += size
        if size > self.largest[1]:
            self.largest = (where, size, ds.shape)
        if scope == "analysis":
            self.analyses[inst].add(rel)
        it = lookup(scope, "dataset", rel)
        if it is None:
            return
        kind = "O" if h5py.check_string_dtype(ds.dtype) is not None else ds.dtype.kind
        if kind not in DTYPE_KINDS[it.dtype]:
            raise _Unusable(where, f"dtype {ds.dtype}, declared {it.dtype}")
        if len(ds.shape) != len(it.shape):
            raise _Unusable(where, f"shape {ds.shape}, declared {shape_text(it.shape)}")
        for n, s in zip(ds.shape, it.shape):
            if isinstance(s, int) and n != s:
                raise _Unusable(where, f"shape {ds.shape}, declared {shape_text(it.shape)}")


def _available_memory() -> int | None:
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _gib(n: int) -> str:
    return f"{n / 2**30:.3g} GiB"
