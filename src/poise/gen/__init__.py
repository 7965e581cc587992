"""Deck generators for tests, examples and benchmarks: the deck builder (:mod:`.deck`: XML text
and DeckSpec, element by element), the hanging chain (:mod:`.chain`, standard library only:
its text is pinned byte for byte by the committed chain decks), a bar under a constant
torque (:mod:`.torque`) and bodies on slides (:mod:`.slide`). Nothing in the solver imports
this package."""
