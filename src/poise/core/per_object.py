"""Values made once per long-lived object (a compiled model, an element family) and kept while
it lives: weak-keyed tables, so the values go with the object. Objects without weak
references (a test's namespace standing in for a model) get their value made at every call."""
from __future__ import annotations

import weakref


def table() -> weakref.WeakKeyDictionary:
    """An empty table for :func:`once_per`."""
    return weakref.WeakKeyDictionary()


def once_per(kept: weakref.WeakKeyDictionary, obj, make):
    """``make()`` for ``obj``: made at the first call and kept in ``kept`` while ``obj`` lives."""
    try:
        got = kept.get(obj)
    except TypeError:                  # no weak references: made every time
        return make()
    if got is None:
        got = kept[obj] = make()
    return got
