"""poise — static and quasi-static equilibria of MotionSolve-style XML multibody decks.

Imports are lazy so that ``import poise`` (and ``poise --help``) stays light.
"""
from __future__ import annotations

# first: single-threaded BLAS for every library loaded from now on (poise.core.blas; runs
# limit the ones loaded before)
from poise.core import blas as _blas  # noqa: F401

from poise.core.version import __version__

__all__ = ["__version__", "solve", "sweep", "open_sweep", "load_deck", "run_deck", "check_deck",
           "read_results", "write_results", "plot_results", "RunResult", "DeckSpec"]

# lazy public API: name -> module holding it (imported on first use, keeps `import poise` light)
_LAZY = {"solve": "poise.app.api", "sweep": "poise.app.api", "open_sweep": "poise.app.api",
         "run_deck": "poise.app.api",
         "check_deck": "poise.app.api", "read_results": "poise.results.hdf5",
         "write_results": "poise.results.hdf5", "load_deck": "poise.app.api",
         "plot_results": "poise.viz.plot", "RunResult": "poise.results.data",
         "DeckSpec": "poise.deck.spec"}


def __getattr__(name):
    if name in _LAZY:
        import importlib
        value = globals()[name] = getattr(importlib.import_module(_LAZY[name]), name)
        return value        # kept: later lookups find it without this hook
    raise AttributeError(f"module 'poise' has no attribute {name!r}")


def __dir__():
    """The public API (resolved lazily) with the module's own names: ``dir(poise)`` and tab
    completion show ``solve``, ``read_results``, ..."""
    return sorted({*__all__, *(n for n in globals() if n.startswith("__"))})
