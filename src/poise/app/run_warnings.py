"""Python warnings raised while a deck runs (numpy ``RuntimeWarning``: overflow, invalid value,
...), recorded as the run's warnings instead of printing as raw ``file:line`` text. One place for
the CLI's ``solve``/``check`` and for ``batch`` and ``sweep`` workers (standard library only)."""
from __future__ import annotations

import contextlib
import os


@contextlib.contextmanager
def collected_warnings():
    """Record Python warnings raised inside the block; yields the list of unique messages.

    Each message reads ``RuntimeWarning: overflow encountered in matmul (newton.py:89)``; a
    message repeated (same category and text) is kept once, with its first place.
    """
    import warnings
    seen: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        try:
            yield seen
        finally:
            keys = set()
            for w in caught:
                key = f"{w.category.__name__}: {' '.join(str(w.message).split())}"
                if key not in keys:
                    keys.add(key)
                    seen.append(f"{key} ({os.path.basename(str(w.filename))}:{w.lineno})")
