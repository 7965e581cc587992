"""Safe, atomic output files: results (HDF5), plots (PNG) and animations (GIF/MP4).

Every output file is written to a hidden temporary file next to its target, flushed and
fsync'ed, then renamed over the target with :func:`os.replace`, and the directory is fsync'ed.
A process killed mid-write leaves at most the hidden temporary file, never a partial file under
the final name; any exception removes the temporary file and leaves the target untouched.

:func:`output_target` decides the target first: symbolic links are followed (the file a link
points to is replaced, not the link), and a path that exists but is not a regular file (a
directory, a device such as ``/dev/null``, a FIFO: the rename would replace the device node
itself) or that is one of the inputs (the deck) is refused with
:class:`poise.core.errors.UsageError` (CLI exit code 2).

Failures are clean: a write that fails for lack of space or permission (``OSError``, HDF5's
``errno = N`` errors, errors HDF5 can only report as "ignored" while closing) removes the
temporary file and raises :class:`OutputError` (a usage error, exit 2) naming the path.
SIGINT/SIGTERM during a short write (``hold_interrupts``: results files) are held until the
writer returns, then raised as ``KeyboardInterrupt`` (the temporary file removed, the target
untouched). Temporary names are
``.<name>.tmp-<pid>@<host>``: one left by a killed process (SIGKILL) is removed by the next
write into that directory once its process is gone.
"""
from __future__ import annotations

import contextlib
import os
import re
import signal
import stat
import sys
import threading

from poise.core.errors import UsageError
from poise.core.wording import shorten


class OutputError(UsageError):
    """An output file could not be written (disk full, no permission, ...): exit 2."""

    status = "io_error"


def output_target(path, inputs=()) -> str:
    """The real path an output for ``path`` goes to, after the checks above.

    Parameters
    ----------
    path : str or os.PathLike
        Output path as the user gave it.
    inputs : iterable of str or os.PathLike or None
        Files the output must not be (the deck). ``None`` entries are ignored.

    Returns
    -------
    str
        ``os.path.realpath(path)``.
    """
    path = os.fspath(path)
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
    except (FileNotFoundError, NotADirectoryError):     # a new file (its directory: the writer's)
        return real
    if not stat.S_ISREG(st.st_mode):
        raise UsageError(f"output {path!r} exists and is not a regular file; expected the path "
                         "of a new file or of an existing regular file")
    for other in inputs:
        if not other:
            continue
        try:
            same = os.path.samefile(real, os.fspath(other))
        except FileNotFoundError:
            continue
        if same:
            raise UsageError(f"output {path!r} is the input deck {os.fspath(other)!r}; writing "
                             "there would destroy the deck")
    return real


def check_output(path, inputs=()) -> str:
    """:func:`output_target` plus a directory that exists and can be written, checked before
    any work (for outputs written at the end of a long run); raises :class:`OutputError`
    (exit 2) naming ``path``, or the :class:`UsageError` of :func:`output_target`."""
    target = output_target(path, inputs)
    directory = os.path.dirname(target)
    if not os.path.isdir(directory):
        raise OutputError(f"cannot write {os.fspath(path)!r}: directory {directory!r} does not "
                          "exist")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write {os.fspath(path)!r}: directory {directory!r} is not "
                          "writable")
    return target


def fsync_path(path: str, directory: bool = False) -> None:
    """fsync a file (errors propagate) or a directory (best effort)."""
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        if directory:  # some platforms cannot open directories; best effort
            return
        raise
    try:
        os.fsync(fd)
    except OSError:
        if not directory:
            raise
    finally:
        os.close(fd)


_HOST = re.sub(r"[^A-Za-z0-9-]", "-", os.uname().nodename if hasattr(os, "uname") else "")[:40]
#: ``.<name>.tmp-<pid>[@<host>][.<ext>]`` (without ``@host``: written by poise <= 0.1)
_TMP = re.compile(r"^\.(?P<name>.+)\.tmp-(?P<pid>\d+)(?:@(?P<host>[A-Za-z0-9-]*))?"
                  r"(?:\.[A-Za-z0-9]+)?$")
_SCANNED: set = set()
#: temporary files being written now (removed by the CLI's interrupt watchdog when it has to end
#: the process while native code holds the main thread: poise_cli.watchdog)
ACTIVE_TEMPS: set = set()


def temp_name(target: str, keep_suffix: bool = False) -> str:
    """The temporary path of ``target`` for this process."""
    directory, name = os.path.split(target)
    return os.path.join(directory, f".{name}.tmp-{os.getpid()}@{_HOST}"
                        + (os.path.splitext(name)[1] if keep_suffix else ""))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:          # EPERM: someone else's live process
        return True
    return True


