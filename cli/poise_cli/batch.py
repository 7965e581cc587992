"""``poise batch``: solve many decks in parallel (Dask, like ``poise sweep``)."""
from __future__ import annotations

import os
import shlex
import sys

import click

from poise.core.wording import plural, shorten
from poise_cli.options import collect_overrides, debug_option, ignore_option, json_option, \
    quiet_option, solver_options, user_code_option, worker_timeout_option, workers_given, \
    workers_option
from poise_cli.summary import fmt_num, print_json, styled_status, table_json


def _equilibrium(row: dict) -> str:
    """`` to an UNSTABLE equilibrium (2 negative modes)`` for a converged deck whose worst frame
    is unstable (neutral likewise); the modes are in the row's ``stability_modes``."""
    c = row.get("stability_class")
    if row.get("status") != "converged" or c not in ("unstable", "neutral"):
        return ""
    n = row.get("n_negative") if c == "unstable" else row.get("n_zero")
    word = "negative" if c == "unstable" else "zero"
    return (f" to {'an UNSTABLE' if c == 'unstable' else 'a NEUTRAL'} equilibrium "
            f"({plural(n, word + ' mode')}: {row.get('stability_modes', '')})")


def _line(row: dict) -> str:
    it = row.get("iterations")
    t = row.get("time")
    parts = [f"{row['deck']}: {styled_status(row['status'])}{_equilibrium(row)}"]
    if it is not None:
        parts.append(plural(it, "iteration"))
    if row.get("imbalance") is not None:
        parts.append(f"imbalance {fmt_num(row['imbalance'])}")
    if t is not None:
        parts.append(f"{t:.3g} s")
    line = ", ".join(parts)
    if row.get("ignored"):      # as poise solve's summary line
        line += f"; left out (--ignore): {row['ignored']}"
    if row.get("skipped"):
        line += " (skipped, up to date)"
    elif row.get("message"):
        line += f": {row['message']}"
    return line


@click.command(short_help="Solve many decks in parallel, one results file each.")
@click.argument("decks", nargs=-1, required=True,
                type=click.Path(exists=True, dir_okay=False, readable=True))
@workers_option
@click.option("--out-dir", type=click.Path(file_okay=False), default="poise_batch",
              show_default=True, help="Directory for <stem>.h5 files and summary.csv/.json.")
@click.option("--force", is_flag=True, help="Solve every deck even if its results are up to date.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Existing Dask scheduler, e.g. tcp://host:8786 (default: a local cluster of "
                   "-j workers). OUT_DIR must be on a filesystem the workers share.")
