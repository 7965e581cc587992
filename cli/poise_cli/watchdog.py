"""Ctrl-C and SIGTERM honoured even while native code holds the main thread.

Python runs a signal handler only when the main thread next executes bytecode: a LAPACK call
that never returns (an SVD of ``inf``), a long sparse factorisation or a user routine stuck in a
C library would make ``poise`` ignore Ctrl-C and SIGTERM for as long as it runs. The console
script therefore registers a wakeup file descriptor (:func:`signal.set_wakeup_fd`: the C-level
handler writes the signal number there at once, whatever the main thread does) read by a
daemon thread. On SIGINT or SIGTERM the thread watches the main thread's Python frame: if it
has not moved within :data:`GRACE` seconds (no bytecode ran, so no handler can), the thread ends
the process itself the way an interrupt does: the temporary files being written are removed
(:data:`poise.core.atomic.ACTIVE_TEMPS`), child processes are terminated, ``poise: interrupted``
is printed and the exit code is 130. When the frame moves, the normal handler runs and unwinds
(temporary files removed by their writers).

A handler's KeyboardInterrupt that lands where Python cannot raise it (a weakref callback such
as the import system's module-lock cleanup, a ``__del__``) would be printed as "Exception
ignored ... Traceback" and lost, and the command would run on: :func:`start` also installs an
unraisable-exception hook that delivers such an interrupt to the main thread again instead.

Only the ``poise`` process installs this (:func:`start`), never a library or test process.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time

#: seconds a signal may wait for the main thread before the process is ended here
GRACE = 2.0
_POLL = 0.05
#: seconds before an interrupt Python could not raise (see :func:`_unraisable_hook`) is sent again
_AGAIN = 0.02
_started = False


def start() -> None:
    """Install the wakeup descriptor and the watching thread (main thread, once)."""
    global _started
    if _started or threading.current_thread() is not threading.main_thread():
        return
    try:
        r, w = os.pipe()
        os.set_blocking(w, False)
        signal.set_wakeup_fd(w, warn_on_full_buffer=False)
    except (OSError, ValueError):
        return
    _started = True
    sys.unraisablehook = _unraisable_hook(sys.unraisablehook)
    threading.Thread(target=_watch, args=(r,), name="poise-interrupt-watchdog",
                     daemon=True).start()


def _watch(fd: int) -> None:
    wanted = {int(signal.SIGINT), int(signal.SIGTERM)}
    main = threading.main_thread().ident
    while True:
        try:
            data = os.read(fd, 64)
        except OSError:
            return
        if not data:
            return
        if wanted.intersection(data) and _stuck(main):
            _end_now()


def _unraisable_hook(hook):
    """``hook`` for every unraisable exception but an interrupt, which is signalled to the
    process again (SIGINT, or SIGTERM when SIGINT has no Python handler) from a short-lived
    thread: raised from the hook itself it would be ignored again, raised :data:`_AGAIN`
    seconds later it lands in the main thread's own code (once more, in the rare case it lands
    in a callback again)."""
    def unraisable(args):
        if not isinstance(args.exc_value, KeyboardInterrupt):
            return hook(args)
        for sig in (signal.SIGINT, signal.SIGTERM):
            if callable(signal.getsignal(sig)):
                threading.Timer(_AGAIN, os.kill, (os.getpid(), sig)).start()
                return None
        return hook(args)
    return unraisable


def _where(ident):
    frame = sys._current_frames().get(ident)
    return None if frame is None else (id(frame), id(frame.f_code), frame.f_lasti)


def _stuck(ident) -> bool:
    """True when the main thread's Python position does not change for GRACE seconds."""
    first = _where(ident)
    if first is None:
        return False
    deadline = time.monotonic() + GRACE
    while time.monotonic() < deadline:
        time.sleep(_POLL)
        if _where(ident) != first:
            return False
    return True


def _end_now() -> None:
    try:
        atomic = sys.modules.get("poise.core.atomic")
        for tmp in list(getattr(atomic, "ACTIVE_TEMPS", ())):
            try:
                os.unlink(tmp)
            except OSError:
                pass
        mp = sys.modules.get("multiprocessing")
        if mp is not None:
            for child in mp.active_children():
                child.terminate()
        os.write(2, b"poise: interrupted\n")
    finally:
        os._exit(130)
