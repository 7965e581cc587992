"""``poise bench DECK``: what accuracy costs on the user's own deck.

Runs the deck over a tolerance ladder for the chosen methods (in-process, one warm-up, median of
``--repeat`` runs) and prints a table: rung, status, iterations, counts, solve time, final
imbalance and the CG-position error (over L, the model's length scale) against a reference: the
tightest rung (1e-12, or tighter when the ladder is) of FIM_S, or of ``--reference-method``.
``--out`` writes the rows as JSON lines; ``--plot FILE.png`` the work-precision diagram
(:mod:`poise.viz.workprec`).
"""
from __future__ import annotations

import contextlib
import json
import tempfile
from pathlib import Path

import click

from poise_cli.options import TOL_MIN, debug_option, ignore_option, json_option, \
    quiet_option, user_code_option

#: version of the ``poise bench --json`` document (bump on incompatible changes)
BENCH_VERSION = 1


def _user_scripts(deck: str, dest: Path, allow: bool, ignore=()) -> None:
    """The variant decks live in ``dest``: copy the user scripts DECK names there (same
    relative paths) when ``allow``, else refuse such a deck, located in DECK itself. The
    references are checked (inside the deck's directory); nothing is imported here."""
    import shutil

    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.deck.parser import load_deck
    from poise.core.errors import DeckError
    from poise.core.user_routines import REFUSE, SKIP, load, script_path, uses_user_routine
    problems = []
    for el in load_deck(deck, **({"ignore": ignore} if ignore else {})).model:
        if not uses_user_routine(el):
            continue
        try:
            load(el, SKIP if allow else REFUSE)
        except DeckError as e:
            problems += e.problems
            continue
        to = dest / str(el.attrs["script_name"])
        to.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(script_path(el), to)
    if problems:
        raise DeckError(problems)


@contextlib.contextmanager
def _reported(fail):
    """Any error inside the block (an invalid deck met by the solves, Ctrl-C) is reported the
    CLI's way by ``fail(exc)`` (exit code, ``--json`` document), never as a traceback."""
    try:
        yield
    except click.exceptions.Exit:
        raise
    except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - reported, mapped to a code
        fail(exc)


def _cg(res):
    import numpy as np
    a = res.analyses[-1].datasets
    return np.asarray(a["bodies/position"]), float(res.model_datasets.get("length_scale", 1.0))


def _tolerances(text: str) -> list[float]:
    """The ladder rungs of ``--tolerances``: finite numbers of at least TOL_MIN (as
    ``--max-imbalance``), else a usage error naming the option and the bad rungs."""
    import math
    try:
        tols = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise click.BadParameter(f"expected comma-separated numbers, got {text!r}",
                                 param_hint="'--tolerances'") from None
    if not tols:
        raise click.BadParameter("expected comma-separated numbers, got none",
                                 param_hint="'--tolerances'")
    bad = [x.strip() for x, t in zip([x for x in text.split(",") if x.strip()], tols)
           if not math.isfinite(t) or t < TOL_MIN]
    if bad:
        raise click.BadParameter(f"every rung must be a finite number >= {TOL_MIN:g}; got "
                                 f"{', '.join(bad)}", param_hint="'--tolerances'")
    return tols


@click.command("bench")
@click.argument("deck", type=click.Path(exists=True, dir_okay=False))
@click.option("--methods", default="FIM_S", show_default=True,
              help="Comma-separated methods: FIM_S, MKEAM, FIM_D.")
@click.option("--tolerances", default="1e-2,1e-4,1e-6,1e-8,1e-10", show_default=True,
              help="Comma-separated ladder rungs.")
@click.option("--repeat", type=int, default=5, show_default=True, help="Timed runs per rung.")
@click.option("--reference-method", default="FIM_S", show_default=True,
              type=click.Choice(["FIM_S", "MKEAM", "FIM_D"], case_sensitive=False),
              help="Method whose tightest rung (1e-12, or the ladder's tightest if tighter) is "
                   "the error reference.")
