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
#: exact types skipped before they are pushed (most items of a model's tuples and dicts)
_SCALARS = frozenset((str, int, float, bool, type(None)))
_SLOTS: dict = {}


def slot_names(cls) -> tuple:
    """The names ``cls`` and its bases keep in ``__slots__`` (cached per class; a single
    name may be given as a string)."""
    names = _SLOTS.get(cls)
    if names is None:
        names = []
        for c in cls.__mro__:
            s = c.__dict__.get("__slots__", ())
            names += [n for n in ((s,) if isinstance(s, str) else s)
                      if n not in ("__dict__", "__weakref__")]
        names = _SLOTS[cls] = tuple(names)
    return names


def reachable(root, skip=()):
    """Every object reachable from ``root`` (each once), depth first. Dict keys are not
    entered (hashable: never an array, nor holding one in a model), nor the objects ``skip``
    (the caller knows they hold none: large tables of text and numbers)."""
    seen: set[int] = {id(o) for o in skip}
    stack = [root]
    while stack:
        o = stack.pop()
        if id(o) in seen or isinstance(o, _LEAVES):
            continue
        seen.add(id(o))
        yield o
        t = type(o)
        if t is np.ndarray:
            if o.dtype == object:
                stack.extend(o.ravel().tolist())
            elif o.base is not None:
                stack.append(o.base)
            continue
        if t is dict:
            stack.extend([v for v in o.values() if type(v) not in _SCALARS])
            continue
        if t is tuple or t is list or isinstance(o, (list, tuple, set, frozenset)):
            stack.extend([v for v in o if type(v) not in _SCALARS])
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
            stack.extend([v for v in d.values() if type(v) not in _SCALARS])
        for s in slot_names(t):
            v = getattr(o, s, None)
            if v is not None:
                stack.append(v)


def _filled(cell) -> bool:
    try:
        _ = cell.cell_contents
    except ValueError:                      # an empty cell
        return False
    return True


def seal(root, skip=()):
    """Make every array reachable from ``root`` read-only; returns ``root``. ``skip``: objects
    known to hold no array (not entered)."""
    for o in reachable(root, skip):
        if isinstance(o, np.ndarray) and o.flags.writeable:
            o.flags.writeable = False
    return root
