"""Deck layer: XML text -> :class:`poise.deck.spec.DeckSpec` (plain data with source locations)."""