@click.option("--out", type=click.Path(dir_okay=False), default=None, help="JSON lines file.")
@click.option("--plot", "plot_out", type=click.Path(dir_okay=False), default=None,
              metavar="FILE.png",
              help="Draw the work-precision diagram (error against solve time, one line per "
                   "method, log-log) to this PNG (needs poise[plot]).")
@user_code_option
@ignore_option
@quiet_option
@json_option
@debug_option
def bench(deck, methods, tolerances, repeat, reference_method, out, plot_out, allow_user_code,
          ignore, quiet, as_json, debug):
    """Time DECK over a tolerance ladder for each method and print the table.

    \b
    The error column is the largest CG position difference from the reference solution over L
    (the model's length scale); the reference is the tightest FIM_S rung unless
    --reference-method says otherwise. A deck naming Python user routines needs
    --allow-user-code (exit 3 otherwise). An Adams dataset runs as the XML deck it translates
    to; --ignore leaves out its refused statements (said after the table and recorded as
    `ignored` in the JSON). With --json the table goes to stderr and stdout holds one JSON
    object: the reference, the rows (as --out writes them) and the files written."""
    import numpy as np
    from poise_cli.errors import report_exception   # lazy: poise CMD --help stays light
    from poise_cli.streams import guarded_stdout
    from poise_cli.summary import print_json

    ctx = click.get_current_context()
    doc = {"bench_version": BENCH_VERSION, "command": "bench", "deck": deck}
    guard = contextlib.ExitStack()      # --json: fd 1 -> stderr until the JSON is printed

    def finish(code: int, **info) -> None:
        guard.close()
        if as_json:
            print_json({**doc, "exit_code": code, **info})
        ctx.exit(code)

    def fail(exc: BaseException) -> None:
        code, info = report_exception(exc, debug=debug)
        finish(code, **info)
    meths = [x.strip().upper() for x in methods.split(",") if x.strip()]
    tols = _tolerances(tolerances)
    bad = [m for m in meths if m not in ("FIM_S", "MKEAM", "FIM_D")]
    if bad or not meths or not tols:
        raise click.BadParameter(f"expected FIM_S, MKEAM and/or FIM_D, got {methods!r}",
                                 param_hint="'--methods'")
    try:   # outputs that cannot be written fail now, not after the ladder
        # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
        from poise.core.atomic import check_output
        from poise.core.errors import UsageError
        for path in (out, plot_out):
            if path:
                check_output(path, (deck,))
        if out and plot_out and check_output(out) == check_output(plot_out):
            raise UsageError(f"--plot {plot_out!r} is also the --out file")
        if plot_out:
            from poise.core.extras import require  # lazy: see above
            require("plot", "poise bench --plot")
            from poise.viz.workprec import check_picture_format  # lazy: matplotlib
            check_picture_format(plot_out)
    except Exception as exc:  # noqa: BLE001 - UsageError/OutputError/MissingExtra: exit 2
        fail(exc)
        return

    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.app.api import run_deck
    from poise.app.ladder import method_settings, run_point, with_settings
    from poise.core.progress import Bar

    if as_json:
        guard.enter_context(guarded_stdout(quiet))
    ignored: list = []
    try:
        from poise.app.runner import check_ignore  # lazy: poise CMD --help stays light
        check_ignore(deck, ignore)
    except Exception as exc:  # noqa: BLE001 - UsageError: exit 2
        fail(exc)
        return
    if deck.lower().endswith((".adm", ".acf")):       # an Adams dataset: its XML deck
        from poise.app.convert import xml_text  # lazy: only Adams datasets need it
        try:
            xml, ignored = xml_text(deck, ignore)
        except Exception as exc:  # noqa: BLE001 - DeckError: located, exit 3
            fail(exc)
            return
    else:
        xml = Path(deck).read_text()
    if ignored:
        doc["ignored"] = ignored
    ref = None
    rows = []
    with _reported(fail), tempfile.TemporaryDirectory(prefix="poise-bench-") as td:
        try:
            _user_scripts(deck, Path(td), allow_user_code, ignore)
        except Exception as exc:  # noqa: BLE001 - DeckError: located, exit 3
            fail(exc)
            return
        ref_method = reference_method.upper()
        ref_tol = min([1e-12, *tols])
        st, tr = method_settings(ref_method, ref_tol)
        p = Path(td) / "ref.xml"
        p.write_bytes(with_settings(xml, st, tr))
        ref_res = run_deck(str(p), allow_user_code=allow_user_code, quiet=True)
        ref = _cg(ref_res)
        if any(a.status != "converged" for a in ref_res.analyses) and not quiet:
            click.echo(f"poise bench: warning: the reference ({ref_method} at {ref_tol:.0e}) did "
                       "not converge; the errors are against its last state", err=True)
        click.echo(f"{'method':6} {'rung':>7} {'status':9} {'iter':>5} {'res/jac/fac':>13} "
                   f"{'solve s (min-max)':>24} {'imbalance':>10} {'error/L':>9}")
        bar = Bar(len(meths) * len(tols), "bench", "rungs", enabled=False if quiet else None,
                  delay=0.0)
        for m in meths:
            for tol in tols:
                st, tr = method_settings(m, tol)
                r, _ = run_point(xml, st, tr, repeat, Path(td), allow_user_code=allow_user_code)
                err = err_abs = None
                p = Path(td) / "variant.xml"
                x, L = _cg(run_deck(str(p), overrides={"fallback": False}, quiet=True,
                                    allow_user_code=allow_user_code))
                if x.shape == ref[0].shape:
                    err_abs = float(np.max(np.abs(x - ref[0])))
                    err = err_abs / L
                r.update(method=m, tol=tol, error=err, error_abs=err_abs, deck=deck,
                         reference=f"{ref_method} {ref_tol:.0e}",
                         **({"ignored": ignored} if ignored else {}))
                rows.append(r)
                bar.clear()
                c, s = r["counts"], r["solve_s"]
                cnt = f"{c.get('residuals', 0)}/{c.get('jacobians', 0)}/{c.get('factorizations', 0)}"
                click.echo(f"{m:6} {tol:7.0e} {r['status']:9} {r['iterations']:5d} {cnt:>13} "
                           f"{s['median']:9.4g} ({s['min']:.3g}-{s['max']:.3g}) "
                           f"{r['imbalance'] if r['imbalance'] is not None else float('nan'):10.2e} "
                           f"{'—' if err is None else f'{err:9.1e}':>9}")
                bar.step()
        bar.close()
    if ignored and not quiet:       # as poise solve's summary line
        from poise.app.runner import ignored_text  # lazy: poise CMD --help stays light
        click.echo(f"poise bench: {ignored_text(ignored)}", err=True)
    if plot_out:
        try:
            # lazy: matplotlib (poise[plot]) only when --plot is given
            from poise.viz.plot import units_of
            from poise.viz.workprec import write_work_precision
            write_work_precision(rows, plot_out, units_of(ref_res.units)["length"],
                                 title=Path(deck).name,
                                 reference=f"{ref_method} at {ref_tol:.0e}")
        except Exception as exc:  # noqa: BLE001 - not writable: exit 2
            fail(exc)
            return
        if not quiet:
            click.echo(f"wrote {plot_out}", err=True)
    if out:
        try:
            from poise.core.atomic import atomic_output  # lazy: see above
            with atomic_output(out, (deck,)) as tmp, open(tmp, "w") as f:
                for r in rows:
                    f.write(json.dumps(r, default=float) + "\n")
        except Exception as exc:  # noqa: BLE001 - OutputError (disk full ...): exit 2
            fail(exc)
            return
    finish(0, status="completed", methods=meths, tolerances=tols, repeat=repeat,
           reference=dict(method=ref_method, tol=ref_tol,
                          status="converged" if all(a.status == "converged"
                                                    for a in ref_res.analyses) else "failed"),
           length_unit=_length_unit(ref_res), length_scale=ref[1], out=out, plot=plot_out,
           rows=rows)


def _length_unit(res) -> str:
    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.results.schema import unit_symbols
    return unit_symbols(res.units)["length"]
