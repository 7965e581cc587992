"""Keep stdout for the command's own output and numerical warnings out of raw stderr.

:func:`guarded_stdout` points file descriptor 1 at stderr (or at ``/dev/null`` under
``--quiet``) while a command solves: native libraries (SUNDIALS IDA prints
``[IDAHandleFailure ...]`` with C stdio), user routines and worker processes started meanwhile
cannot put anything on the real stdout, which stays strict JSON under ``--json``.
:func:`collected_warnings` records Python warnings (numpy ``RuntimeWarning``: overflow, invalid
value, ...) instead of letting them print as raw ``file:line: RuntimeWarning`` text; the command
reports them once each as run warnings (nothing under ``--quiet``).
"""
from __future__ import annotations

import contextlib
import os
import sys

from poise.app.run_warnings import collected_warnings  # noqa: F401 - the commands' one recorder


def _flush_all() -> None:
    """Flush Python's stdout and every C stdio stream (text a native library buffered)."""
    for s in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            s.flush()
    with contextlib.suppress(Exception):
        import ctypes
        ctypes.CDLL(None).fflush(None)


@contextlib.contextmanager
def guarded_stdout(quiet: bool = False):
    """Redirect fd 1 to fd 2 (``quiet``: to ``/dev/null``) inside the block, restore it after.

    A no-op when fd 1 or fd 2 cannot be duplicated (closed descriptors, some test runners).
    """
    try:
        saved = os.dup(1)
    except OSError:
        yield
        return
    try:
        target = os.open(os.devnull, os.O_WRONLY) if quiet else os.dup(2)
    except OSError:
        os.close(saved)
        yield
        return
    _flush_all()
    os.dup2(target, 1)
    os.close(target)
    try:
        yield
    finally:
        _flush_all()
        os.dup2(saved, 1)
        os.close(saved)
