"""The progress hook between the solvers and whoever shows progress.

Solvers never draw: they call :func:`report` with ``(label, done, total)`` as long work advances
(quasi-static frames, MKEAM iterations) and ``done=None`` when it ends. The orchestration layer
installs the callback for the duration of a run (:func:`reporting`; :mod:`poise.app.progress`
draws it); without one, reports go nowhere.
"""
from __future__ import annotations

import contextlib
import contextvars

#: the installed ``callback(label, done, total)``; ``False``/``None``: none (quiet / not set)
PROGRESS: contextvars.ContextVar = contextvars.ContextVar("poise_progress", default=None)


def report(label: str, done: int | None, total: int) -> None:
    """Tell the installed callback (if any) that ``done`` of ``total`` are done (None: ended)."""
    cb = PROGRESS.get()
    if callable(cb):
        cb(label, done, total)


@contextlib.contextmanager
def reporting(callback):
    """Install ``callback`` (or ``False``: silence, ``None``: automatic) inside the block."""
    tok = PROGRESS.set(callback)
    try:
        yield
    finally:
        PROGRESS.reset(tok)
