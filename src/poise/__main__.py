"""``python -m poise`` == the ``poise`` command."""
from poise_cli.main import cli

if __name__ == "__main__":  # pragma: no cover
    cli(prog_name="poise")
