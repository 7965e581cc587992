"""XML deck reader: bytes -> typed :class:`~poise.deck.spec.DeckSpec` (then validated).

Layout (deck_format.md §1.1): the root may have any name; model elements come from ``<Model>``
(or from directly under the root when there is no ``<Model>``); commands come from ``<Command>``
or directly under the root, in document order. Command-only elements (``Simulate``, ``Stop``, ...)
are commands wherever they appear. Element and attribute names are case-insensitive.

Security: lxml runs with ``resolve_entities=False, no_network=True, load_dtd=False,
dtd_validation=False, huge_tree=False``; a document that declares entities (``<!ENTITY``: expansion
bombs, external entities) is refused before parsing. Every failure is a located
:class:`~poise.core.errors.DeckError` (never a raw lxml exception).

Typing follows ``poise.deck.spec``. A value that cannot be typed (``mass="abc"``) is stored as the
raw string; :func:`poise.deck.validate.validate` reports it. Unknown elements are kept under their
written name and unknown attributes are dropped with one warning each, so that validation can
report every problem of the deck at once.

Locations: an element's line is the line of the ``<`` that opens its start tag (see "element
lines" below; decks in other encodings are re-encoded as UTF-8 first).
"""
from __future__ import annotations

import gc
import hashlib
import io
import re
from typing import Any

import numpy as np
from lxml import etree

from poise.deck.schema import ENUM_ALIASES, Attr, element_schema
from poise.deck.spec import DeckSpec, Element, Expr
from poise.deck.validate import FileProblem, validate
from poise.core.errors import DeckError, Problem, SourceLoc

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eEdD][+-]?\d+)?$")
_TRUE = {"TRUE", "YES", "1", "T", "ON"}
_FALSE = {"FALSE", "NO", "0", "F", "OFF"}
_ENTITY = re.compile(rb"<!ENTITY", re.IGNORECASE)
_SECTIONS = ("model", "command")


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
# Deck elements are typed in batches (_Builder.flush): the records of one batch are grouped by
# *shape* (tag as written + attribute names as written, in order) and each shape is analysed
# once (_Shape: schema, canonical names, duplicate/unknown attribute warnings, defaults), so the
# per-element Python work is a few C-level calls; attribute values are typed column by column
# (plain numbers through one float()/int() map per column).
_PLAIN_BYTES = b"0123456789.+-eE"
_SHAPES: dict[tuple, "_Shape"] = {}
_SHAPES_MAX = 4096


def _reals(col: list) -> list:
    """``parse_number`` of every value (the raw string where it is not a number)."""
    try:
        j = "".join(col)
        # over these characters float() accepts exactly what parse_number accepts
        if j.isascii() and not j.encode("ascii").translate(None, _PLAIN_BYTES):
            return list(map(float, col))
    except ValueError:
        pass
    out = []
    for v in col:
        x = parse_number(v)
        out.append(v if x is None else x)
    return out


def _ints(col: list, keep_raw: bool = True) -> list:
    """``_parse_int`` of every value (the raw string, or None without ``keep_raw``, where it is
    not an integer). Plain digit strings of up to 15 digits (exact in a float) go through int()."""
    j = "".join(col)
    if j.isascii() and j.isdigit() and all(col) and max(map(len, col)) <= 15:
        return list(map(int, col))
    out = []
    for v in col:
        x = _parse_int(v)
        out.append(v if x is None and keep_raw else x)
    return out


class _Shape:
    """What every element with one tag and one list of attribute names (as written) becomes."""

    __slots__ = ("tag", "kind", "names", "cols", "id_src", "warns", "defaults")

    def __init__(self, wtag: Any, keys: tuple):
        sch = element_schema(_local_tag(wtag))
        self.tag = sch.tag if sch else _local_tag(wtag)
        self.kind = sch.kind if sch else "model"
        raw: dict[str, int] = {}                 # lower-case name -> index of its last value
        for i, k in enumerate(keys):
            raw[_lower_local(k)] = i
        self.id_src = raw.get("id")
        out: dict[str, tuple] = {}               # attribute -> (value index, Attr | tag)
        warns: list[str] = []
        if sch is None:
            for n, i in raw.items():
                out[n] = (i, "id" if n == "id" else "raw")
        else:
            written: dict[str, str] = {}
            for n, i in raw.items():
                a = _schema_attr(sch, n)
                if a is None:
                    if sch.open_attrs:
                        out[n] = (i, "guess")
                    else:
                        warns.append(f"unknown attribute '{n}' ignored")
                    continue
                if a.name in written:
                    warns.append(f"attribute '{a.name}' given twice (as '{written[a.name]}' and "
                                 f"'{n}'); '{n}' is used")
                written[a.name] = n
                out[a.name] = (i, a)
        self.names = tuple(out)
        self.cols = tuple(out.values())
        self.warns = tuple(warns)
        present = set(out)
        self.defaults = tuple((n, d) for n, d in _defaults(self.tag) if n not in present)


