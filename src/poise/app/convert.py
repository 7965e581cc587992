"""``poise convert``: an Adams dataset or command file -> a MotionSolve XML deck.

The dataset is read and validated exactly as ``poise solve`` reads it (an invalid one is a
located DeckError, exit 3, and nothing is written); the XML (:mod:`poise.deck.adm.xmlout`)
reads back to the same model. The output is written atomically and may be none of the inputs
(the command file or the dataset it names).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

from poise.core.atomic import atomic_output, output_target
from poise.core.errors import UsageError
from poise.deck.adm import is_dataset, translate_dataset
from poise.deck.adm.xmlout import to_xml


@dataclass
class ConvertReport:
    """What ``poise convert`` did: ``source``, ``output``, element counts, warnings and the
    elements left out by ``ignore``."""

    source: str
    output: str
    model_elements: int = 0
    commands: int = 0
    warnings: list = field(default_factory=list)
    ignored: list = field(default_factory=list)


def xml_text(source: str, ignore=()) -> tuple[str, list]:
    """The XML deck text of a dataset or command file (validated: a located DeckError when it
    is invalid), for tools that edit XML decks (``poise bench``'s tolerance ladder), and the
    elements ``ignore`` left out (``DeckSpec.ignored``)."""
    source = os.fspath(source)
    with open(source, "rb") as f:
        data = f.read()
    spec, ctx = translate_dataset(source, data, ignore=ignore)
    return to_xml(ctx, source), list(spec.ignored)


def convert(source: str, output: str, ignore=()) -> ConvertReport:
    """Translate ``source`` (``.adm``/``.acf``) and write the XML deck ``output``."""
    source = os.fspath(source)
    if not is_dataset(source):
        raise UsageError(f"{source!r} is not an Adams dataset or command file; expected a "
                         "path ending in .adm or .acf")
    try:
        with open(source, "rb") as f:
            data = f.read()
    except OSError as e:
        raise UsageError(f"cannot read {source!r}: {e.strerror or e}") from None
    spec, ctx = translate_dataset(source, data, ignore=ignore)
    inputs = (source, *spec.input_files)
    output_target(output, inputs)
    text = to_xml(ctx, source)
    with atomic_output(output, inputs) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write(text)
    return ConvertReport(source, os.fspath(output), len(spec.model), len(spec.commands),
                         [str(w) for w in spec.warnings], list(spec.ignored))
