"""Freed memory handed back to the operating system after the big stages of a large run.

CPython and numpy free through the C library's allocator, and glibc keeps freed heap pages
resident: after a 10⁵-link deck's parse (millions of short-lived records) or once the parsed deck
is dropped, hundreds of MB stay in the process's resident set, free but not returned, and every
later peak (the factorisations) stacks on them. :func:`release` asks glibc to return them
(``malloc_trim(0)``: whole free pages anywhere in the heap). It is called only after large
stages (callers pass the size that was freed), costs a few milliseconds, and is a no-op where
the C library is not glibc (macOS, Windows, musl).

:func:`heap_arrays` keeps a large solve's big arrays in the heap: glibc maps every block above
its mmap threshold (32 MB at most) afresh and the kernel zeroes each page at first touch, so at
10^5 links every factorisation's storage, every Jacobian and every copy of one is faulted in
again (≈ 1.2 s of system time per solve, the part of its cost that grows faster than the
model). In the heap, freed blocks are reused by the next of the same size.
"""
from __future__ import annotations

import contextlib
import sys

#: Stages smaller than this many bytes of input (or of model unknowns x 1000) are not followed
#: by a trim: their freed memory is small and small runs stay free of the call.
LARGE = 1 << 23
#: The same inside a solve (between its stages): a trim also hands back the pages the next stage
#: would reuse, and each of them is faulted in again (~2 us a page here); below this many bytes
#: that costs more than the memory held (10^4 links: ~50 ms, for a peak the trim does not set).
SOLVE_LARGE = 1 << 27

_libc = None          # the C library (glibc), False when unavailable
_held = False         # inside heap_arrays: freed pages stay for the next stage

#: glibc's largest mmap threshold (``DEFAULT_MMAP_THRESHOLD_MAX`` on 64-bit): above it every
#: block is mapped afresh whatever the allocator learnt from earlier frees.
MMAP_MAX_THRESHOLD = 32 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_MMAP_MAX = -1, -3, -4     # mallopt parameters
_MMAPS_DEFAULT = 65536                 # glibc's DEFAULT_MMAP_MAX
_KEEP = (1 << 31) - 1                  # a trim threshold (int) not reached: pages stay


def _glibc():
    """glibc (``mallopt``, ``malloc_trim``) or False where the C library is another."""
    global _libc
    if _libc is None:
        _libc = False
        if sys.platform.startswith("linux"):
            try:
                import ctypes        # lazy: only large runs on Linux get here
                lib = ctypes.CDLL(None)
                lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
                lib.mallopt.restype = ctypes.c_int
                lib.malloc_trim.argtypes = [ctypes.c_size_t]
                lib.malloc_trim.restype = ctypes.c_int
                _libc = lib
            except (OSError, AttributeError):      # not glibc
                pass
    return _libc


@contextlib.contextmanager
def heap_arrays(nbytes: int):
    """Within the block, big arrays live in the heap (glibc: no ``mmap`` per block, no
    automatic trim) when ``nbytes`` (the size of the solve's largest arrays: its Jacobian's
    values) is above :data:`MMAP_MAX_THRESHOLD`; smaller runs are left as they are (their
    arrays are below the threshold glibc learns from its frees: already in the heap). On exit
    the freed pages go back to the OS (``malloc_trim``) and glibc gets back its own limits (at
    their learnt values: the threshold at its largest, as after any large free). Within the
    block :func:`release` keeps the pages too: the next stage's arrays reuse them (at 10^5
    links trimming between the solve's stages cost ≈ 0.4 s of faults and lowered no peak)."""
    global _held
    lib = _glibc() if nbytes > MMAP_MAX_THRESHOLD and not _held else False
    if not lib:
        yield False
        return
    lib.mallopt(_M_TRIM_THRESHOLD, _KEEP)
    lib.mallopt(_M_MMAP_MAX, 0)
    _held = True
    try:
        yield True
    finally:
        _held = False
        lib.mallopt(_M_MMAP_MAX, _MMAPS_DEFAULT)
        lib.mallopt(_M_MMAP_THRESHOLD, MMAP_MAX_THRESHOLD)
        lib.mallopt(_M_TRIM_THRESHOLD, 2 * MMAP_MAX_THRESHOLD)
        lib.malloc_trim(0)


def release(size: int = LARGE, large: int = LARGE) -> bool:
    """Return freed heap memory to the OS when ``size`` (of what a stage dropped, in bytes)
    is at least ``large`` (:data:`LARGE`, or :data:`SOLVE_LARGE` between a solve's stages);
    True when glibc trimmed something (never inside :func:`heap_arrays`)."""
    if size < large or _held:
        return False
    lib = _glibc()
    return bool(lib.malloc_trim(0)) if lib else False


def hand_over(obj):
    """A zero-argument callable giving ``obj``, once: the caller drops its own reference, so the
    receiver holds the only one and a large object (a Jacobian) goes as soon as the receiver
    is done with it, before its next big allocation. :func:`taken` reads either form."""
    return [obj].pop


def taken(obj):
    """``obj`` itself, or what the :func:`hand_over` callable ``obj`` gives."""
    return obj() if callable(obj) else obj