def _shape(wtag: Any, keys: tuple) -> _Shape:
    k = (wtag, keys)
    s = _SHAPES.get(k)
    if s is None:
        if len(_SHAPES) >= _SHAPES_MAX:
            _SHAPES.clear()
        s = _SHAPES[k] = _Shape(wtag, keys)
    return s


class _Builder:
    """Builds :class:`Element` objects from parse records, in batches, and collects warnings.

    A record is ``[tag as written, attributes (dict), text, line, section, event]``; ``event``
    orders the warnings as the document does (a nested-element warning at the nested element's
    start, the element's own warnings at its end).
    """

    def __init__(self, path: str):
        self.path = path
        self.items: list[tuple] = []       # (Element, section, _Shape) in document order
        self.warnings: list[tuple] = []    # (event, Problem)

    def flush(self, recs: list) -> None:
        if not recs:
            return
        groups: dict[tuple, list[int]] = {}
        for k, r in enumerate(recs):
            key = (r[0], tuple(r[1]))
            g = groups.get(key)
            if g is None:
                groups[key] = [k]
            else:
                g.append(k)
        built: list = [None] * len(recs)
        for (wtag, keys), idx in groups.items():
            shp = _shape(wtag, keys)
            rs = [recs[k] for k in idx]
            raw = list(zip(*[r[1].values() for r in rs]))    # one tuple per attribute
            if shp.id_src is not None:
                idents = _ints(list(raw[shp.id_src]), keep_raw=False)
            else:
                idents = [None] * len(rs)
            path, tag = self.path, shp.tag
            locs = [SourceLoc(path, r[3], tag, ident) for r, ident in zip(rs, idents)]
            cols = [self._column(shp, name, src, conv, list(raw[src]), locs, idents)
                    for name, (src, conv) in zip(shp.names, shp.cols)]
            names = shp.names
            rows = zip(*cols) if cols else ((),) * len(rs)
            texts = [r[2] for r in rs]
            if any(texts):
                texts = [t.strip() if t and t.strip() else None for t in texts]
            else:
                texts = [None] * len(rs)
            els = [Element(tag, dict(zip(names, row)), loc, txt)
                   for row, loc, txt in zip(rows, locs, texts)]
            for k, el, r in zip(idx, els, rs):
                built[k] = (el, r[4], shp)
            if shp.warns:
                for r, loc in zip(rs, locs):
                    for msg in shp.warns:
                        self.warnings.append((r[5], Problem(loc, msg)))
        self.items.extend(built)

    @staticmethod
    def _column(shp: _Shape, name: str, src: int, conv: Any, col: list, locs: list,
                idents: list) -> list:
        if conv == "raw":
            return col
        if conv == "id":                   # unknown element: the id typed when it is one
            return [v if x is None else x for v, x in zip(col, idents)]
        if conv == "guess":
            return _reals(col)
        k = conv.kind
        if k == "real":
            return _reals(col)
        if k == "int":
            return _ints(col)
        if k == "str":
            return col
        if k in ("bool", "enum", "int_list", "real_list"):   # no location: one per value
            memo = {v: coerce(conv, v, None) for v in set(col)}
            return [memo[v] for v in col]
        if k == "real_or_expr":
            x = _reals(col)
            if all(type(v) is float for v in x):
                return x
        return [coerce(conv, v, loc) for v, loc in zip(col, locs)]


_DEFAULTS: dict[str, tuple] = {}   # canonical tag -> ((name, default), ...) in schema order


def _defaults(tag: str) -> tuple:
    d = _DEFAULTS.get(tag)
    if d is None:
        sch = element_schema(tag)
        d = _DEFAULTS[tag] = () if sch is None else tuple(
            (a.name, a.default) for a in sch.attrs.values() if a.default is not None)
    return d


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


