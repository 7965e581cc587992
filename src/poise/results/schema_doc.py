"""``docs/results-format.md`` generated from the results schema.

The prose lives in ``results_format.md`` next to this module; each ``{{datasets:SECTION}}`` /
``{{attrs:SECTION}}`` line there becomes the table of the declared datasets / attributes of
that section (:mod:`poise.results.schema_items`). A test compares the committed document with
:func:`markdown`, so a declaration cannot change without the document.
"""
from __future__ import annotations

import re
from pathlib import Path

from poise.results.schema import Item, items, shape_text

TEMPLATE = Path(__file__).with_name("results_format.md")
_MARK = re.compile(r"^\{\{(datasets|attrs):([a-z-]+)\}\}$", re.M)
_UNIT_TEXT = {"": "–", "1": "1"}


def _unit(it: Item) -> str:
    if it.dtype in ("str", "json") and not it.unit:
        return "–"
    return _UNIT_TEXT.get(it.unit, it.unit.replace("*", "·"))


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _name(it: Item) -> str:
    return f"`{it.name}`"


def table(kind: str, section: str) -> str:
    rows = [it for it in items() if it.section == section
            and it.kind == ("dataset" if kind == "datasets" else "attr")]
    if not rows:
        raise ValueError(f"{TEMPLATE.name}: no {kind} declared in section {section!r}")
    if kind == "datasets":
        out = ["| dataset | shape | dtype | units | meaning |", "|---|---|---|---|---|"]
        for it in rows:
            opt = "*(optional)* " if it.optional else ""
            out.append(f"| {_name(it)} | {shape_text(it.shape)} | {it.dtype} | {_unit(it)} | "
                       f"{opt}{_cell(it.meaning)} |")
    else:
        out = ["| attribute | type | units | meaning |", "|---|---|---|---|"]
        for it in rows:
            opt = "*(optional)* " if it.optional else ""
            out.append(f"| {_name(it)} | {it.dtype} | {_unit(it)} | {opt}{_cell(it.meaning)} |")
    return "\n".join(out)


def markdown() -> str:
    """The whole document: the template with every table filled in."""
    text = TEMPLATE.read_text(encoding="utf-8")
    used = set()

    def fill(m):
        used.add((m.group(1), m.group(2)))
        return table(m.group(1), m.group(2))
    out = _MARK.sub(fill, text)
    missing = {(("datasets" if it.kind == "dataset" else "attrs"), it.section)
               for it in items()} - used
    if missing:
        raise ValueError(f"{TEMPLATE.name}: sections without a table: {sorted(missing)}")
    return out
