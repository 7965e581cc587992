"""XML deck reader: bytes -> typed :class:`~poise.deck.spec.DeckSpec` (then validated).

Layout (deck_format.md §1.1): the root may have any name; model elements come from ``<Model>``
(or from directly under the root when there is no ``<Model>``); commands come from ``<Command>``
or directly under the root, in document order. Command-only elements (``Simulate``, ``Stop``, ...)
are commands wherever they appear. Element and attribute names are case-insensitive.

Security: lxml runs with ``resolve_entities=False, no_network=True, load_dtd=False,
dtd_validation=False, huge_tree=False``; a document that declares entities (``<!ENTITY``: expansion
bombs, external entities) is refused before parsing. Every failure is a located
:class:`~poise.errors.DeckError` (never a raw lxml exception).

Typing follows ``poise.deck.spec``. A value that cannot be typed (``mass="abc"``) is stored as the
raw string; :func:`poise.deck.validate.validate` reports it. Unknown elements are kept under their
written name and unknown attributes are dropped with one warning each, so that validation can
report every problem of the deck at once.
"""
from __future__ import annotations

import hashlib
import io
import re
from dataclasses import replace
from typing import Any

from lxml import etree

from poise.deck.schema import ENUM_ALIASES, Attr, element_schema
from poise.deck.spec import DeckSpec, Element, Expr
from poise.deck.validate import FileProblem, validate
from poise.errors import DeckError, Problem, SourceLoc

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eEdD][+-]?\d+)?$")
_TRUE = {"TRUE", "YES", "1", "T", "ON"}
_FALSE = {"FALSE", "NO", "0", "F", "OFF"}
_ENTITY = re.compile(rb"<!ENTITY", re.IGNORECASE)
_SECTIONS = ("model", "command")
_TAG_SCAN = re.compile(rb"<!--.*?-->|<!\[CDATA\[.*?\]\]>|<\?.*?\?>|<[A-Za-z_:]", re.S)
_BIG_LINE = 65535  # libxml2 stores element line numbers in 16 bits