# --------------------------------------------------------------------------- document walk
_CONTAINERS = ("root", *_SECTIONS)
_LOWER_TAG: dict[str, str] = {}      # element tag as written -> lower-case local name
_FLUSH = 4096                         # records typed per batch (bounded memory)


def _lower_tag(tag: str) -> str:
    v = _LOWER_TAG.get(tag)
    if v is None:
        v = _LOWER_TAG[tag] = _local_tag(tag).lower()
    return v


def _role(stack: list, name: str) -> str:
    """Role of a new element from its parent's role: "root", "model"/"command" (sections),
    "deck" (a deck element) or "nested" (inside a deck element: ignored)."""
    if not stack:
        return name if name in _SECTIONS else "root"
    parent = stack[-1]
    if parent == "root" and name in _SECTIONS:
        return name
    if parent in _CONTAINERS:
        return "deck"
    return "nested"


class _Target:
    """lxml parser target (no tree is built): deck-element records with the line numbers of
    the byte scan (:func:`_start_tag_scan`), flushed to the builder in batches."""

    def __init__(self, path: str, lines: np.ndarray, b: _Builder):
        self.path, self.lines, self.b = path, lines.tolist(), b
        self.stack: list[str] = []
        self.n = -1                  # start-tag ordinal
        self.event = 0
        self.cur: list | None = None
        self.parts: list[str] | None = None   # text of the open deck element (before a child)
        self.recs: list[list] = []
        self.seen_model = False

    def start(self, tag, attrib):
        self.n += 1
        self.event += 1
        stack = self.stack
        role = _role(stack, _lower_tag(tag))
        if role == "deck":
            self.cur = [tag, attrib if attrib else {}, None, self.lines[self.n], stack[-1], 0]
            self.parts = []
        elif role == "nested":
            if self.parts:                  # the element's text is what precedes a child
                self.cur[2] = "".join(self.parts)
            self.parts = None
            if stack[-1] == "deck":
                name = _local(tag)
                self.b.warnings.append((self.event, FileProblem(
                    SourceLoc(self.path, self.lines[self.n], name),
                    f"nested element <{name}> ignored")))
        elif role == "model":
            self.seen_model = True
        stack.append(role)

    def data(self, text):
        if self.parts is not None:
            self.parts.append(text)

    def end(self, tag):
        self.event += 1
        if self.stack.pop() == "deck":
            rec = self.cur
            if self.parts:
                rec[2] = "".join(self.parts)
            rec[5] = self.event
            self.recs.append(rec)
            self.cur = self.parts = None
            if len(self.recs) >= _FLUSH:
                self.b.flush(self.recs)
                self.recs = []

    def close(self):
        self.b.flush(self.recs)
        self.recs = []


# --------------------------------------------------------------------------- element lines
# One convention for every located message (FILE:LINE): an element's line is the line of the
# '<' that opens its start tag -- the line an editor shows for ``<Force_Vector_TwoBody`` however
# many lines its attributes take. Its expression attributes (:class:`Expr`) carry the same
# location: the reader does not track attribute lines; messages name the attribute and the column
# in its value. Lines are counted at LF: CRLF is one line end, a lone CR (classic Mac OS) is not
# one, as libxml2 does not count it either (its syntax-error lines stay comparable).
# Both walks take these lines from one vectorised byte scan (:func:`_start_tag_scan`). Decks the
# scan cannot read -- UTF-16/32, or a declared encoding outside _ASCII_ENCODINGS -- are first
# re-encoded as UTF-8 (:func:`_as_utf8`: same characters, same line ends). Only bytes that do not
# decode keep libxml2's numbers (the line of the '>' that ends the start tag, unreliable beyond
# line 65535: libxml2 stores element lines in 16 bits); libxml2 then reports the encoding error.
_ENCODING = re.compile(rb"""^<\?xml[^>]*?encoding\s*=\s*["']([A-Za-z0-9._-]+)["']""")
_ASCII_ENCODINGS = re.compile(r"(utf-?8|(us-)?ascii|iso[-_]?8859[-_]?\d+|latin-?1|"
                              r"(windows|cp)-?125\d)", re.IGNORECASE)
