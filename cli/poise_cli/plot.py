"""``poise plot``: convergence history and quasi-static time histories as a PNG."""
from __future__ import annotations

from pathlib import Path

import click

from poise_cli.options import debug_option, json_option, quiet_option
from poise_cli.picture import run_picture


def id_list(ctx, param, value):
    """Comma-separated ids or deck labels (``2,3`` or ``'Wrist pin,Slide'``)."""
    if value is None:
        return None
    out = [x.strip() for x in value.split(",") if x.strip()]
    return [int(x) if x.lstrip("-").isdigit() else x for x in out]


@click.command(short_help="Plot convergence and time histories of a results file (PNG).")
@click.argument("results", type=click.Path(exists=True, dir_okay=False, readable=True))
@click.option("-o", "--out", type=click.Path(dir_okay=False), default=None,
              help="PNG file. Default: <results stem>.png next to the results file.")
@click.option("--analysis", type=int, default=None, help="Analysis index (default: the last).")
@click.option("--bodies", callback=id_list, default=None, metavar="IDS",
              help="Body ids or labels for position histories, e.g. 2,3 or 'Crank,Rod'.")
@click.option("--joints", callback=id_list, default=None, metavar="IDS",
              help="Joint ids or labels for force histories, e.g. 'Wrist pin'.")
@click.option("--requests", callback=id_list, default=None, metavar="IDS",
              help="Post_Request ids or labels for channel histories.")
@quiet_option
@json_option
@debug_option
def plot(results, out, analysis, bodies, joints, requests, quiet, as_json, debug):
    """Plot the convergence of RESULTS (static: imbalance and error per iteration, log scale;
    quasi-static: the final imbalance/error of each frame against time with the tolerance lines,
    and iterations per frame; MKEAM kinetic energy per iteration) and, for quasi-static runs,
    time histories of body positions, joint forces and request channels. Axes carry the deck's
    units; legends name bodies by their deck label."""
    ctx = click.get_current_context()
    out = out or str(Path(results).with_suffix(".png"))
    def make():
        # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
        from poise.viz.plot import write_plot
        return write_plot(results, out, analysis=analysis, bodies=bodies, joints=joints,
                            requests=requests)

    run_picture(ctx, results, make, as_json, debug, quiet,
                lambda info: f"wrote {out} ({info['width']}x{info['height']}, "
                             f"{', '.join(info['panels'])})")
