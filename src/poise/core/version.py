"""The version of poise (here so that modules below the package root need not import it)."""

__version__ = "0.1.0"   # also in pyproject.toml
