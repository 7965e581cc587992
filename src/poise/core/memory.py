"""Freed memory handed back to the operating system after the big stages of a large run.

CPython and numpy free through the C library's allocator, and glibc keeps freed heap pages
resident: after a 10⁵-link deck's parse (millions of short-lived records) or once the parsed deck
is dropped, hundreds of MB stay in the process's resident set, free but not returned, and every
later peak (the factorisations) stacks on them. :func:`release` asks glibc to return them
(``malloc_trim(0)``: whole free pages anywhere in the heap). It is called only after large
stages (callers pass the size that was freed), costs a few milliseconds, and is a no-op where
the C library is not glibc (macOS, Windows, musl).
"""
from __future__ import annotations

import sys

#: Stages smaller than this many bytes of input (or of model unknowns x 1000) are not followed
#: by a trim: their freed memory is small and small runs stay free of the call.
LARGE = 1 << 23
#: The same inside a solve (between its stages): a trim also hands back the pages the next stage
#: would reuse, and each of them is faulted in again (~2 us a page here); below this many bytes
#: that costs more than the memory held (10^4 links: ~50 ms, for a peak the trim does not set).
SOLVE_LARGE = 1 << 27

_trim = None          # glibc's malloc_trim, False when unavailable


def release(size: int = LARGE, large: int = LARGE) -> bool:
    """Return freed heap memory to the OS when ``size`` (of what a stage dropped, in bytes)
    is at least ``large`` (:data:`LARGE`, or :data:`SOLVE_LARGE` between a solve's stages);
    True when glibc trimmed something."""
    global _trim
    if size < large or not sys.platform.startswith("linux"):
        return False
    if _trim is None:
        try:
            import ctypes        # lazy: only large runs on Linux get here
            _trim = ctypes.CDLL(None).malloc_trim
            _trim.argtypes = [ctypes.c_size_t]
            _trim.restype = ctypes.c_int
        except (OSError, AttributeError):      # not glibc
            _trim = False
    if _trim is False:
        return False
    return bool(_trim(0))


def hand_over(obj):
    """A zero-argument callable giving ``obj``, once: the caller drops its own reference, so the
    receiver holds the only one and a large object (a Jacobian) goes as soon as the receiver
    is done with it, before its next big allocation. :func:`taken` reads either form."""
    return [obj].pop


def taken(obj):
    """``obj`` itself, or what the :func:`hand_over` callable ``obj`` gives."""
    return obj() if callable(obj) else obj
