"""``poise bench DECK``: what accuracy costs on the user's own deck.

Runs the deck over a tolerance ladder for the chosen methods (in-process, one warm-up, median of
``--repeat`` runs) and prints a table: rung, status, iterations, counts, solve time, final
imbalance and — with ``--reference-method`` — the CG-position error against a tight solution
(rung 1e-12) of another method. ``--out`` writes the rows as JSON lines.
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import click

from poise_cli.options import user_code_option


def _user_scripts(deck: str, dest: Path, allow: bool) -> None:
    """The variant decks live in ``dest``: copy the user scripts DECK names there (same
    relative paths) when ``allow``, else refuse such a deck, located in DECK itself. The
    references are checked (inside the deck's directory); nothing is imported here."""
    import shutil

    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.deck.parser import load_deck
    from poise.core.errors import DeckError
    from poise.core.user_routines import REFUSE, SKIP, load, script_path, uses_user_routine
    problems = []
    for el in load_deck(deck).model:
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


def _cg(res):
    import numpy as np
    a = res.analyses[-1].datasets
    return np.asarray(a["bodies/position"]), float(res.model_datasets.get("length_scale", 1.0))


@click.command("bench")
@click.argument("deck", type=click.Path(exists=True, dir_okay=False))
@click.option("--methods", default="FIM_S", show_default=True,
              help="Comma-separated methods: FIM_S, MKEAM, FIM_D.")
@click.option("--tolerances", default="1e-2,1e-4,1e-6,1e-8,1e-10", show_default=True,
              help="Comma-separated ladder rungs.")
@click.option("--repeat", type=int, default=5, show_default=True, help="Timed runs per rung.")
@click.option("--reference-method", default=None,
              help="Method whose rung-1e-12 solution is the error reference (e.g. MKEAM).")
@click.option("--out", type=click.Path(dir_okay=False), default=None, help="JSON lines file.")
@user_code_option
def bench(deck, methods, tolerances, repeat, reference_method, out, allow_user_code):
    """Time DECK over a tolerance ladder for each method and print the table.

    A deck naming Python user routines needs --allow-user-code (exit 3 otherwise)."""
    import numpy as np

    # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
    from poise.app.api import run_deck
    from poise.app.ladder import method_settings, run_point, with_settings

    xml = Path(deck).read_text()
    ref = None
    rows = []
    with tempfile.TemporaryDirectory(prefix="poise-bench-") as td:
        try:
            _user_scripts(deck, Path(td), allow_user_code)
        except Exception as exc:  # noqa: BLE001 - DeckError: located, exit 3
            from poise_cli.errors import report_exception
            click.get_current_context().exit(report_exception(exc)[0])
        if reference_method:
            st, tr = method_settings(reference_method.upper(), 1e-12)
            p = Path(td) / "ref.xml"
            p.write_bytes(with_settings(xml, st, tr))
            ref = _cg(run_deck(str(p), allow_user_code=allow_user_code))
        click.echo(f"{'method':6} {'rung':>7} {'status':9} {'iter':>5} {'res/jac/fac':>13} "
                   f"{'solve s (min-max)':>24} {'imbalance':>10} {'error/L':>9}")
        for m in [x.strip().upper() for x in methods.split(",") if x.strip()]:
            for tol in [float(x) for x in tolerances.split(",") if x.strip()]:
                st, tr = method_settings(m, tol)
                r, _ = run_point(xml, st, tr, repeat, Path(td), allow_user_code=allow_user_code)
                err = None
                if ref is not None:
                    p = Path(td) / "variant.xml"
                    x, L = _cg(run_deck(str(p), overrides={"fallback": False},
                                  allow_user_code=allow_user_code))
                    if x.shape == ref[0].shape:
                        err = float(np.max(np.abs(x - ref[0]))) / L
                r.update(method=m, tol=tol, error=err, deck=deck)
                rows.append(r)
                c, s = r["counts"], r["solve_s"]
                cnt = f"{c.get('residuals', 0)}/{c.get('jacobians', 0)}/{c.get('factorizations', 0)}"
                click.echo(f"{m:6} {tol:7.0e} {r['status']:9} {r['iterations']:5d} {cnt:>13} "
                           f"{s['median']:9.4g} ({s['min']:.3g}-{s['max']:.3g}) "
                           f"{r['imbalance'] if r['imbalance'] is not None else float('nan'):10.2e} "
                           f"{'—' if err is None else f'{err:9.1e}':>9}")
    if out:
        with open(out, "w") as f:
            for r in rows:
                f.write(json.dumps(r, default=float) + "\n")
