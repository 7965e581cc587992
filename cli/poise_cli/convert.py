"""``poise convert``: an Adams dataset or command file -> a MotionSolve XML deck."""
from __future__ import annotations

import click

from poise_cli.errors import report_exception
from poise_cli.options import debug_option, ignore_option, json_option, quiet_option
from poise_cli.summary import print_json


@click.command(short_help="Write an Adams dataset (.adm/.acf) as a MotionSolve XML deck.")
@click.argument("source", type=click.Path(exists=True, dir_okay=False, readable=True))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The XML deck to write (atomically; never the dataset or command file).")
@ignore_option
@quiet_option
@json_option
@debug_option
def convert(source, output, ignore, quiet, as_json, debug):
    """Translate SOURCE (an Adams dataset .adm, or a command file .acf with the dataset it
    names) into a MotionSolve XML deck that poise reads back to the same model: same results,
    labels and comments kept.

    Exit code 0 when written, 2 for a usage error, 3 for an invalid dataset (every problem
    printed on stderr; nothing written).
    """
    ctx = click.get_current_context()
    try:
        # lazy: keeps the command module light (poise CMD --help imports no numpy/h5py)
        from poise.app.convert import convert as run_convert
        rep = run_convert(source, output, ignore=ignore)
    except (Exception, KeyboardInterrupt) as exc:
        code, info = report_exception(exc, debug=debug)
        if as_json:
            print_json({"source": source, "output": None, "exit_code": code, **info})
        ctx.exit(code)
        return
    if not quiet:
        for w in rep.warnings:
            click.echo(f"warning: {w}", err=True)
        click.echo(f"wrote {rep.output} ({rep.model_elements} model elements, {rep.commands} "
                   "commands)", err=True)
    if as_json:
        print_json({"source": rep.source, "output": rep.output, "status": "converted",
                    "exit_code": 0, "model_elements": rep.model_elements,
                    "commands": rep.commands, "warnings": rep.warnings, "ignored": rep.ignored})
    ctx.exit(0)
