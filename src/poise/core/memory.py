"""Freed memory handed back to the operating system after the big stages of a large run.

CPython and numpy free through the C library's allocator, and glibc keeps freed heap pages
resident: after a 10⁵-link deck's parse (millions of short-lived records) or once the parsed deck
is dropped, hundreds of MB stay in the process's resident set, free but not returned, and every
later peak (the factorisations) stacks on them. :func:`release` asks glibc to return them
(``malloc_trim(0)``: whole free pages anywhere in the heap). It is called only after large
stages (callers pass the size that was freed), costs a few milliseconds, and is a no-op where
the C library is not glibc (macOS, Windows, musl).

Inside a large solve the freed memory is worth keeping instead: glibc maps every array above
its mmap threshold (at most 32 MB) afresh and unmaps it when freed, so the solve's big
temporaries are pages the kernel zeroes again at each allocation. :func:`kept_heap` (around a
large model's solve, ``Driver.run``) has glibc serve them from the heap and keep its freed
pages; SuperLU's factorisations, which set the solve's peak, still get fresh mapped storage
(:func:`mapped`, around them in :func:`poise.solvers.superlu.splu`); afterwards the settings
are restored and the heap trimmed.
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading

#: Stages smaller than this many bytes of input (or of model unknowns x 1000) are not followed
#: by a trim: their freed memory is small and small runs stay free of the call.
LARGE = 1 << 23
#: The same inside a solve (between its stages): a trim also hands back the pages the next stage
#: would reuse, and each of them is faulted in again (~2 us a page here); below this many bytes
#: that costs more than the memory held (10^4 links: ~50 ms, for a peak the trim does not set).
SOLVE_LARGE = 1 << 27

#: Models with at least this many unknowns (``nq + nc``) solve inside :func:`kept_heap` (a
#: 10^5-link chain has 1.1 M); below, the solve's arrays are mostly under glibc's mmap threshold
#: and reuse the heap anyway.
KEEP_LARGE = 1 << 19
#: Inside a kept heap, factorisations of systems of at least this many unknowns are
#: :func:`mapped`.
MAPPED_LARGE = 1 << 15
#: ... and the heap is trimmed before them only when it holds at least this many free bytes:
#: less is what the next iteration's temporaries reuse (a Newton iteration's, ~150 MB at 10^5
#: links), and handing it back costs more in re-faulted pages than it lowers the peak.
MAPPED_TRIM = 1 << 28

_trim = None          # glibc's malloc_trim, False when unavailable
_mallopt = None       # glibc's mallopt, False when unavailable
_free = None          # bytes free in glibc's heap (mallinfo2), None when unavailable
# mallopt's parameters (malloc.h), glibc's defaults (restored) and the kept heap's trim threshold
# (mallopt takes an int: 2 GB, so the heap's free top is not given back)
_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4
_DEFAULT_TRIM_THRESHOLD, _DEFAULT_MMAP_MAX = 128 * 1024, 65536
_KEEP_TRIM_THRESHOLD = 2 ** 31 - 1
#: environment variables that set what :func:`kept_heap` changes: the user's choice stands
_USER_SETTINGS = ("MALLOC_MMAP_MAX_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_",
                  "MALLOC_TOP_PAD_")
_lock = threading.Lock()
_kept = {"users": 0}


def release(size: int = LARGE, large: int = LARGE) -> bool:
    """Return freed heap memory to the OS when ``size`` (of what a stage dropped, in bytes)
    is at least ``large``; True when glibc trimmed something."""
    if size < large or not glibc():
        return False
    return bool(_trim(0))


def release_stage(size: int) -> bool:
    """:func:`release` between a solve's stages (:data:`SOLVE_LARGE`), except inside a
    :func:`kept_heap`: there nothing is trimmed, the next stage's temporaries reuse those
    pages, and the one place where freed pages would stack on the peak, a factorisation, trims
    first (:func:`mapped`)."""
    return False if _kept["users"] else release(size, SOLVE_LARGE)


def glibc() -> bool:
    """Whether glibc's ``malloc_trim`` and ``mallopt`` are at hand (looked up once, on Linux)."""
    global _trim, _mallopt, _free
    if _trim is None:
        _trim = _mallopt = False
        if sys.platform.startswith("linux"):
            try:
                import ctypes        # lazy: only large runs on Linux get here
                libc = ctypes.CDLL(None)
                trim, mallopt = libc.malloc_trim, libc.mallopt
            except (OSError, AttributeError):      # not glibc
                return False
            trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
            mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
            _trim, _mallopt = trim, mallopt
            _free = _heap_free(libc, ctypes)
    return _trim is not False


