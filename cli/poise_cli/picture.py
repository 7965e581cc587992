"""What ``poise plot`` and ``poise animate`` share: check the results file, make the picture,
report errors with the CLI's exit codes (the commands stay independent of each other)."""
from __future__ import annotations

import click

from poise_cli.errors import report_exception
from poise_cli.summary import print_json


def run_picture(ctx, results, make, as_json, debug, quiet, message) -> None:
    """Shared body of ``poise plot`` / ``poise animate``: check the results file, call ``make()``
    (returns an info dict), report errors with the CLI's exit codes, print the JSON or the line."""
    try:
        results_or_usage(results)
        info = make()
    except (Exception, KeyboardInterrupt) as exc:
        code, info = report_exception(exc, debug=debug)
        if as_json:
            print_json({"results": results, "output": None, "exit_code": code, **info})
        ctx.exit(code)
        return
    if as_json:
        print_json({"results": results, "exit_code": 0, **info})
    if not quiet:
        click.echo(message(info), err=True)
    ctx.exit(0)


def results_or_usage(path: str) -> None:
    """Exit 2 when PATH is not a poise results file."""
    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.core.errors import UsageError
    from poise.results.hdf5 import ResultsFormatError, open_checked
    try:
        open_checked(path).close()
    except ResultsFormatError as e:
        raise UsageError(str(e)) from None