_SPECIAL = re.compile(rb"<!--|<!\[CDATA\[|<\?|<!DOCTYPE")
_SPECIAL_END = {b"<!--": b"-->", b"<![CDATA[": b"]]>", b"<?": b"?>"}
# the document type declaration with its internal subset, whose quoted literals, comments and
# processing instructions may hold '<', '>', '[' or ']'
_DOCTYPE = re.compile(rb"""<!DOCTYPE(?:[^"'\[>]++|"[^"]*+"|'[^']*+')*+"""
                      rb"""(?:\[(?:[^"'<\]]++|"[^"]*+"|'[^']*+'|<!--.*?-->|<\?.*?\?>|<)*+"""
                      rb"""\]\s*+)?>""", re.S)
_CHUNK = 1 << 24
_FEED = 1 << 16


def _positions(a: np.ndarray, values: tuple) -> list:
    """Offsets of each byte value in ``a`` (scanned in chunks: bounded temporaries)."""
    out: list[list] = [[] for _ in values]
    for i in range(0, a.size, _CHUNK):
        c = a[i:i + _CHUNK]
        for k, v in enumerate(values):
            out[k].append(np.flatnonzero(c == v) + i)
    return [np.concatenate(o) if o else np.zeros(0, np.intp) for o in out]


def _start_tag_scan(data: bytes) -> np.ndarray | None:
    """Line of the ``<`` opening every start tag, in document order (the convention above).

    None when the bytes cannot be scanned reliably: UTF-16/32 or a declared encoding outside
    ``_ASCII_ENCODINGS`` (:func:`_parse` re-encodes those as UTF-8 first; only undecodable bytes
    arrive here), a document that does not start with ``<``, a document type declaration that
    does not end; then libxml2's numbers are used. Outside comments, CDATA sections,
    processing instructions and the document type declaration, ``<`` followed by anything but
    ``/``, ``!`` or ``?`` opens a start tag (well-formed XML has no raw ``<`` in text or attribute
    values; the walks check that the count matches the elements parsed).
    """
    head = data[3:] if data[:3] == b"\xef\xbb\xbf" else data
    head = head.lstrip(b" \t\r\n")
    if not head.startswith(b"<") or b"\x00" in data[:4]:
        return None
    m = _ENCODING.match(head[:300])
    if m and not _ASCII_ENCODINGS.fullmatch(m.group(1).decode("ascii")):
        return None
    a = np.frombuffer(data, np.uint8)
    lt, nl = _positions(a, (60, 10))
    # '<' inside comments, CDATA, processing instructions and the DOCTYPE
    spans = []
    end = -1
    for sm in _SPECIAL.finditer(data):
        if sm.start() < end:
            continue
        tok = sm.group()
        if tok == b"<!DOCTYPE":
            dm = _DOCTYPE.match(data, sm.start())
            if dm is None:
                return None
            end = dm.end()
        else:
            e = data.find(_SPECIAL_END[tok], sm.end())
            end = len(data) if e < 0 else e + len(_SPECIAL_END[tok])
        spans.append((sm.start(), end))
    if spans:
        sp = np.array(spans, np.intp)
        k = np.searchsorted(sp[:, 0], lt, side="right") - 1
        inside = (k >= 0) & (lt < sp[np.maximum(k, 0), 1])
        lt = lt[~inside]
    nxt = a[np.minimum(lt + 1, a.size - 1)]
    starts = lt[(nxt != 47) & (nxt != 33) & (nxt != 63) & (lt + 1 < a.size)]
    return np.searchsorted(nl, starts) + 1           # newlines before the '<', plus one


_SCAN = object()   # "scan the bytes" (the default of the walks' ``lines``)


def _walk_fast(data: bytes, path: str, lines: Any = _SCAN) -> tuple[_Builder, bool] | None:
    """Parse with an lxml target (no tree) and the byte-scan line numbers (``lines``: the scan
    of ``data`` when already done); None when the scan does not apply or anything is unusual
    (the tree walk then reports)."""
    if lines is _SCAN:
        lines = _start_tag_scan(data)
    if lines is None:
        return None
    b = _Builder(path)
    t = _Target(path, lines, b)
    parser = etree.XMLParser(target=t, resolve_entities=False, no_network=True, load_dtd=False,
                             dtd_validation=False, huge_tree=False)
    try:
        view = memoryview(data)
        for i in range(0, len(data), _FEED):      # in pieces, as iterparse reads (libxml2's
            parser.feed(bytes(view[i:i + _FEED]))  # push buffer is limited without huge_tree)
        parser.close()
    except Exception:        # malformed XML etc.: the tree walk produces the same messages
        return None
    if t.n + 1 != len(lines) or t.n < 0:
        return None
    return b, t.seen_model


