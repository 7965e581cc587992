"""poise — static and quasi-static equilibria of MotionSolve-style XML multibody decks.

Imports are lazy so that ``import poise`` (and ``poise --help``) stays light.
"""
from __future__ import annotations

import os

# The solver's dense work is on 3x3 .. 12x12 blocks and vectors: multi-threaded OpenBLAS only adds
# thread start-up and, on a loaded machine, busy-waiting (a 1000-link chain solved 1.8x slower on
# 2 cores with another process running). Takes effect when poise is imported before numpy; an
# explicit setting in the environment wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from poise.core.version import __version__

__all__ = ["__version__", "solve", "sweep", "load_deck", "run_deck", "check_deck",
           "read_results", "write_results", "plot_results", "RunResult", "DeckSpec"]

# lazy public API: name -> module holding it (imported on first use, keeps `import poise` light)
_LAZY = {"solve": "poise.app.api", "sweep": "poise.app.api", "run_deck": "poise.app.api",
         "check_deck": "poise.app.api", "read_results": "poise.results.hdf5",
         "write_results": "poise.results.hdf5", "load_deck": "poise.app.api",
         "plot_results": "poise.viz.plot", "RunResult": "poise.results.data",
         "DeckSpec": "poise.deck.spec"}


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'poise' has no attribute {name!r}")


def __dir__():
    """The public API (resolved lazily) with the module's own names: ``dir(poise)`` and tab
    completion show ``solve``, ``read_results``, ..."""
    return sorted({*__all__, *(n for n in globals() if n.startswith("__"))})
