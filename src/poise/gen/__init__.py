"""Deck generators (standard library only): used by ``decks/gen_chain.py`` and ``benchmarks.chain``."""
