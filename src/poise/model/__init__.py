"""Compiled model layer: DeckSpec -> Model (flat arrays, index maps) and State."""
