"""``poise`` command group.

Keep this module (and the command modules it imports) light: no numpy, scipy, h5py or lxml at
import time. Heavy imports happen inside the command functions.
"""
from __future__ import annotations

import click

from poise import __version__
from poise_cli.animate import animate
from poise_cli.batch import batch
from poise_cli.bench import bench
from poise_cli.check import check
from poise_cli.plot import plot
from poise_cli.show import show
from poise_cli.solve import solve
from poise_cli.sweep import sweep

CONTEXT_SETTINGS = {"help_option_names": ["-h", "--help"], "max_content_width": 100}


@click.group(context_settings=CONTEXT_SETTINGS)
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
    """


cli.add_command(solve)
cli.add_command(check)
cli.add_command(show)
cli.add_command(batch)
cli.add_command(sweep)
cli.add_command(plot)
cli.add_command(animate)
cli.add_command(bench)


def main() -> None:  # pragma: no cover - console entry alias
    cli(prog_name="poise")


if __name__ == "__main__":  # ``python -m poise_cli.main`` (also ``python -m poise_cli``)
    cli(prog_name="poise")
