"""One progress reporter for long commands (``poise animate``, ``poise bench``).

On a terminal: click's progress bar (bar, count, ETA) on stderr. Not a terminal (CI logs, pipes):
a plain line every 10 % or every 10 s, whichever comes first, so a log shows the run advancing
without carriage-return garbage. Nothing at all with ``quiet=True`` or env ``POISE_QUIET=1``.
click is already a dependency; no second progress library is pulled in.
"""
from __future__ import annotations

import os
import sys
import time


def silenced(quiet: bool = False) -> bool:
    """True when progress must print nothing (``--quiet`` or ``POISE_QUIET`` set, not 0)."""
    return bool(quiet) or os.environ.get("POISE_QUIET", "").strip() not in ("", "0")


class Progress:
    """``with Progress(total, "label", quiet=q) as p: ... p.update(1)``."""

    PLAIN_EVERY_S = 10.0
    PLAIN_EVERY_FRAC = 0.10

    def __init__(self, total: int, label: str, quiet: bool = False, stream=None):
        self.total = max(int(total), 0)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.on = not silenced(quiet) and self.total > 0
        try:
            self.tty = self.on and self.stream.isatty()
        except (AttributeError, ValueError):
            self.tty = False
        self.n = 0
        self._bar = None
        self._t0 = self._last_t = time.monotonic()
        self._last_frac = 0.0

    def __enter__(self):
        if self.tty:
            import click
            self._bar = click.progressbar(length=self.total, label=self.label, file=self.stream,
                                          show_eta=True, show_pos=True)
            self._bar.__enter__()
        return self

    def update(self, k: int = 1) -> None:
        self.n = min(self.n + k, self.total)
        if not self.on:
            return
        if self._bar is not None:
            self._bar.update(k)
            return
        now = time.monotonic()
        frac = self.n / self.total if self.total else 1.0
        if (frac - self._last_frac >= self.PLAIN_EVERY_FRAC or now - self._last_t
                >= self.PLAIN_EVERY_S or self.n == self.total):
            self._last_t, self._last_frac = now, frac
            self.stream.write(f"{self.label}: {self.n}/{self.total} ({100 * frac:.0f} %), "
                              f"{now - self._t0:.1f} s\n")
            self.stream.flush()

    def __exit__(self, *exc):
        if self._bar is not None:
            self._bar.__exit__(*exc)
        return False
