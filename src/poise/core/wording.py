"""Counted nouns and shortened text in messages (one way for every command and solver).

``plural(1, "iteration")`` is ``"1 iteration"``, never ``"1 iterations"`` or ``"frame(s)"``;
text cut to fit a table cell or a line ends with ``...`` so a reader knows there is more.
"""
from __future__ import annotations

#: what a shortened text ends with (ASCII: any terminal encoding can print it)
ELLIPSIS = "..."


def plural(n, word: str, words: str | None = None) -> str:
    """``"<n> <word>"`` with the plural form (``words``, default ``word + "s"``) unless n is 1."""
    return f"{n} {word if n == 1 else (words or word + 's')}"


def shorten(text: str, width: int) -> str:
    """``text`` on one line (whitespace runs collapsed), cut to at most ``width`` characters
    ending with :data:`ELLIPSIS` when it was longer."""
    s = " ".join(str(text).split())
    if len(s) <= width:
        return s
    keep = max(width - len(ELLIPSIS), 0)
    return s[:keep].rstrip() + ELLIPSIS
