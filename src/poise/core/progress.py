"""Progress of long work, one way everywhere (quasi-static frames, MKEAM iterations, batch,
sweep, animate, bench).

Solvers never draw: they call :func:`report` with ``(label, done, total)`` as work advances and
``done=None`` when it ends; the orchestration installs a callback for a run
(:func:`solver_progress`: :func:`reporter` draws one :class:`Bar` per label). :class:`Bar` has
three modes, chosen once: ``tty`` (stderr is a terminal, ``CI`` unset): click's progress bar
with position, percentage and ETA, erased when done; ``plain`` (a log, CI): a line ``poise:
LABEL 40/100 UNIT (40%), 12 s, ETA 18 s`` every 10 % or 10 s, nothing for work that ends
within ``delay`` seconds; ``off``: ``--quiet``, ``POISE_QUIET`` set, or a worker process
(batch/sweep workers: their parent shows the cases done). Here in core because the solvers,
the orchestration (``poise.app``) and the pictures (``poise.viz``) all use it.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
import sys
import time

#: the installed ``callback(label, done, total)``; ``False``/``None``: none (quiet / not set)
PROGRESS: contextvars.ContextVar = contextvars.ContextVar("poise_progress", default=None)


def report(label: str, done: int | None, total: int) -> None:
    """Tell the installed callback (if any) that ``done`` of ``total`` are done (None: ended)."""
    cb = PROGRESS.get()
    if callable(cb):
        cb(label, done, total)


def installed():
    """The installed callback, or None (for a solver driver's ``progress`` argument)."""
    cb = PROGRESS.get()
    return cb if callable(cb) else None


@contextlib.contextmanager
def reporting(callback):
    """Install ``callback`` (or ``False``: silence, ``None``: automatic) inside the block."""
    tok = PROGRESS.set(callback)
    try:
        yield
    finally:
        PROGRESS.reset(tok)


#: a plain line at least every this many seconds, and at each 10 % step
PLAIN_EVERY_S = 10.0
PLAIN_STEP = 0.1


def quiet_env() -> bool:
    """``POISE_QUIET`` is set to something other than empty / 0."""
    return os.environ.get("POISE_QUIET", "").strip() not in ("", "0")


def choose_mode(enabled: bool | None = None, stream=None) -> str:
    """``off`` (``enabled`` False, ``POISE_QUIET``), ``tty`` or ``plain`` (see module doc)."""
    if enabled is False or quiet_env() or _in_worker():
        return "off"
    stream = stream or sys.stderr
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError):
        tty = False
    return "tty" if tty and not os.environ.get("CI") else "plain"


def _in_worker() -> bool:
    """A child process (batch pool, Dask worker): its parent shows the progress of cases."""
    mp = sys.modules.get("multiprocessing")
    return mp is not None and mp.parent_process() is not None


def _dur(s: float) -> str:
    s = max(0.0, s)
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


class Bar:
    """Progress of ``total`` units of work labelled ``label`` (see the module doc for modes).

    ``update(done)`` sets the position, ``step(k)`` advances it, ``write(line)`` prints a line
    without breaking the bar, ``close()`` ends it. ``delay``: seconds before anything is shown.
    """

    def __init__(self, total: int, label: str, unit: str = "", enabled: bool | None = None,
                 delay: float = 1.0, stream=None, mode: str | None = None):
        self.total, self.label, self.unit = max(int(total), 1), label, unit
        self.stream = stream or sys.stderr
        self.mode = mode or choose_mode(enabled, self.stream)
        self.delay = delay
        self.done = 0
        self.t0 = time.monotonic()
        self._bar = None                 # click's ProgressBar once shown (tty)
        self._last_t = self.t0           # plain: time and fraction of the last line
        self._last_f = 0.0
        self.lines = 0                   # plain lines written

    # ------------------------------------------------------------------ public
    def update(self, done: int) -> None:
        done = min(max(int(done), 0), self.total)
        delta, self.done = done - self.done, done
        if self.mode == "off":
            return
        now = time.monotonic()
        if now - self.t0 < self.delay:          # quick work says nothing
            return
        if self.mode == "tty":
            self._tty(delta)
        else:
            self._plain(now)

    def step(self, k: int = 1) -> None:
        self.update(self.done + k)

    def clear(self) -> None:
        """Erase the bar from the terminal (it comes back on the next update): call before
        printing a line of one's own."""
        if self._bar is not None:
            self._erase()
            self.stream.flush()
            self._bar._last_line = None      # click redraws only a changed line

    def write(self, line: str) -> None:
        """Print ``line`` on the stream (above the bar on a terminal)."""
        self.clear()
        self.stream.write(line + "\n")
        self.stream.flush()
        if self._bar is not None:
            self._bar.render_progress()

    def close(self) -> None:
        if self.mode == "off":
            return
        if self._bar is not None:
            self._erase()
            self.stream.write("\033[?25h")   # click hides the cursor while drawing
            self.stream.flush()
            self._bar = None
        elif self.mode == "plain" and self.lines and self._last_f < 1.0:
            self._line(time.monotonic(), final=True)
        self.mode = "off"                    # closed: says nothing more

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ drawing
    def _tty(self, delta: int) -> None:
        if self._bar is None:
            import click
            self._bar = click.progressbar(length=self.total, label=self.label, show_eta=True,
                                          show_percent=True, show_pos=True, width=30,
                                          file=self.stream)
            self._bar.start = time.time() - (time.monotonic() - self.t0)   # ETA from our start
            self._bar.update(self.done)
        elif delta:
            self._bar.update(delta)

    def _erase(self) -> None:
        width = (self._bar.max_width or 0) + len(self.label) + 40
        self.stream.write("\r" + " " * width + "\r")

    def _plain(self, now: float) -> None:
        f = self.done / self.total
        if (f - self._last_f >= PLAIN_STEP - 1e-9 or now - self._last_t >= PLAIN_EVERY_S
                or (f >= 1.0 and self.lines)):
            self._line(now)

    def _line(self, now: float, final: bool = False) -> None:
        f = self.done / self.total
        el = now - self.t0
        eta = f", ETA {_dur(el * (1 - f) / f)}" if 0 < f < 1 and not final else ""
        unit = f" {self.unit}" if self.unit else ""
        end = ", done" if final else ""
        self.stream.write(f"poise: {self.label} {self.done}/{self.total}{unit} ({f:.0%}), "
                          f"{_dur(el)}{eta}{end}\n")
        self.stream.flush()
        self._last_t, self._last_f = now, f
        self.lines += 1


def reporter(enabled: bool | None = None):
    """A solver callback ``(label, done, total)`` drawing one :class:`Bar` per label
    (``done`` None ends it); ``None`` when ``enabled`` resolves to ``off``."""
    if choose_mode(enabled) == "off":
        return False
    bars: dict[str, Bar] = {}
    units = {"MKEAM": "iterations (at most)"}

    def progress(label, done, total):
        bar = bars.get(label)
        if done is None:
            if bar is not None:
                bars.pop(label).close()
            return
        if bar is None:
            bar = bars[label] = Bar(total, label, units.get(label, "frames"), enabled,
                                    delay=1.0 if label != "MKEAM" else 2.0)
        bar.update(done)
    return progress


@contextlib.contextmanager
def solver_progress(enabled: bool | None = None):
    """Inside the block, the solvers' progress reports draw bars (``enabled`` False: nothing)."""
    with reporting(reporter(enabled)):
        yield