def _heap_free(libc, ctypes):
    """A callable giving the free bytes in glibc's heap (``mallinfo2().fordblks``, glibc >=
    2.33), or None."""
    info = getattr(libc, "mallinfo2", None)
    if info is None:
        return None

    class _Info(ctypes.Structure):
        _fields_ = [(f, ctypes.c_size_t) for f in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
            "fordblks", "keepcost")]

    info.argtypes, info.restype = [], _Info
    return lambda: info().fordblks


def user_chosen() -> bool:
    """Whether the environment sets glibc's malloc thresholds (``MALLOC_*_`` variables or
    ``glibc.malloc`` tunables): then :func:`kept_heap` changes nothing."""
    return (any(v in os.environ for v in _USER_SETTINGS)
            or "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", ""))


@contextlib.contextmanager
def kept_heap(size: int):
    """Inside the block, when ``size`` (a model's unknowns) is at least :data:`KEEP_LARGE`,
    glibc serves every allocation from the heap (``M_MMAP_MAX`` 0) and keeps its free top
    (``M_TRIM_THRESHOLD`` 2 GB): freed arrays are reused, not fresh pages. After it glibc's
    defaults are restored (its dynamic mmap threshold stays where it was, fixed, as after any
    ``mallopt``) and the heap is trimmed. Re-entrant and thread-safe (the last one out restores;
    the setting is the process's); a no-op off glibc, for smaller models and when the
    environment sets the thresholds (:func:`user_chosen`)."""
    if size < KEEP_LARGE or not glibc() or user_chosen():
        yield
        return
    with _lock:
        if _kept["users"] == 0:
            _mallopt(_M_MMAP_MAX, 0)
            _mallopt(_M_TRIM_THRESHOLD, _KEEP_TRIM_THRESHOLD)
        _kept["users"] += 1
    try:
        yield
    finally:
        with _lock:
            _kept["users"] -= 1
            if _kept["users"] == 0:
                _mallopt(_M_MMAP_MAX, _DEFAULT_MMAP_MAX)
                _mallopt(_M_TRIM_THRESHOLD, _DEFAULT_TRIM_THRESHOLD)
                _trim(0)


@contextlib.contextmanager
def mapped(size: int):
    """Inside a :func:`kept_heap`, around a factorisation of ``size`` unknowns (at least
    :data:`MAPPED_LARGE`): the heap's free pages go back to the OS first (when at least
    :data:`MAPPED_TRIM` bytes are free) and large allocations are mapped again. SuperLU
    reserves its factors' storage by its fill estimate (gigabytes of address space at 10^5
    links) and touches only what the factors fill: mapped, the untouched part costs nothing;
    from a kept heap, arrays made between two factorisations take the start of the freed
    region, the next factors land beside it, and the pages both touched stay resident at the
    solve's peak. Elsewhere a no-op."""
    with _lock:
        active = _kept["users"] > 0 and size >= MAPPED_LARGE
        if active:
            if _free is None or _free() >= MAPPED_TRIM:
                _trim(0)
            _mallopt(_M_MMAP_MAX, _DEFAULT_MMAP_MAX)
    try:
        yield
    finally:
        if active:
            with _lock:
                _mallopt(_M_MMAP_MAX, 0 if _kept["users"] else _DEFAULT_MMAP_MAX)


def hand_over(obj):
    """A zero-argument callable giving ``obj``, once: the caller drops its own reference, so the
    receiver holds the only one and a large object (a Jacobian) goes as soon as the receiver
    is done with it, before its next big allocation. :func:`taken` reads either form."""
    return [obj].pop


def taken(obj):
    """``obj`` itself, or what the :func:`hand_over` callable ``obj`` gives."""
    return obj() if callable(obj) else obj
