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

__version__ = "0.1.0"

__all__ = ["__version__", "solve", "sweep", "load_deck", "run_deck", "check_deck",
           "read_results"]


def __getattr__(name):  # lazy public API
    if name == "solve":
        from poise.api import solve
        return solve
    if name == "sweep":
        from poise.api import sweep
        return sweep
    if name in ("run_deck", "check_deck"):
        from poise import api
        return getattr(api, name)
    if name == "read_results":
        from poise.results.hdf5 import read_results
        return read_results
    if name == "load_deck":
        from poise.deck.parser import load_deck
        return load_deck
    raise AttributeError(f"module 'poise' has no attribute {name!r}")
