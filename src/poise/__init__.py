"""poise — static and quasi-static equilibria of MotionSolve-style XML multibody decks.

Imports are lazy so that ``import poise`` (and ``poise --help``) stays light.
"""
from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__", "solve", "load_deck"]


def __getattr__(name):  # lazy public API
    if name == "solve":
        from poise.api import solve
        return solve
    if name == "load_deck":
        from poise.deck.parser import load_deck
        return load_deck
    raise AttributeError(f"module 'poise' has no attribute {name!r}")