def _walk_tree(data: bytes, path: str, lines: Any = _SCAN) -> tuple[_Builder, bool]:
    """The general walk: lxml iterparse (secure options). Lines from the byte scan (``lines``:
    the scan of ``data`` when already done) when it applies and counts as many start tags as
    the parser found elements, else libxml2's (the module's convention comment)."""
    if lines is _SCAN:
        lines = _start_tag_scan(data)
    b = _Builder(path)
    recs: list[list] = []
    ords: list[int] = []        # start-tag ordinal of each record
    nested: list[tuple] = []    # (event, ordinal, libxml2 line, name) of nested elements
    seen_model = False
    ctx = etree.iterparse(io.BytesIO(data), events=("start", "end"), resolve_entities=False,
                          no_network=True, load_dtd=False, dtd_validation=False, huge_tree=False,
                          remove_comments=True, remove_pis=True)
    stack: list[str] = []
    ordinal = -1
    ord_stack: list[int] = []  # start-tag ordinal of each open element
    first = True
    event = 0
    for ev, elem in ctx:
        if not isinstance(elem.tag, str):
            continue
        event += 1
        if ev == "start":
            if first:
                first = False
                dtd = elem.getroottree().docinfo.internalDTD
                if dtd is not None and any(True for _ in dtd.iterentities()):
                    raise DeckError(FileProblem(SourceLoc(path, 1, "xml"),
                                                "entity declarations are not allowed in a deck"))
            ordinal += 1
            role = _role(stack, _lower_tag(elem.tag))
            if role == "nested" and stack[-1] == "deck":
                nested.append((event, ordinal, elem.sourceline or 0, _local(elem.tag)))
            seen_model = seen_model or role == "model"
            stack.append(role)
            ord_stack.append(ordinal)
            continue
        role = stack.pop()
        own = ord_stack.pop()
        if role == "deck":
            recs.append([elem.tag, dict(elem.attrib), elem.text, elem.sourceline or 0, stack[-1],
                         event])
            ords.append(own)
        if stack:  # keep memory bounded: drop processed elements
            elem.clear()
            parent_el = elem.getparent()
            if parent_el is not None:
                while elem.getprevious() is not None:
                    del parent_el[0]
    if not recs and not stack and first:
        raise DeckError(FileProblem(SourceLoc(path, 1, "xml"), "empty deck"))
    scanned = lines is not None and len(lines) == ordinal + 1
    if scanned:
        at = lines.tolist()
        for rec, k in zip(recs, ords):
            rec[3] = at[k]
    for ev, k, line, name in nested:
        b.warnings.append((ev, FileProblem(SourceLoc(path, at[k] if scanned else line, name),
                                           f"nested element <{name}> ignored")))
    b.flush(recs)
    return b, seen_model


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
    with _no_gc():     # millions of small acyclic objects: no cyclic collection meanwhile
        return _parse(data, path, check)


class _no_gc:
    """Cyclic garbage collection off inside the block (restored on exit if it was on)."""

    def __enter__(self):
        self.on = gc.isenabled()
        gc.disable()

    def __exit__(self, *exc):
        if self.on:
            gc.enable()


_BOMS = ((b"\x00\x00\xfe\xff", "utf-32-be"), (b"\xff\xfe\x00\x00", "utf-32-le"),
         (b"\xfe\xff", "utf-16-be"), (b"\xff\xfe", "utf-16-le"))
_NO_BOM = ((b"\x00\x00\x00<", "utf-32-be"), (b"<\x00\x00\x00", "utf-32-le"),
           (b"\x00<\x00?", "utf-16-be"), (b"<\x00?\x00", "utf-16-le"))
_DECL_ENCODING = re.compile(r"""^(\s*<\?xml[^>]*?encoding\s*=\s*)(["'])[^"']*\2""")