def remove_stale_temps(directory: str, name: str | None = None) -> list[str]:
    """Remove the temporary files a killed poise process left in ``directory``; return them.

    A temp file is stale when its process (pid in the name) no longer exists on this host.
    Files tagged with another host (a shared filesystem) are left alone; untagged (old) ones
    only for ``name``. Each directory is scanned once per process (``name`` given) so that
    writing many files into one directory stays linear.
    """
    key = os.path.realpath(directory)
    if name is not None:
        if key in _SCANNED:
            return []
        _SCANNED.add(key)
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    me = os.getpid()
    for e in entries:
        m = _TMP.match(e.name)
        if m is None:
            continue
        host = m.group("host")
        if host is None and (name is None or m.group("name") != name):
            continue
        if host is not None and host != _HOST:
            continue
        pid = int(m.group("pid"))
        if pid == me or _pid_alive(pid):
            continue
        with contextlib.suppress(OSError):
            if e.is_file(follow_symlinks=False):
                os.unlink(e.path)
                removed.append(e.path)
    return removed


_ERRNO = re.compile(r"errno = (\d+)")


def _io_reason(exc: BaseException | None, unraisable: list) -> str | None:
    """Why a write failed when it is an I/O failure (a reason text), else None."""
    for e in ([exc] if exc is not None else []) + [u.exc_value for u in unraisable]:
        if e is None:
            continue
        if isinstance(e, OSError):
            no = e.errno
            if no is None:
                m = _ERRNO.search(str(e))
                no = int(m.group(1)) if m else None
            return os.strerror(no) if no else shorten(str(e), 200)
        m = _ERRNO.search(str(e))
        if m:          # HDF5 reports failed writes as RuntimeError "... errno = 28 ..."
            return os.strerror(int(m.group(1)))
    return None


@contextlib.contextmanager
def _held_interrupts(hold: bool = True):
    """Hold SIGINT/SIGTERM inside the block (main thread only); yields the list of signals
    received, which the caller turns into ``KeyboardInterrupt`` at a safe point."""
    got: list = []
    if not hold or threading.current_thread() is not threading.main_thread():
        yield got
        return
    old = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            old[sig] = signal.signal(sig, lambda n, f: got.append(n))
        except (ValueError, OSError):
            pass
    try:
        yield got
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


@contextlib.contextmanager
def _collect_unraisable():
    """Errors raised where Python can only ignore them (HDF5 closing a file whose last write
    failed): recorded instead of printed as a traceback."""
    seen: list = []
    old = sys.unraisablehook

    def hook(u):
        if isinstance(u.exc_value, OSError) or _ERRNO.search(str(u.exc_value)):
            seen.append(u)
        else:
            old(u)
    sys.unraisablehook = hook
    try:
        yield seen
    finally:
        sys.unraisablehook = old


@contextlib.contextmanager
def atomic_output(path, inputs=(), keep_suffix: bool = False, hold_interrupts: bool = False):
    """Context manager yielding the temporary path to write instead of ``path``.

    On a clean exit the temporary file is fsync'ed and renamed over the target
    (:func:`output_target`); on any exception (also KeyboardInterrupt) it is removed.
    ``keep_suffix`` appends the target's extension to the temporary name, for writers that
    choose the format by extension (matplotlib, ffmpeg). ``hold_interrupts`` holds SIGINT and
    SIGTERM until the writer returns (for short writes through native code that an interrupt
    would leave in a broken state: HDF5); long writers (animations) stay interruptible.
    """
    target = output_target(path, inputs)
    directory = os.path.dirname(target)
    remove_stale_temps(directory, os.path.basename(target))
    tmp = temp_name(target, keep_suffix)
    with _held_interrupts(hold_interrupts) as signals, _collect_unraisable() as unraisable:
        ACTIVE_TEMPS.add(tmp)
        try:
            yield tmp
            if signals:
                raise KeyboardInterrupt
            if unraisable:
                raise OutputError(f"cannot write {os.fspath(path)!r}: "
                                  f"{_io_reason(None, unraisable)}")
            fsync_path(tmp)
            os.replace(tmp, target)
        except BaseException as exc:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            ACTIVE_TEMPS.discard(tmp)
            if isinstance(exc, (KeyboardInterrupt, UsageError)):
                raise
            reason = _io_reason(exc, unraisable)
            if reason is None:
                raise
            raise OutputError(f"cannot write {os.fspath(path)!r}: {reason}") from exc
    ACTIVE_TEMPS.discard(tmp)
    fsync_path(directory, directory=True)
    if signals:     # arrived after the last check: the file is complete, the run interrupted
        raise KeyboardInterrupt
