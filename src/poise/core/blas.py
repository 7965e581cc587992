"""BLAS runs single-threaded while poise solves, whatever the caller imported first.

The solver's dense work is on 3x3 .. 12x12 blocks and vectors: a multi-threaded BLAS only adds
thread start-up and, on a loaded machine, busy-waiting (a 1000-link chain solved 1.8x slower on
2 cores with another process running; four-bar ``--require-stable`` 6.2x slower). Two parts:

* importing poise sets ``OPENBLAS_NUM_THREADS=1`` and ``MKL_NUM_THREADS=1`` (``setdefault``:
  the caller's own setting wins); every BLAS library loaded later starts single-threaded;
* :func:`limited` (around every run, poise.app.runner) limits the BLAS libraries that were
  already loaded when poise was imported (numpy imported first, e.g. in a notebook) with
  threadpoolctl, and restores their thread count after. When poise came first there is nothing
  to limit and threadpoolctl is not even imported.
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading

#: the caller's own OPENBLAS_NUM_THREADS / MKL_NUM_THREADS (None: not set; poise sets 1)
USER_SETTING = {v: os.environ.get(v) for v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
#: modules that load a BLAS library and were imported before poise (their BLAS did not see
#: the variables above)
LOADED_BEFORE = tuple(m for m in ("numpy", "scipy") if m in sys.modules)

for _v in USER_SETTING:
    os.environ.setdefault(_v, "1")

_lock = threading.Lock()
_state = {"users": 0, "limiter": None, "controller": None}


def needed() -> bool:
    """Whether a BLAS library may run multi-threaded in a solve: it was loaded before poise set
    the variables, and the caller did not choose a thread count themselves."""
    return bool(LOADED_BEFORE) and all(v is None for v in USER_SETTING.values())


@contextlib.contextmanager
def limited():
    """One BLAS thread inside the block (re-entrant and thread-safe: the first run in limits,
    the last one out restores the previous counts)."""
    if not needed():
        yield
        return
    with _lock:
        if _state["users"] == 0:
            if _state["controller"] is None:      # scanning the loaded libraries: once
                from threadpoolctl import ThreadpoolController   # lazy: only when needed
                _state["controller"] = ThreadpoolController()
            _state["limiter"] = _state["controller"].limit(limits=1, user_api="blas")
        _state["users"] += 1
    try:
        yield
    finally:
        with _lock:
            _state["users"] -= 1
            if _state["users"] == 0 and _state["limiter"] is not None:
                _state["limiter"].restore_original_limits()
                _state["limiter"] = None