def _as_utf8(data: bytes) -> bytes:
    """The deck re-encoded as UTF-8 when the line scan cannot read its encoding.

    UTF-16/32 (by byte-order mark or by the first characters, XML 1.0 appendix F) and declared
    encodings outside ``_ASCII_ENCODINGS`` (e.g. Shift_JIS) are decoded and re-encoded as UTF-8
    with the declaration rewritten to ``encoding="UTF-8"``: the same characters and line ends,
    so every element gets the one line convention (its ``<`` line) at any deck size. Bytes that
    do not decode are returned unchanged (libxml2 then reports the located encoding error).
    """
    enc = next((e for bom, e in _BOMS if data.startswith(bom)), None)
    if enc is None:
        enc = next((e for pat, e in _NO_BOM if data.startswith(pat)), None)
    if enc is None:
        head = data[3:] if data[:3] == b"\xef\xbb\xbf" else data
        m = _ENCODING.match(head.lstrip(b" \t\r\n")[:300])
        if m is None or _ASCII_ENCODINGS.fullmatch(m.group(1).decode("ascii")):
            return data
        enc = m.group(1).decode("ascii")
    try:
        text = data.decode(enc)
    except (LookupError, UnicodeDecodeError):
        return data
    text = _DECL_ENCODING.sub(r'\1"UTF-8"', text.lstrip("\ufeff"), count=1)
    return text.encode("utf-8")


def _parse(data: bytes, path: str, check: bool) -> DeckSpec:
    spec = DeckSpec(path=path, sha256=hashlib.sha256(data).hexdigest())
    _refuse_entities(data, path)
    data = _as_utf8(data)
    lines = _start_tag_scan(data)
    walked = _walk_fast(data, path, lines)
    if walked is None:
        try:
            walked = _walk_tree(data, path, lines)
        except DeckError:
            raise
        except etree.XMLSyntaxError as e:
            line = e.lineno or (e.position[0] if e.position else 0) or 0
            msg = " ".join((e.msg or str(e)).replace("\n,", ",").split())   # one line
            raise DeckError(FileProblem(SourceLoc(path, line, "xml"),
                                        f"malformed XML: {msg}")) from None
        except Exception as e:  # any other lxml / decoding failure is still a deck problem
            raise DeckError(FileProblem(SourceLoc(path, 0, "xml"),
                                        f"cannot parse deck: {type(e).__name__}: {e}")) from None
    b, seen_model = walked

    model, commands = spec.model, spec.commands
    for el, where, shp in b.items:
        kind = shp.kind
        if kind == "command" or where == "command" or (where == "root" and seen_model
                                                       and kind == "both"):
            el.is_command = True
            commands.append(el)
        else:
            if shp.defaults:
                el.attrs.update(shp.defaults)
            model.append(el)
    b.warnings.sort(key=lambda w: w[0])
    spec.warnings.extend(w for _, w in b.warnings)
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
        data = _read_deck(path)
    except OSError as e:
        raise DeckError(FileProblem(SourceLoc(path, 0, "xml"),
                                    f"cannot read deck: {e.strerror or e}")) from None
    return parse_deck_bytes(data, path, check=check)


#: Largest deck read (bytes). A 100 000-link chain deck is ~130 MB and needs ~3 GiB to solve;
#: the limit only stops endless inputs (``/dev/zero``, a stuck pipe) from exhausting memory.
MAX_DECK_BYTES = 1 << 32
_HEAD = 1 << 16


def _read_deck(path: str) -> bytes:
    """The deck's bytes; a stream that cannot be XML (``/dev/zero``, binary data) is refused
    after its first 64 KiB, and any input beyond :data:`MAX_DECK_BYTES` is refused."""
    def refuse(msg):
        raise DeckError(FileProblem(SourceLoc(path, 0, "xml"), msg))

    with open(path, "rb") as f:
        head = f.read(_HEAD)
        # after byte-order marks, whitespace (and the NULs of UTF-16/32) a deck starts with '<'
        start = head.lstrip(b"\xef\xbb\xbf\xfe\xff\x00 \t\r\n")[:1]
        if start and start != b"<":
            refuse(f"not an XML deck: expected '<' at the start of the file, found byte "
                   f"0x{start[0]:02x}")
        if not start and len(head) == _HEAD:
            refuse(f"not an XML deck: only NUL bytes and whitespace in the first {_HEAD} bytes")
        chunks, n = [head], len(head)
        while True:
            b = f.read(1 << 24)
            if not b:
                break
            n += len(b)
            if n > MAX_DECK_BYTES:
                refuse(f"deck larger than {MAX_DECK_BYTES >> 30} GiB (poise.deck.parser."
                       "MAX_DECK_BYTES); is it the right file?")
            chunks.append(b)
    return b"".join(chunks)