@worker_timeout_option
@solver_options
@user_code_option
@ignore_option
@quiet_option
@json_option
@debug_option
def batch(decks, workers, out_dir, force, scheduler, worker_timeout, method, max_num_iter,
          max_imbalance, max_error, stability, no_fallback, require_stable, allow_neutral,
          allow_user_code, ignore, quiet, as_json, debug):
    """Solve every DECK in parallel on Dask (the engine of poise sweep: a local cluster by
    default, --scheduler for a real one; a local process pool without Dask installed).

    \b
    Writes OUT_DIR/<deck stem>.h5 per deck (equal stems: <stem>-2.h5, ...) and the summary
    table OUT_DIR/summary.csv and OUT_DIR/summary.json (deck, output, status, exit_code,
    iterations, time, the worst imbalance and stability class with their frames and modes,
    skipped, message, ignored). Decks whose results file records the same deck hash, solver
    options, --ignore kinds, poise version and user scripts are skipped unless --force.
    --ignore applies to the Adams datasets among the decks.
    A deck that fails (whatever its user code does, even killing its worker) is its own row.
    Exit code: the worst deck's (0 converged, 1 not converged, 3 invalid deck, 4 internal
    error); 2 when the cluster had no worker for --worker-timeout seconds (the summary keeps
    the decks that finished).
    """
    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.app.batch import BATCH_KEYS, BATCH_VERSION, run_batch, worst_exit_code, \
        write_table
    overrides = collect_overrides(method=method, max_num_iter=max_num_iter,
                                  max_imbalance=max_imbalance, max_error=max_error,
                                  stability=stability, fallback=False if no_fallback else None,
                                  require_stable=True if require_stable else None,
                                  allow_neutral=allow_neutral)
    command = shlex.join(["poise", *sys.argv[1:]])

    def on_row(row):
        if not quiet:
            click.echo(_line(row), err=True)

    from poise_cli.errors import report_exception
    from poise_cli.streams import guarded_stdout

    table = os.path.join(out_dir, "summary.csv")

    def fail(exc):
        code, info = report_exception(exc, debug=debug)
        if as_json:
            done = getattr(exc, "rows", None) or []
            print_json(table_json("batch", out_dir, code, done,
                                  sum(bool(r["skipped"]) for r in done), table,
                                  batch_version=BATCH_VERSION, **info))
        sys.exit(code)

    try:
        with guarded_stdout(quiet):      # workers inherit fd 1: nothing of theirs on stdout
            rows = run_batch(list(decks), out_dir, jobs=workers_given(workers),
                             overrides=overrides, force=force,
                             command=command, on_row=on_row, allow_user_code=allow_user_code,
                             progress=False if quiet else None, scheduler=scheduler,
                             worker_timeout=worker_timeout,
                             **({"ignore": ignore} if ignore else {}))
    except (Exception, KeyboardInterrupt) as exc:   # out-dir not writable, no workers: exit 2
        if getattr(exc, "rows", None) is not None:  # no workers: keep what finished
            try:
                write_table(exc.rows, os.path.join(out_dir, "summary"), keys=BATCH_KEYS,
                            extra={"batch_version": BATCH_VERSION, "out_dir": out_dir,
                                   "exit_code": 2, "incomplete": True})
            except Exception:  # noqa: BLE001 - the first error is the one to report
                pass
        fail(exc)
    code = worst_exit_code(r["exit_code"] for r in rows)
    n_skipped = sum(bool(r["skipped"]) for r in rows)
    doc = table_json("batch", out_dir, code, rows, n_skipped, table,
                     batch_version=BATCH_VERSION, skipped=n_skipped)
    counts = doc["counts"]
    summary = {k: doc[k] for k in ("batch_version", "out_dir", "exit_code", "counts", "skipped")}
    try:
        write_table(rows, os.path.join(out_dir, "summary"), keys=BATCH_KEYS, extra=summary)
    except (Exception, KeyboardInterrupt) as exc:   # disk full: exit 2
        fail(exc)
    if as_json:
        print_json(doc)
    else:
        _print_table(rows)
    if not quiet:
        click.echo(f"poise batch: {plural(len(rows), 'deck')}: "
                   + ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
                   + (f" ({n_skipped} skipped, up to date)" if n_skipped else "")
                   + f"; summary in {os.path.join(out_dir, 'summary.csv')}", err=True)
    sys.exit(code)


def _print_table(rows):
    heads = ("deck", "status", "iterations", "time [s]", "stability", "message")
    data = [(r["deck"], "skipped" if r["skipped"] else r["status"],
             "" if r["iterations"] is None else str(r["iterations"]),
             "" if r["time"] is None else f"{r['time']:.3g}",
             _stability_cell(r),
             shorten("skipped (up to date)" if r["skipped"] else (r["message"] or ""), 100))
            for r in rows]
    w = [max([len(h), *(len(d[i]) for d in data)]) for i, h in enumerate(heads)]
    click.echo("  ".join(h.ljust(w[i]) for i, h in enumerate(heads)).rstrip())
    for d in data:
        click.echo("  ".join(x.ljust(w[i]) for i, x in enumerate(d)).rstrip())


def _stability_cell(r: dict) -> str:
    """``unstable (2 negative)`` / ``neutral (1 zero)`` / ``stable`` / ``""``."""
    c = r.get("stability_class")
    if c == "unstable":
        return f"unstable ({r.get('n_negative')} negative)"
    if c == "neutral":
        return f"neutral ({r.get('n_zero')} zero)"
    return c or ""
