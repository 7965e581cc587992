"""Progress of long work, one way everywhere (quasi-static frames, MKEAM iterations, batch,
sweep, animate, bench).

Solvers never draw: they call :func:`report` with ``(label, done, total)`` as work advances and
``done=None`` when it ends; the orchestration installs a callback for a run
(:func:`solver_progress`: :func:`reporter` draws one :class:`Bar` per label). :class:`Bar` has
three modes, chosen once: ``tty`` (stderr is a terminal, ``CI`` unset): a tqdm bar
with position, percentage, rate and ETA, erased when done; ``plain`` (a log, CI): a line ``poise:
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
    without breaking the bar, ``note(line)`` the same unless the bar is off (``--quiet``),
    ``close(end)`` ends it: ``end`` other than ``"done"`` (``"gave up"``, ``"interrupted"``)
    is said in a last line. ``delay``: seconds before anything is shown.
    """

    def __init__(self, total: int, label: str, unit: str = "", enabled: bool | None = None,
                 delay: float = 1.0, stream=None, mode: str | None = None):
        self.total, self.label, self.unit = max(int(total), 1), label, unit
        self.stream = stream or sys.stderr
        self.mode = mode or choose_mode(enabled, self.stream)
        self.delay = delay
        self.done = 0
        self.t0 = time.monotonic()
        self._bar = None                 # the tqdm bar (tty), drawn once ``delay`` has passed
        self._cleared = False
        self._last_t = self.t0           # plain: time and fraction of the last line
        self._last_f = 0.0
        self.lines = 0                   # plain lines written
        if self.mode == "tty":
            from tqdm import tqdm        # lazy: only on a terminal
            self._bar = tqdm(total=self.total, desc=label, unit=f" {unit}" if unit else "it",
                             file=self.stream, leave=False, delay=delay, dynamic_ncols=True,
                             mininterval=0.2)

    # ------------------------------------------------------------------ public
    def update(self, done: int) -> None:
        done = min(max(int(done), 0), self.total)
        delta, self.done = done - self.done, done
        if self.mode == "off":
            return
        if self.mode == "tty":
            if delta:
                self._bar.update(delta)
            if self._cleared:
                self._cleared = False
                self._bar.refresh()
            return
        now = time.monotonic()
        if now - self.t0 < self.delay:          # quick work says nothing
            return
        self._plain(now)

    def step(self, k: int = 1) -> None:
        self.update(self.done + k)

    def clear(self) -> None:
        """Erase the bar from the terminal (it comes back on the next update): call before
        printing a line of one's own."""
        if self._bar is not None:
            self._bar.clear()
            self._cleared = True

    def write(self, line: str) -> None:
        """Print ``line`` on the stream (above the bar on a terminal)."""
        if self._bar is not None:
            self._bar.write(line, file=self.stream)
        else:
            self.stream.write(line + "\n")
            self.stream.flush()

    def note(self, line: str) -> None:
        """:meth:`write`, unless the bar is off (quiet)."""
        if self.mode != "off":
            self.write(line)

    def close(self, end: str = "done") -> None:
        if self.mode == "off":
            return
        now = time.monotonic()
        # work that ended otherwise than done is said in a last line, unless it ended at once
        # (a usage error before any work) without a line before
        said = end != "done" and (self.lines or now - self.t0 >= 1.0)
        if self._bar is not None:
            self._bar.close()                  # erased (leave=False)
            self._bar = None
            if said:
                self._line(now, final=end)
        elif self.mode == "plain" and ((self.lines and self._last_f < 1.0) or said):
            self._line(now, final=end)
        self.mode = "off"                    # closed: says nothing more

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(ending(exc))

    # ------------------------------------------------------------------ drawing
    def _plain(self, now: float) -> None:
        f = self.done / self.total
        if (f - self._last_f >= PLAIN_STEP - 1e-9 or now - self._last_t >= PLAIN_EVERY_S
                or (f >= 1.0 and self.lines)):
            self._line(now)

    def _line(self, now: float, final: str | None = None) -> None:
        f = self.done / self.total
        el = now - self.t0
        eta = f", ETA {_dur(el * (1 - f) / f)}" if 0 < f < 1 and not final else ""
        unit = f" {self.unit}" if self.unit else ""
        end = f", {final}" if final else ""
        self.stream.write(f"poise: {self.label} {self.done}/{self.total}{unit} ({f:.0%}), "
                          f"{_dur(el)}{eta}{end}\n")
        self.stream.flush()
        self._last_t, self._last_f = now, f
        self.lines += 1


def note(line: str, enabled: bool | None = None) -> None:
    """Print ``line`` on stderr unless progress is off (quiet, a worker process)."""
    if choose_mode(enabled) != "off":
        sys.stderr.write(line + "\n")
        sys.stderr.flush()


def ending(exc: BaseException | None) -> str:
    """The word a progress line ends with for a run ended by ``exc``: ``done`` (None), the
    exception's ``progress_end`` (e.g. ``gave up``), ``interrupted`` or ``failed``."""
    if exc is None:
        return "done"
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    return getattr(exc, "progress_end", None) or "failed"


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
