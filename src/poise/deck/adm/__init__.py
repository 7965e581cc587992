"""Adams solver datasets (``.adm``) and command files (``.acf``) -> :class:`DeckSpec`.

``load_dataset`` is what :func:`poise.deck.parser.parse_deck_bytes` calls for a path ending in
``.adm`` or ``.acf``; ``translate_dataset`` also returns the translation (its XML element
records, for ``poise convert``). The statement table is :mod:`poise.deck.adm.vocab`; docs/adm.md
maps every statement and keyword.
"""
from __future__ import annotations

from poise.deck.adm.acf import read_acf
from poise.deck.adm.reader import is_dataset, read_adm


def translate_dataset(path: str, data: bytes, *, check: bool = True, ignore=()):
    """(DeckSpec, translation context) of a dataset or command file's bytes."""
    if str(path).lower().endswith(".acf"):
        return read_acf(path, data, check=check, ignore=ignore)
    return read_adm(path, data, check=check, ignore=ignore)


def load_dataset(path: str, data: bytes, *, check: bool = True, ignore=()):
    """The DeckSpec of a dataset or command file's bytes (located DeckError when invalid)."""
    return translate_dataset(path, data, check=check, ignore=ignore)[0]


__all__ = ["is_dataset", "load_dataset", "translate_dataset"]
