"""``poise`` command group.

Keep this module (and the command modules it imports) light: no numpy, scipy, h5py or lxml at
import time. Heavy imports happen inside the command functions.
"""
from __future__ import annotations

import os
import sys

import click

import poise_cli
from poise import __version__

CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"], "max_content_width": 100}

#: name -> (module, one-line help). Command modules are imported only when their command runs
#: (``poise solve`` never imports the plot/animate/batch/sweep/bench modules) and ``poise --help``
#: prints this table without importing any of them; tests/cli/test_startup.py checks it against the
#: commands' own short help.
COMMANDS = {
    "animate": ("poise_cli.animate", "Animate a results file as a stick figure (GIF, MP4 or PNG)."),
    "batch": ("poise_cli.batch", "Solve many decks in parallel, one results file each."),
    "bench": ("poise_cli.bench", "Time DECK over a tolerance ladder for each method and print "
                                 "the table."),
    "check": ("poise_cli.check", "Validate a deck and print its structure (no solve)."),
    "convert": ("poise_cli.convert", "Write an Adams dataset (.adm/.acf) as a MotionSolve XML "
                                     "deck."),
    "plot": ("poise_cli.plot", "Plot convergence and time histories of a results file (PNG)."),
    "show": ("poise_cli.show", "Summarise an HDF5 results file."),
    "solve": ("poise_cli.solve", "Solve a deck and write the HDF5 results file."),
    "sweep": ("poise_cli.sweep", "Parameter sweep of a deck on Dask (local cluster or scheduler)."),
}


class LazyGroup(click.Group):
    """A group whose subcommands are imported on first use (see :data:`COMMANDS`), and whose
    console-script call ends the process without interpreter finalisation (:func:`end_process`)."""

    def list_commands(self, ctx):
        return sorted(set(self.commands) | set(COMMANDS))

    def get_command(self, ctx, name):
        if name not in self.commands and name in COMMANDS:
            import importlib
            self.add_command(getattr(importlib.import_module(COMMANDS[name][0]), name), name)
        return self.commands.get(name)

    def format_commands(self, ctx, formatter):
        names = self.list_commands(ctx)
        limit = formatter.width - 6 - max(len(n) for n in names)
        rows = [(n, (self.commands.get(n) or click.Command(n, help=COMMANDS[n][1]))
                 .get_short_help_str(limit)) for n in names]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def invoke(self, ctx):
        # Ctrl-C (and SIGTERM, _install_sigterm) in a command: one line, exit 130, never a
        # traceback or click's "Aborted!" (exit 1)
        previous = _install_sigterm()
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            interrupted()
        finally:
            if not _PROCESS:        # a test or library caller: its dispositions as they were
                _restore(previous)

    def __call__(self, *args, **kwargs):
        # The console script, ``python -m poise_cli`` and ``python -c`` call ``cli()`` from
        # ``__main__``: end the process fast there. Anywhere else (tests, CliRunner, a library
        # caller catching SystemExit) behave like click.
        if (kwargs.get("standalone_mode", True) is False
                or sys._getframe(1).f_globals.get("__name__") != "__main__"):
            return self.main(*args, **kwargs)
        global _PROCESS
        _PROCESS = True
        from poise_cli import watchdog
        watchdog.start()    # Ctrl-C/SIGTERM honoured while native code holds the main thread
        try:
            try:
                self.main(*args, **kwargs)
            except SystemExit as e:
                end_process(e.code)
            end_process(0)
        except KeyboardInterrupt:       # between the command and the end of the process
            _quiet_exit(EXIT_INTERRUPTED)


EXIT_INTERRUPTED = 130


def interrupted():
    """Report an interrupt (Ctrl-C, SIGTERM) in one line and exit 130."""
    from poise_cli.errors import say_interrupted
    say_interrupted()
    raise click.exceptions.Exit(EXIT_INTERRUPTED)


def _quiet_exit(code: int) -> None:
    try:
        from poise_cli.errors import say_interrupted
        say_interrupted()
    except BaseException:  # noqa: BLE001 - nothing more can be reported
        pass
    os._exit(code)


def _interrupt(signum, frame):
    """Ctrl-C in a command: remembered (:data:`poise_cli.signalled`), then raised as
    KeyboardInterrupt: unwinds (temporary files removed), exit 130. SIGTERM is handled alike."""
    poise_cli.signalled = True
    raise KeyboardInterrupt



#: True in the process the console script (or ``python -m poise_cli``) runs: the command owns
#: the process and its signal dispositions
_PROCESS = False


def _install_sigterm() -> dict:
    """Install the command's handlers; returns the ones replaced (signal -> handler)."""
    import signal
    import threading
    from poise_cli import _early_interrupt
    previous: dict = {}
    if threading.current_thread() is threading.main_thread():
        try:
            if signal.getsignal(signal.SIGINT) is _early_interrupt:
                previous[signal.SIGINT] = signal.signal(signal.SIGINT, _interrupt)
            if signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, _early_interrupt):
                previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, _interrupt)
        except (ValueError, OSError):
            pass
    return previous


def _restore(previous: dict) -> None:
    import signal
    for sig, handler in previous.items():
        try:
            signal.signal(sig, handler)
        except (ValueError, OSError):
            pass


def end_process(code) -> None:
    """Exit with ``code`` once the command is done, skipping interpreter finalisation.

    Tearing down numpy, h5py, lxml and a few hundred modules costs ~40 ms, a large share of a
    small deck's whole process. By the time a command returns, its results file is closed,
    fsync'ed and renamed; so the exit handlers are run (``atexit``: logging, h5py, user code),
    stdout/stderr are flushed and the process ends with ``os._exit``. Falls back to a normal
    ``sys.exit`` when another non-daemon thread is still running, when ``code`` is not an
    integer, or when ``POISE_FULL_EXIT`` is set (e.g. to let a user routine's finalisers run).
    """
    if code is None:
        code = 0
    th = sys.modules.get("threading")
    if (not isinstance(code, int) or os.environ.get("POISE_FULL_EXIT")
            or (th is not None and any(t is not th.main_thread() and not t.daemon and t.is_alive()
                                       for t in th.enumerate()))):
        sys.exit(code)
    import atexit
    run_exitfuncs = getattr(atexit, "_run_exitfuncs", None)
    if run_exitfuncs is None:  # not CPython
        sys.exit(code)
    run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # e.g. a closed pipe; Python exits with 120 in that case
            code = code or 120
    os._exit(code)


@click.group(cls=LazyGroup, context_settings=CONTEXT_SETTINGS)
@click.version_option(__version__, "-V", "--version", prog_name="poise",
                      message="%(prog)s %(version)s")
def cli() -> None:
    """Static equilibria of MotionSolve-style XML multibody decks, results in HDF5.

    \b
    Exit codes:
      0  every analysis converged
      1  an analysis did not converge (results file written)
      2  usage error
      3  invalid deck (located problems on stderr)
      4  internal error (rerun with --debug for the traceback)
    130  interrupted (Ctrl-C or SIGTERM)
    """


def main() -> None:  # pragma: no cover - console entry alias
    cli(prog_name="poise")


if __name__ == "__main__":  # ``python -m poise_cli.main`` (also ``python -m poise_cli``)
    cli(prog_name="poise")
