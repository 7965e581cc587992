"""Deep read-only: every array reachable from an object made non-writeable.

A compiled model is immutable all the way down (:mod:`poise.model.layout`): its own arrays and
those of its element families, kernels' parameters, expression programs, splines, assembler and
everything inside tuples, lists and dicts. :func:`seal` walks the object graph once (attributes,
``__slots__``, containers, closures of poise's own functions) and clears numpy's ``writeable``
flag; a kernel that wrote into a parameter would then fail at once instead of changing the next
solve's answer. User code (functions of deck scripts) is not entered.
"""
from __future__ import annotations

import types

import numpy as np

_LEAVES = (str, bytes, int, float, complex, bool, type(None), type, types.ModuleType,
           types.BuiltinFunctionType, np.generic, np.dtype)


def reachable(root):
    """Every object reachable from ``root`` (each once), depth first."""
    seen: set[int] = set()
    stack = [root]
    while stack:
        o = stack.pop()
        if isinstance(o, _LEAVES) or id(o) in seen:
            continue
        seen.add(id(o))
        yield o
        if isinstance(o, np.ndarray):
            if o.dtype == object:
                stack.extend(o.ravel().tolist())
            elif o.base is not None:
                stack.append(o.base)
            continue
        if isinstance(o, dict):
            stack.extend(o.keys())
            stack.extend(o.values())
            continue
        if isinstance(o, (list, tuple, set, frozenset)):
            stack.extend(o)
            continue
        if isinstance(o, types.MethodType):
            stack.append(o.__self__)
            continue
        if isinstance(o, types.FunctionType):
            if (o.__module__ or "").startswith("poise"):       # not user code
                stack.extend(c.cell_contents for c in (o.__closure__ or ())
                             if _filled(c))
                stack.extend(o.__defaults__ or ())
            continue
        d = getattr(o, "__dict__", None)
        if d is not None:
            stack.extend(d.values())
        for cls in type(o).__mro__:
            for s in getattr(cls, "__slots__", ()):
                if s not in ("__dict__", "__weakref__") and hasattr(o, s):
                    stack.append(getattr(o, s))


def _filled(cell) -> bool:
    try:
        _ = cell.cell_contents
    except ValueError:                      # an empty cell
        return False
    return True


def seal(root):
    """Make every array reachable from ``root`` read-only; returns ``root``."""
    for o in reachable(root):
        if isinstance(o, np.ndarray) and o.flags.writeable:
            o.flags.writeable = False
    return root
