"""Deck generators for tests, examples and benchmarks: the deck builder (:mod:`.deck`: XML text
and DeckSpec, element by element) and the hanging chain (:mod:`.chain`, standard library only:
its text is pinned byte for byte by the committed chain decks). Nothing in the solver imports
this package."""
