"""Safe, atomic output files: results (HDF5), plots (PNG) and animations (GIF/MP4).

Every output file is written to a hidden temporary file next to its target, flushed and
fsync'ed, then renamed over the target with :func:`os.replace`, and the directory is fsync'ed.
A process killed mid-write leaves at most the hidden temporary file, never a partial file under
the final name; any exception removes the temporary file and leaves the target untouched.

:func:`output_target` decides the target first: symbolic links are followed (the file a link
points to is replaced, not the link), and a path that exists but is not a regular file (a
directory, a device such as ``/dev/null``, a FIFO: the rename would replace the device node
itself) or that is one of the inputs (the deck) is refused with
:class:`poise.errors.UsageError` (CLI exit code 2).
"""
from __future__ import annotations

import contextlib
import os
import stat


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
    from poise.errors import UsageError
    path = os.fspath(path)
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
    except FileNotFoundError:
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


@contextlib.contextmanager
def atomic_output(path, inputs=(), keep_suffix: bool = False):
    """Context manager yielding the temporary path to write instead of ``path``.

    On a clean exit the temporary file is fsync'ed and renamed over the target
    (:func:`output_target`); on any exception (also KeyboardInterrupt) it is removed.
    ``keep_suffix`` appends the target's extension to the temporary name, for writers that
    choose the format by extension (matplotlib, ffmpeg).
    """
    target = output_target(path, inputs)
    directory = os.path.dirname(target)
    name = os.path.basename(target)
    tmp = os.path.join(directory, f".{name}.tmp-{os.getpid()}"
                       + (os.path.splitext(name)[1] if keep_suffix else ""))
    try:
        yield tmp
        fsync_path(tmp)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    fsync_path(directory, directory=True)
