"""``poise sweep``: parameter sweep of one deck on Dask distributed."""
from __future__ import annotations

import os
import sys

import click

from poise.core.wording import plural
from poise_cli.errors import report_exception
from poise_cli.options import collect_overrides, debug_option, ignore_option, json_option, \
    quiet_option, solver_options, user_code_option, worker_timeout_option, workers_option
from poise_cli.summary import print_json, table_json


@click.command(short_help="Parameter sweep of a deck on Dask (local cluster or scheduler).")
@click.argument("deck", type=click.Path(exists=True, dir_okay=False, readable=True))
@click.option("--set", "sets", multiple=True, required=True, metavar="TAG[ID].ATTR=VALUES",
              help="Attribute to vary: Tag[id].attr or Tag.attr (single element such as "
                   "Param_Static), VALUES an inclusive range a:b:step or a list v1,v2. Repeat.")
@click.option("--grid", "mode", flag_value="grid", default=True,
              help="All combinations (default).")
@click.option("--zip", "mode", flag_value="zip", help="Parameters in lock-step (equal lengths).")
@click.option("--random", "n_random", type=click.IntRange(min=1), default=None, metavar="N",
              help="N random cases (ranges of reals sampled uniformly, lists by choice).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed for --random.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Existing Dask scheduler, e.g. tcp://host:8786 (default: a local cluster).")
@workers_option
@worker_timeout_option
@click.option("--out-dir", type=click.Path(file_okay=False), default="poise_sweep",
              show_default=True, help="Directory for case_NNNNN.h5 and index.csv/index.json.")
@click.option("--output", "outputs", multiple=True, metavar="GROUP[ID].DATASET",
              help="Index column(s) from the last frame, e.g. bodies[2].position, "
                   "joints[1].force, requests[1].values: any per-element dataset of "
                   "docs/results-format.md. Repeat.")
@click.option("--force", is_flag=True, help="Rerun cases whose results file is complete.")
@click.option("--max-cases", type=click.IntRange(min=1), default=100_000, show_default=True,
              help="Refuse sweeps with more cases than this (counted before any case is made).")
@solver_options
@user_code_option
@ignore_option
@quiet_option
@json_option
@debug_option
def sweep(deck, sets, mode, n_random, seed, scheduler, workers, worker_timeout, out_dir, outputs,
          force, max_cases, method, max_num_iter, max_imbalance, max_error, stability,
          no_fallback, require_stable, allow_neutral, allow_user_code, ignore, quiet, as_json,
          debug):
    """Solve DECK once per combination of --set values on Dask distributed.

    \b
    Each case writes OUT_DIR/case_NNNNN.h5; OUT_DIR/index.csv and index.json hold one row per
    case: case, the parameter values, file, status, exit_code, iterations, wall_time, the
    worst imbalance and stability class with their frames and modes, resumed, message, ignored
    (what --ignore left out of an Adams dataset) and the --output columns. Cases whose file is complete and was
    made with the same values are not run again (resume after an interruption).
    Exit code: the worst case's (0, 1, 3, 4); 2 for a bad --set/--output, or when the cluster
    had no worker for --worker-timeout seconds (the index keeps the finished cases); 3 invalid
    deck.
    """
    ctx = click.get_current_context()
    overrides = collect_overrides(method=method, max_num_iter=max_num_iter,
                                  max_imbalance=max_imbalance, max_error=max_error,
                                  stability=stability, fallback=False if no_fallback else None,
                                  require_stable=True if require_stable else None,
                                  allow_neutral=allow_neutral)
    if n_random is not None:
        mode = "random"
    index = os.path.join(out_dir, "index.csv")

    def on_row(row):
        if not quiet and (row.get("exit_code") or 0) not in (0, 1):
            click.echo(f"case {row['case']}: {row['status']}: {row.get('message', '')}", err=True)

    from poise_cli.streams import guarded_stdout
    try:
        # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
        from poise.app.batch import worst_exit_code
        from poise.app.sweep import INDEX_VERSION, run_sweep
        with guarded_stdout(quiet):      # workers inherit fd 1: nothing of theirs on stdout
            rows = run_sweep(deck, list(sets), mode=mode, out_dir=out_dir, scheduler=scheduler,
                             outputs=list(outputs), n=n_random, seed=seed,
                             workers=workers or None,
                             overrides=overrides, force=force, progress=None if not quiet else False,
                             on_row=on_row, max_cases=max_cases, allow_user_code=allow_user_code,
                             worker_timeout=worker_timeout,
                             **({"ignore": ignore} if ignore else {}))
    except (Exception, KeyboardInterrupt) as exc:
        code, info = report_exception(exc, debug=debug)
        if as_json:
            done = getattr(exc, "rows", None) or []
            print_json(table_json("sweep", out_dir, code, done,
                                  sum(bool(r.get("resumed")) for r in done), index,
                                  index_version=1, deck=deck, **info))
        ctx.exit(code)
        return
    code = worst_exit_code(r["exit_code"] for r in rows)
    n_resumed = sum(bool(r.get("resumed")) for r in rows)
    doc = table_json("sweep", out_dir, code, rows, n_resumed, index,
                     index_version=INDEX_VERSION, deck=deck, n_cases=len(rows),
                     resumed=n_resumed, index=index)
    counts = doc["counts"]
    if as_json:
        print_json(doc)
    if not quiet:
        left = next((r["ignored"] for r in rows if r.get("ignored")), "")
        click.echo(f"poise sweep: {plural(len(rows), 'case')}: "
                   + ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
                   + f" ({n_resumed} resumed, {len(rows) - n_resumed} run); index in "
                   + os.path.join(out_dir, "index.csv")
                   + (f"; left out (--ignore): {left}" if left else ""), err=True)
    sys.stdout.flush()
    ctx.exit(code)
