"""Parsed decks and compiled models kept between runs of one process, keyed by file content.

A script or notebook that solves the same small deck again and again (``poise.solve`` in a
loop, a parameter study through the API) pays the parse and the compile once. An entry is used
only while the file is unchanged: its path (as given and absolute), size, modification time
and the SHA-256 of the bytes read now must all match, so an edited file, even one rewritten
within the same clock tick, is parsed and compiled again. Only small decks are kept
(:data:`MAX_BYTES`, :data:`MAX_N` KKT unknowns, :data:`ENTRIES` of them, least recently used
dropped first), and only decks that read nothing besides themselves (no Adams command file's
model, no user-routine script, no ``--ignore``): their other inputs are not in the key.

Sharing is safe because a :class:`~poise.model.model.Model` is immutable all the way down
(sealed arrays); each run gets its own shallow copy of the :class:`DeckSpec` (its lists), the
elements themselves are never changed by a run.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import stat
import threading
import weakref
from collections import OrderedDict

from poise.deck.spec import DeckSpec

MAX_BYTES = 1 << 16          # deck files larger than this are not kept
MAX_N = 600                  # nor models with more KKT unknowns (the dense-LU range)
ENTRIES = 16                 # decks kept, least recently used dropped first

_lock = threading.Lock()
_entries: OrderedDict = OrderedDict()    # key -> _Entry
_handed: dict = {}                       # id(spec copy) -> key of the entry it came from
_memos: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()   # kept model -> its memo


@dataclasses.dataclass
class _Entry:
    stamp: tuple                         # (size, mtime_ns, sha256)
    spec: DeckSpec
    models: dict = dataclasses.field(default_factory=dict)   # user_code -> Model


def _key_stamp(path):
    """``(key, stamp)`` of a deck path that may be cached, else None."""
    if isinstance(path, DeckSpec) or not isinstance(path, (str, os.PathLike)):
        return None
    p = str(path)
    if p.lower().endswith((".adm", ".acf")):
        return None
    try:                                 # the file's status and bytes from one descriptor
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)      # (a FIFO: no wait for a writer)
        try:
            st = os.fstat(fd)
            if st.st_size > MAX_BYTES or not stat.S_ISREG(st.st_mode):
                return None
            data = b""
            while len(data) <= MAX_BYTES:
                chunk = os.read(fd, MAX_BYTES + 1 - len(data))
                if not chunk:
                    break
                data += chunk
        finally:
            os.close(fd)
    except OSError:
        return None                      # the loader reports it
    if len(data) != st.st_size:
        return None                      # changing while read: not cached
    return (p, os.path.abspath(p)), (st.st_size, st.st_mtime_ns,
                                     hashlib.sha256(data).hexdigest())


def load(path, ignore, loader) -> DeckSpec:
    """The deck at ``path`` (``loader(path, ignore)`` parses it when no unchanged entry is
    kept): a fresh shallow copy each call."""
    ks = None if ignore else _key_stamp(path)
    if ks is None:
        return loader(path, ignore)
    key, stamp = ks
    with _lock:
        e = _entries.get(key)
        if e is not None and e.stamp != stamp:
            del _entries[key]
            e = None
        if e is not None:
            _entries.move_to_end(key)
    if e is None:
        spec = loader(path, ignore)
        if spec.input_files or spec.ignored or spec.sha256 != stamp[2]:
            return spec
        e = _Entry(stamp, spec)
        with _lock:
            _entries[key] = e
            while len(_entries) > ENTRIES:
                _entries.popitem(last=False)
    out = e.spec.copy()
    with _lock:
        if len(_handed) >= 4 * ENTRIES:     # copies whose model was given by the caller
            _handed.clear()
        _handed[id(out)] = (out, key, e)
    return out


def compiled(spec: DeckSpec, user_code: str, compile_fn):
    """The model of ``spec`` (``compile_fn(spec, user_code=...)`` when not kept): a kept
    model only for a spec :func:`load` handed out from an entry still current."""
    with _lock:
        got = _handed.pop(id(spec), None)
    if got is None or got[0] is not spec:
        return compile_fn(spec, user_code=user_code)
    _, key, e = got
    m = e.models.get(user_code)
    if m is not None:
        return m
    m = compile_fn(spec, user_code=user_code)
    if (m.N <= MAX_N and not (getattr(m, "input_files", None) or {})
            and not getattr(m, "user_routines", ())):
        with _lock:
            if _entries.get(key) is e:
                e.models[user_code] = m
                _memos[m] = {}
    return m


def memo(model) -> dict | None:
    """The dict kept beside ``model`` while it is a kept model (:func:`compiled`), else None:
    what a run derives from a kept deck and its model alone (the results' model datasets and
    labels, :mod:`poise.app.runner`) is made once there; it goes with the model."""
    with _lock:
        return _memos.get(model)


def clear() -> None:
    """Forget every kept deck and model."""
    with _lock:
        _entries.clear()
        _handed.clear()
        _memos.clear()
