"""The parsed deck: plain data with source locations (the first of three representations).

The parser (``poise.deck.parser``) turns XML into a :class:`DeckSpec`. Nothing here knows about
numerics; the compiler (``poise.model.compile``) turns a DeckSpec into a compiled model.

Attribute values are already typed by the schema (``poise.deck.schema``, :mod:`poise.deck.values`):
``real`` -> float, ``int`` -> int, ``bool`` -> bool, ``enum`` -> str (upper-case canonical value),
``str`` -> str, ``real_or_expr`` -> float if the text is a plain number else :class:`Expr`,
``expr`` -> :class:`Expr`, ``int_list``/``real_list`` -> tuple of int/float.

Attribute names are lower-cased; element tags are canonical (schema spelling, e.g.
``Force_SpringDamper``) whatever the case in the file.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from poise.core.errors import SourceLoc


@dataclass(frozen=True)
class Expr:
    """An expression-valued attribute, kept as text until the expression compiler reads it.

    Attributes
    ----------
    text : str
        The expression exactly as written in the deck (without surrounding quotes).
    loc : SourceLoc
        Location of the owning element (its start tag's line, not the attribute's own line,
        which the reader does not track); messages add ``attr`` and the column.
    attr : str
        Attribute name (lower case), for error messages (``fx_expression col 14: ...``).
    """

    text: str
    loc: SourceLoc
    attr: str


@dataclass(slots=True)
class Element:
    """One deck element (model element or command).

    Attributes
    ----------
    tag : str
        Canonical element name.
    attrs : dict[str, Any]
        Typed attribute values, lower-case names. Attributes the schema does not know are not
        stored (a warning was emitted for each).
    loc : SourceLoc
        Source location (file, line, tag, id).
    text : str or None
        Element text content (tabular data of ``Reference_Spline``, ``Reference_Array``, ...).
    is_command : bool
        True when the element came from the command section (or is a command element).
    """

    tag: str
    attrs: dict[str, Any]
    loc: SourceLoc
    text: str | None = None
    is_command: bool = False

    @property
    def id(self) -> int | None:
        return self.attrs.get("id")

    def get(self, name: str, default: Any = None) -> Any:
        return self.attrs.get(name, default)

    def has(self, name: str) -> bool:
        return name in self.attrs


@dataclass
class DeckSpec:
    """A parsed and validated deck.

    Attributes
    ----------
    path : str
        The deck path as given.
    sha256 : str
        SHA-256 of the deck bytes.
    model : list[Element]
        Model elements in document order.
    commands : list[Element]
        Command elements in document order (``Simulate``, ``Stop``, command versions of
        ``Param_Static`` etc.).
    warnings : list
        :class:`poise.core.errors.Problem` warnings (unknown attributes, ...), already located.
    ignored : list[dict]
        Elements of an Adams dataset left out by ``--ignore KIND`` (``kind``, ``statement``,
        ``file``, ``line``), recorded in the results.
    input_files : dict[str, str]
        Files read besides the deck (an Adams command file's model) -> SHA-256.
    """

    path: str
    sha256: str
    model: list[Element] = field(default_factory=list)
    commands: list[Element] = field(default_factory=list)
    warnings: list = field(default_factory=list)
    ignored: list = field(default_factory=list)
    input_files: dict = field(default_factory=dict)

    def copy(self, elements: bool = False) -> "DeckSpec":
        """A copy with its own lists (model, commands, warnings, ignored) and input-file
        dict; ``elements``: its own elements and attribute dicts too, so that nothing done
        to the copy's elements reaches this spec."""
        own = (lambda els: [replace(e, attrs=dict(e.attrs)) for e in els]) if elements else list
        return replace(self, model=own(self.model), commands=own(self.commands),
                       warnings=list(self.warnings), ignored=list(self.ignored),
                       input_files=dict(self.input_files))

    def elements(self, tag: str) -> list[Element]:
        """Model elements with canonical tag ``tag`` in document order."""
        idx = self.__dict__.get("_tag_index")
        if idx is not None:
            return list(idx.get(tag, ()))
        return [e for e in self.model if e.tag == tag]

    def by_id(self, tag: str) -> dict[int, Element]:
        return {e.id: e for e in self.elements(tag) if e.id is not None}

    def indexed(self) -> "_Indexed":
        """Context in which :meth:`elements` / :meth:`by_id` read a tag index built once
        (one pass over ``model``) instead of scanning the whole model per call. ``model`` must
        not change inside the block (the compiler uses it; nested use is fine)."""
        return _Indexed(self)


class _Indexed:
    def __init__(self, spec: DeckSpec):
        self.spec = spec
        self.owner = False

    def __enter__(self) -> DeckSpec:
        d = self.spec.__dict__
        if d.get("_tag_index") is None:
            idx: dict[str, list[Element]] = {}
            for e in self.spec.model:
                lst = idx.get(e.tag)
                if lst is None:
                    idx[e.tag] = [e]
                else:
                    lst.append(e)
            d["_tag_index"] = idx
            self.owner = True
        return self.spec

    def __exit__(self, *exc) -> None:
        if self.owner:
            self.spec.__dict__.pop("_tag_index", None)

    def tags(self) -> set[str]:
        return {e.tag for e in self.model}