def _start_tag_lines(data: bytes, wanted: set[int]) -> dict[int, int]:
    """Line numbers of the start tags with the given 0-based ordinals (document order).

    libxml2 reports 65535 for every element beyond that line once the tree has been pruned, so
    big decks are fixed up by scanning the raw bytes: outside comments, CDATA and processing
    instructions, ``<`` followed by a name character always opens a start tag.
    """
    out: dict[int, int] = {}
    if data[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\x00" in data[:4]:
        return out  # UTF-16/32 decks: keep libxml2's numbers
    k, line, pos = 0, 1, 0
    last = max(wanted) if wanted else -1
    for m in _TAG_SCAN.finditer(data):
        if m.end() - m.start() != 2:
            continue
        if k in wanted:
            line += data.count(b"\n", pos, m.start())
            pos = m.start()
            out[k] = line
        k += 1
        if k > last:
            break
    return out


# --------------------------------------------------------------------------- value typing
_PLAIN = frozenset("0123456789.+-eE")


def parse_number(text: str) -> float | None:
    """Plain number in Fortran/C notation (``1.E-3``, ``1.5D0``, ``-9810.``) or None."""
    t = text.strip()
    # fast path: over these characters float() accepts exactly what _NUMBER accepts
    if t and _PLAIN.issuperset(t):
        try:
            return float(t)
        except ValueError:
            return None
    if not _NUMBER.match(t):
        return None
    return float(t.replace("d", "e").replace("D", "e"))


def _parse_int(text: str) -> int | None:
    v = parse_number(text)
    if v is None or not abs(v) < 2.0 ** 63 or v != int(v):   # NaN, inf, beyond int64: invalid
        return None
    return int(v)


def coerce(attr: Attr, raw: str, loc: SourceLoc) -> Any:
    """Type one attribute value per its schema kind.

    Parameters
    ----------
    attr : Attr
        Schema of the attribute.
    raw : str
        Text as written in the deck.
    loc : SourceLoc
        Location of the owning element (for :class:`Expr`).

    Returns
    -------
    Any
        The typed value, or the raw string when it cannot be typed (validation reports it).
    """
    k = attr.kind
    text = raw.strip()
    if k == "real":
        v = parse_number(text)
        return raw if v is None else v
    if k == "int":
        v = _parse_int(text)
        return raw if v is None else v
    if k == "bool":
        u = text.upper()
        return True if u in _TRUE else False if u in _FALSE else raw
    if k == "enum":
        u = " ".join(text.upper().split())
        return ENUM_ALIASES.get(u, u)
    if k == "str":
        return raw
    if k == "real_or_expr":
        if not text:
            return raw
        v = parse_number(text)
        return Expr(text, loc, attr.name) if v is None else v
    if k == "expr":
        return Expr(text, loc, attr.name)
    if k in ("int_list", "real_list"):
        parts = [p for p in re.split(r"[\s,]+", text) if p]
        conv = _parse_int if k == "int_list" else parse_number
        vals = [conv(p) for p in parts]
        return raw if any(v is None for v in vals) else tuple(vals)
    raise ValueError(f"unknown attribute kind {k!r}")  # schema bug, not a deck problem


def _guess(raw: str) -> Any:
    v = parse_number(raw)
    return raw if v is None else v


def _local(tag: Any) -> str:
    return etree.QName(tag).localname if isinstance(tag, str) else ""


_LOCAL: dict[str, str] = {}          # element tag as written -> local name


def _local_tag(tag: Any) -> str:
    if not isinstance(tag, str):
        return ""
    v = _LOCAL.get(tag)
    if v is None:
        v = _LOCAL[tag] = _local(tag)
    return v


_LOWER_LOCAL: dict[str, str] = {}   # attribute / tag name as written -> lower-case local name


def _lower_local(name: str) -> str:
    v = _LOWER_LOCAL.get(name)
    if v is None:
        v = _LOWER_LOCAL[name] = _local(name).lower()
    return v


_ATTR_CACHE: dict[tuple[str, str], Attr | None] = {}   # (tag, lower-case name) -> Attr


def _schema_attr(sch, n: str) -> Attr | None:
    key = (sch.tag, n)
    try:
        return _ATTR_CACHE[key]
    except KeyError:
        a = _ATTR_CACHE[key] = sch.attr(n)
        return a


# --------------------------------------------------------------------------- element building
class _Builder:
    """Builds :class:`Element` objects and collects warnings."""

    def __init__(self, path: str):
        self.path = path
        self.warnings: list[Problem] = []

    def build(self, name: str, attrib: Any, text: str | None, line: int) -> Element:
        sch = element_schema(name)
        low = _LOWER_LOCAL
        raw = {low.get(k) or _lower_local(k): v for k, v in attrib.items()}
        ident = _parse_int(raw["id"]) if "id" in raw else None
        tag = sch.tag if sch else name
        loc = SourceLoc(self.path, line, tag, ident)
        attrs: dict[str, Any] = {}
        if sch is None:
            attrs = dict(raw)
            if ident is not None:
                attrs["id"] = ident
        else:
            written: dict[str, str] = {}
            for n, v in raw.items():
                a = _schema_attr(sch, n)
                if a is None:
                    if sch.open_attrs:
                        attrs[n] = _guess(v)
                    else:
                        self.warnings.append(Problem(loc, f"unknown attribute '{n}' ignored"))
                    continue
                if a.name in written:
                    self.warnings.append(Problem(
                        loc, f"attribute '{a.name}' given twice (as '{written[a.name]}' and '{n}'); "
                        f"'{n}' is used"))
                written[a.name] = n
                if a.kind == "real":   # the common case, inlined: same result as coerce()
                    x = parse_number(v)
                    attrs[a.name] = v if x is None else x
                else:
                    attrs[a.name] = coerce(a, v, loc)
        txt = text.strip() if text and text.strip() else None
        return Element(tag=tag, attrs=attrs, loc=loc, text=txt)


_DEFAULTS: dict[str, tuple] = {}   # canonical tag -> ((name, default), ...) in schema order


def _apply_defaults(el: Element) -> None:
    d = _DEFAULTS.get(el.tag)
    if d is None:
        sch = element_schema(el.tag)
        d = _DEFAULTS[el.tag] = () if sch is None else tuple(
            (a.name, a.default) for a in sch.attrs.values() if a.default is not None)
    attrs = el.attrs
    for name, default in d:
        if name not in attrs:
            attrs[name] = default


# --------------------------------------------------------------------------- security pre-scan
def _line_of(data: bytes, offset: int) -> int:
    return data.count(b"\n", 0, offset) + 1


def _refuse_entities(data: bytes, path: str) -> None:
    """Raise a located DeckError when the document declares entities."""
    m = _ENTITY.search(data)
    if m is not None:
        raise DeckError(FileProblem(SourceLoc(path, _line_of(data, m.start()), "xml"),
                                    "entity declarations (<!ENTITY>) are not allowed in a deck "
                                    "(entity expansion / external entities); remove the DOCTYPE"))
    for enc in ("utf-16", "utf-32"):
        if data[:2] in (b"\xff\xfe", b"\xfe\xff") or (len(data) > 3 and b"\x00" in data[:4]):
            try:
                text = data.decode(enc)
            except UnicodeDecodeError:
                continue
            i = text.upper().find("<!ENTITY")
            if i >= 0:
                raise DeckError(FileProblem(SourceLoc(path, text.count("\n", 0, i) + 1, "xml"),
                                            "entity declarations (<!ENTITY>) are not allowed in a deck"))


# --------------------------------------------------------------------------- main entry points
def parse_deck_bytes(data: bytes, path: str, *, check: bool = True) -> DeckSpec:
    """Parse deck bytes into a :class:`DeckSpec`.

    Parameters
    ----------
    data : bytes
        Raw deck bytes (their SHA-256 goes to ``DeckSpec.sha256``).
    path : str
        Deck path used in every message.
    check : bool, optional
        Run :func:`poise.deck.validate.validate` (default True).

    Returns
    -------
    DeckSpec

    Raises
    ------
    DeckError
        Malformed XML, entity declarations, or (with ``check``) any validation problem; all
        validation problems of the deck are reported in one error.
    """
    spec = DeckSpec(path=path, sha256=hashlib.sha256(data).hexdigest())
    _refuse_entities(data, path)
    b = _Builder(path)
    items: list[tuple[Element, str]] = []  # (element, "model" | "command" | "root")
    seen_model = False
    try:
        ctx = etree.iterparse(io.BytesIO(data), events=("start", "end"), resolve_entities=False,
                              no_network=True, load_dtd=False, dtd_validation=False, huge_tree=False,
                              remove_comments=True, remove_pis=True)
        stack: list[str] = []
        ordinal = -1
        ord_stack: list[int] = []  # start-tag ordinal of each open element
        big: dict[int, Element] = {}  # ordinal -> element whose line libxml2 capped
        first = True
        for event, elem in ctx:
            if not isinstance(elem.tag, str):
                continue
            if event == "start":
                if first:
                    first = False
                    dtd = elem.getroottree().docinfo.internalDTD
                    if dtd is not None and any(True for _ in dtd.iterentities()):
                        raise DeckError(FileProblem(SourceLoc(path, 1, "xml"),
                                                    "entity declarations are not allowed in a deck"))
                ordinal += 1
                name = _local_tag(elem.tag).lower()
                parent = stack[-1] if stack else None
                if parent is None:
                    role = name if name in _SECTIONS else "root"
                elif parent == "root" and name in _SECTIONS:
                    role = name
                elif parent in ("root", *_SECTIONS):
                    role = "deck"
                else:
                    role = "nested"
                    if parent == "deck":
                        b.warnings.append(FileProblem(
                            SourceLoc(path, elem.sourceline or 0, _local(elem.tag)),
                            f"nested element <{_local(elem.tag)}> ignored"))
                seen_model = seen_model or role == "model"
                stack.append(role)
                ord_stack.append(ordinal)
                continue
            role = stack.pop()
            own = ord_stack.pop()
            if role == "deck":
                el = b.build(_local_tag(elem.tag), elem.attrib, elem.text, elem.sourceline or 0)
                items.append((el, stack[-1]))
                if el.loc.line >= _BIG_LINE:
                    big[own] = el
            if stack:  # keep memory bounded: drop processed elements
                elem.clear()
                parent_el = elem.getparent()
                if parent_el is not None:
                    while elem.getprevious() is not None:
                        del parent_el[0]
    except DeckError:
        raise
    except etree.XMLSyntaxError as e:
        line = e.lineno or (e.position[0] if e.position else 0) or 0
        msg = (e.msg or str(e)).strip()
        raise DeckError(FileProblem(SourceLoc(path, line, "xml"), f"malformed XML: {msg}")) from None
    except Exception as e:  # any other lxml / decoding failure is still a deck problem
        raise DeckError(FileProblem(SourceLoc(path, 0, "xml"),
                                    f"cannot parse deck: {type(e).__name__}: {e}")) from None
    if big:
        fixed = _start_tag_lines(data, set(big))
        moved: dict[int, SourceLoc] = {}
        for k, el in big.items():
            if k in fixed:
                old_loc, el.loc = el.loc, replace(el.loc, line=fixed[k])
                moved[id(old_loc)] = el.loc
                for name, v in el.attrs.items():
                    if isinstance(v, Expr):
                        el.attrs[name] = replace(v, loc=el.loc)
        b.warnings = [replace(w, loc=moved[id(w.loc)]) if id(w.loc) in moved else w
                      for w in b.warnings]
    if not items and not stack and first:
        raise DeckError(FileProblem(SourceLoc(path, 1, "xml"), "empty deck"))

    for el, where in items:
        sch = element_schema(el.tag)
        kind = sch.kind if sch else "model"
        if kind == "command" or where == "command" or (where == "root" and seen_model and kind == "both"):
            el.is_command = True
            spec.commands.append(el)
        else:
            _apply_defaults(el)
            spec.model.append(el)
    spec.warnings.extend(b.warnings)
    if check:
        validate(spec)
    return spec


def load_deck(path, *, check: bool = True) -> DeckSpec:
    """Read, parse and validate a deck file.

    Parameters
    ----------
    path : str or os.PathLike
        Deck path (used as given in every message).
    check : bool, optional
        Validate the deck (default True).

    Returns
    -------
    DeckSpec

    Raises
    ------
    DeckError
        Unreadable file, malformed XML, or any validation problem (all collected).
    """
    path = str(path)          # os.PathLike accepted; messages and locations carry text
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise DeckError(FileProblem(SourceLoc(path, 0, "xml"),
                                    f"cannot read deck: {e.strerror or e}")) from None
    return parse_deck_bytes(data, path, check=check)
