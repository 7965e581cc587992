"""One run at a time writes into an output directory (``poise sweep``, ``poise batch``).

Two sweeps started into one ``--out-dir`` would each find no finished case and both solve all
of them, then overwrite each other's index. :func:`directory_lock` holds an exclusive
``flock`` on ``OUT_DIR/.poise.lock`` for the whole run (from before the finished cases are
looked for until the index is written): a second run says who holds it and waits, then finds
the first run's cases finished and resumes them instead of solving them again. The lock goes
with its process (a killed run leaves no stale lock); the file stays, holding the last
holder's ``pid@host``. The wait is interruptible (Ctrl-C, SIGTERM).
"""
from __future__ import annotations

import contextlib
import os
import socket

from poise.core.atomic import OutputError

LOCK_NAME = ".poise.lock"


@contextlib.contextmanager
def directory_lock(out_dir: str, what: str = "run", say=None):
    """Hold ``OUT_DIR/.poise.lock`` inside the block; ``say(line)`` is told when another
    process holds it (then the block waits for it)."""
    import fcntl
    path = os.path.join(out_dir, LOCK_NAME)
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as e:
        raise OutputError(f"cannot write {path!r}: {e.strerror or e}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "another process"
            if say is not None:
                say(f"waiting for the poise {what} writing into {out_dir} ({holder}) to finish")
            fcntl.flock(fd, fcntl.LOCK_EX)
        me = f"poise {what}, pid {os.getpid()}@{socket.gethostname()}".encode()
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
            os.pwrite(fd, me, 0)
        yield
    finally:
        os.close(fd)                         # releases the lock
