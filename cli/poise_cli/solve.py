"""``poise solve``: run every analysis of a deck and write the HDF5 results file."""
from __future__ import annotations

import os
import shlex
import sys
from pathlib import Path

import click

from poise_cli.errors import report_exception
from poise_cli.options import collect_overrides, debug_option, ignore_option, json_option, \
    quiet_option, solver_options, user_code_option
from poise_cli.summary import analysis_line, analysis_summary, analysis_time, print_json, \
    sanitize, solve_summary


def default_output(deck: str) -> str:
    """``<deck stem>.h5`` in the current directory."""
    return str(Path.cwd() / (Path(deck).stem + ".h5"))


@click.command(short_help="Solve a deck and write the HDF5 results file.")
@click.argument("deck", type=click.Path(exists=True, dir_okay=False, readable=True))
@click.option("-o", "--output", type=click.Path(dir_okay=False, writable=True), default=None,
              help="Results file (HDF5). Default: <deck stem>.h5 in the current directory.")
@solver_options
@user_code_option
@ignore_option
@quiet_option
@json_option
@debug_option
def solve(deck, output, method, max_num_iter, max_imbalance, max_error, stability,
          no_fallback, require_stable, allow_neutral, allow_user_code, ignore, quiet, as_json,
          debug):
    """Solve every analysis of DECK and write the results to an HDF5 file.

    The file is written even when an analysis fails (exit code 1). Options given here override
    the deck's Param_Static attributes.
    """
    ctx = click.get_current_context()
    out = output or default_output(deck)
    out_dir = os.path.dirname(os.path.abspath(out))
    if not os.path.isdir(out_dir):
        raise click.BadParameter(f"directory {out_dir!r} does not exist",
                                 param_hint="'-o' / '--output'")
    if not os.access(out_dir, os.W_OK | os.X_OK):     # refused now, not after the solve
        raise click.BadParameter(f"directory {out_dir!r} is not writable",
                                 param_hint="'-o' / '--output'")
    overrides = collect_overrides(method=method, max_num_iter=max_num_iter,
                                  max_imbalance=max_imbalance, max_error=max_error,
                                  stability=stability,
                                  fallback=False if no_fallback else None,
                                  require_stable=True if require_stable else None,
                                  allow_neutral=allow_neutral)
    command = shlex.join(["poise", *sys.argv[1:]])
    reported: list[str] = []

    def progress(line: str) -> None:
        reported.append(line)
        if not quiet:
            click.echo(line, err=True)

    def fail(exc: BaseException, output_path: str | None = None) -> None:
        code, info = report_exception(exc, debug=debug)
        if as_json:
            print_json(solve_summary(deck, output_path, info.pop("status"), code, [], {}, [],
                                     **info))
        ctx.exit(code)

    try:  # before the solve: a path that cannot take the results fails now, not after it
        # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
        from poise.core.atomic import output_target
        output_target(out, (deck,))
    except (Exception, KeyboardInterrupt) as exc:   # UsageError: exit 2
        fail(exc)
        return

    from poise_cli.streams import collected_warnings, guarded_stdout
    try:
        with guarded_stdout(quiet), collected_warnings() as numeric:
            # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
            from poise.app.api import run_deck
            more = {"ignore": ignore} if ignore else {}      # Adams datasets only
            result = run_deck(deck, overrides, command=command, progress=progress, quiet=quiet,
                              allow_user_code=allow_user_code, **more)
    except (Exception, KeyboardInterrupt) as exc:
        fail(exc)
        return

    result.warnings = list(result.warnings) + numeric   # recorded in the file and the JSON
    warnings = [str(w) for w in result.warnings]
    if not quiet:
        for w in warnings:
            click.echo(f"warning: {w}", err=True)

    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.core import phases
    try:
        with phases.counting_imports(), guarded_stdout(quiet), collected_warnings():
            t0, imported = phases.now(), phases.import_seconds()   # imports: their own phase
            from poise.results.hdf5 import write_results   # lazy: h5py, timed as import
            write_results(result, out)
            t_write = phases.now() - t0
            imported = phases.import_seconds() - imported
    except (Exception, KeyboardInterrupt) as exc:
        fail(exc)
        return
    timings = dict(result.timings)
    timings["write"] = t_write
    timings["import"] = timings.get("import", 0.0) + imported

    if not quiet:
        if not reported:  # the runner did not report per analysis: print our own lines
            for a in result.analyses:
                click.echo(analysis_line(analysis_summary(a), analysis_time(timings, a.index)),
                           err=True)
        n_failed = sum(not a.converged for a in result.analyses)
        if n_failed:
            click.echo(f"poise: {n_failed} of {len(result.analyses)} analyses did not converge",
                       err=True)
        click.echo(f"wrote {out}", err=True)

    code = result.exit_code
    if as_json:
        print_json(sanitize(solve_summary(
            deck, out, result.status, code, [analysis_summary(a) for a in result.analyses],
            timings, warnings)))
    ctx.exit(code)
