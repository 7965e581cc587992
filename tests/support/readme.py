"""The README's fenced code blocks, for the tests that run them as written.

``code_blocks("sh")`` / ``code_blocks("python")``: ``(line, text)`` per fenced block of that
language, ``line`` the README line of the block's first line (for messages). One parser for
every README test, so they agree on what an example is.
"""
from __future__ import annotations

import re

from support.paths import ROOT

README = ROOT / "README.md"
_FENCE = re.compile(r"^( *)```(\S*)\s*$")


def code_blocks(lang: str, path=README) -> list[tuple[int, str]]:
    """Fenced blocks of ``lang`` in ``path``; blocks indented under a list item are included
    with that indentation removed."""
    out, body, indent, start, inside = [], [], "", 0, False
    for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        m = _FENCE.match(line)
        if not inside:
            if m:
                inside, indent, start, body = True, m.group(1), k + 1, []
                keep = m.group(2) == lang
            continue
        if m and not m.group(2) and m.group(1) == indent:
            inside = False
            if keep:
                out.append((start, "\n".join(body) + "\n"))
            continue
        body.append(line[len(indent):] if line.startswith(indent) else line.lstrip())
    return out
