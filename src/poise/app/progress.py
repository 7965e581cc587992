"""The quasi-static progress bar (a terminal concern: solvers only call a callback)."""
from __future__ import annotations

import contextlib
import contextvars
import os
import sys
import time as _time


#: ``False`` silences the progress bar of quasi-static runs started in this context (``poise
#: solve --quiet`` through ``run_deck(quiet=True)``); ``None``: automatic (stderr is a terminal,
#: not in CI, ``POISE_QUIET`` unset).
PROGRESS: contextvars.ContextVar = contextvars.ContextVar("poise_progress", default=None)


@contextlib.contextmanager
def progress_bar(enabled: bool | None):
    """Context in which quasi-static progress bars are ``enabled`` (None: automatic)."""
    tok = PROGRESS.set(enabled)
    try:
        yield
    finally:
        PROGRESS.reset(tok)


class Progress:
    """A one-line progress bar on stderr for runs longer than ~1 s (TTY only, not in CI)."""

    def __init__(self, total: int, label: str, enabled: bool | None = None):
        if enabled is None:
            enabled = (sys.stderr.isatty() and not os.environ.get("CI")
                       and not os.environ.get("POISE_QUIET"))
        self.enabled = enabled
        self.total = max(total, 1)
        self.label = label
        self.t0 = _time.perf_counter()
        self.last = 0.0
        self.shown = False

    def update(self, done: int):
        if not self.enabled:
            return
        now = _time.perf_counter()
        if now - self.t0 < 1.0 or now - self.last < 0.1:
            return
        self.last = now
        f = done / self.total
        bar = "#" * int(30 * f)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {done}/{self.total} frames")
        sys.stderr.flush()
        self.shown = True

    def close(self):
        if self.shown:
            sys.stderr.write("\r" + " " * 70 + "\r")
            sys.stderr.flush()


def progress_callback():
    """A ``progress(label, done, total)`` drawing a :class:`Progress` bar per label (enabled
    as the :data:`PROGRESS` context says when this is called); ``done`` None closes it."""
    enabled = PROGRESS.get()
    bars = {}

    def progress(label, done, total):
        bar = bars.get(label)
        if bar is None:
            bar = bars[label] = Progress(total, label, enabled=enabled)
        if done is None:
            bars.pop(label).close()
        else:
            bar.update(done)
    return progress
