"""Everything reachable from an object, and a snapshot of its mutable state (tests of the
immutable compiled model).

The walk follows what the garbage collector sees (:func:`gc.get_referents`): attributes,
``__slots__``, container items, array bases, bound methods' objects and the closure cells and
defaults of poise's own functions. It does not enter modules, classes, code objects, function
globals, nor user code (functions of deck scripts), so it sees exactly what a model holds.
"""
from __future__ import annotations

import gc
import types

import numpy as np

_SKIP = (types.ModuleType, type, types.CodeType, types.BuiltinFunctionType, str, bytes, int,
         float, complex, bool, type(None), np.generic, np.dtype, types.FrameType)


def reachable(root) -> dict:
    """``{id: (object, path)}`` of every object reachable from ``root`` (path: how it was
    first reached, for messages)."""
    out: dict = {}
    stack = [(root, "model")]
    while stack:
        o, path = stack.pop()
        if isinstance(o, _SKIP) or id(o) in out:
            continue
        out[id(o)] = (o, path)
        if isinstance(o, types.FunctionType):
            if not (o.__module__ or "").startswith("poise"):
                continue                                    # user code: not entered
            kids = [c.cell_contents for c in (o.__closure__ or ()) if _filled(c)]
            kids += list(o.__defaults__ or ())
            stack += [(k, f"{path}<closure>") for k in kids]
            continue
        if isinstance(o, dict):
            stack += [(v, f"{path}[{k!r}]") for k, v in o.items()]
            stack += [(k, f"{path}.<key>") for k in o]
            continue
        d = getattr(o, "__dict__", None) if not isinstance(o, (list, tuple, np.ndarray)) \
            else None
        if isinstance(d, dict):
            stack += [(v, f"{path}.{k}") for k, v in d.items()]
        for r in gc.get_referents(o):
            if r is d or isinstance(r, _SKIP):
                continue
            if isinstance(r, dict) and r is getattr(o, "__dict__", None):
                continue
            stack.append((r, f"{path}.<{type(r).__name__}>"))
    return out


def _filled(cell) -> bool:
    try:
        _ = cell.cell_contents
    except ValueError:
        return False
    return True


def state(o):
    """What may change in ``o`` without a new object: its attribute names, container keys or
    length, an array's writeable flag and bytes."""
    if isinstance(o, np.ndarray):
        return ("array", o.flags.writeable, o.shape,
                o.tobytes() if o.dtype != object else len(o))
    if isinstance(o, dict):
        return ("dict", frozenset(map(repr, o.keys())))
    if isinstance(o, (list, set, bytearray)):
        return (type(o).__name__, len(o))
    attrs = set(getattr(o, "__dict__", {}) or {})
    for cls in type(o).__mro__:
        for s in getattr(cls, "__slots__", ()):
            if s not in ("__dict__", "__weakref__") and hasattr(o, s):
                attrs.add(s)
    return ("object", frozenset(attrs))


def snapshot(root) -> dict:
    """``{id: (path, state)}`` of everything reachable from ``root``."""
    return {k: (p, state(o)) for k, (o, p) in reachable(root).items()}
