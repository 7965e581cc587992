"""Exception -> exit code mapping and error reporting for the CLI.

Exit codes
----------
0  every analysis converged
1  an analysis did not converge (the results file was written)
2  usage error (bad option, missing file, unreadable results file)
3  invalid deck (``poise.core.errors.DeckError``): every located problem printed on stderr
4  internal error: one line on stderr, traceback only with ``--debug``
"""
from __future__ import annotations

import sys
import traceback

import click

import poise_cli

EXIT_OK = 0
EXIT_NOT_CONVERGED = 1
EXIT_USAGE = 2
EXIT_INVALID_DECK = 3
EXIT_INTERNAL = 4
EXIT_INTERRUPTED = 130


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _interrupted(exc: BaseException) -> bool:
    """``exc`` is, or was caused by, a KeyboardInterrupt (Ctrl-C/SIGTERM landing inside code
    that wraps exceptions, e.g. ``RuntimeError: Error calling __set_name__`` at import), or the
    command's handler saw Ctrl-C/SIGTERM before it (:data:`poise_cli.signalled`: code that
    replaces the KeyboardInterrupt without chaining it, e.g. Cython's ``ImportError: Failed to
    import 'zlib.decompress'`` when the signal lands inside an import)."""
    if poise_cli.signalled:
        return True
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


_said_interrupted = False


def say_interrupted() -> None:
    """Print ``poise: interrupted`` once per process and ignore further Ctrl-C/SIGTERM (a
    second interrupt while the first unwinds, e.g. as a batch's workers die, says nothing more)."""
    global _said_interrupted
    if _said_interrupted:
        return
    import os
    if os.path.basename(sys.argv[0] if sys.argv else "") in ("poise", "__main__.py"):
        _said_interrupted = True       # the process ends now (not a test or library caller)
        _ignore_interrupts()
    try:
        sys.stderr.write("poise: interrupted\n")
        sys.stderr.flush()
    except BaseException:  # noqa: BLE001 - nothing more can be reported
        pass


def _ignore_interrupts() -> None:
    try:
        import signal
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    except (ValueError, OSError):      # not the main thread
        pass


def report_exception(exc: BaseException, debug: bool = False) -> tuple[int, dict]:
    """Print ``exc`` on stderr the way the CLI reports it and return ``(exit_code, info)``.

    ``info`` is merged into the ``--json`` summary: ``status`` plus ``problems`` (invalid deck)
    or ``error`` (other errors).
    """
    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.core.errors import DeckError, UsageError, one_line  # light module (dataclasses only)

    if isinstance(exc, DeckError):
        problems = [one_line(p) for p in exc.problems] or [one_line(exc)]
        if debug:
            traceback.print_exception(exc, file=sys.stderr)
        for line in problems:
            click.echo(line, err=True)
        n = len(problems)
        click.echo(f"poise: invalid deck: {n} problem{'s' if n != 1 else ''}", err=True)
        return EXIT_INVALID_DECK, {"status": "invalid_deck", "problems": problems}
    if isinstance(exc, UsageError):
        click.echo(f"poise: error: {_one_line(exc)}", err=True)
        return EXIT_USAGE, {"status": getattr(exc, "status", "usage_error"),
                            "error": _one_line(exc)}
    if _interrupted(exc):
        say_interrupted()
        return EXIT_INTERRUPTED, {"status": "interrupted", "error": "interrupted"}
    msg = f"{type(exc).__name__}: {_one_line(exc)}" if str(exc) else type(exc).__name__
    if debug:
        traceback.print_exception(exc, file=sys.stderr)
        click.echo(f"poise: internal error: {msg}", err=True)
    else:
        click.echo(f"poise: internal error: {msg}; rerun with --debug for the traceback",
                   err=True)
    return EXIT_INTERNAL, {"status": "internal_error", "error": msg}
