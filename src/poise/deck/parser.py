"""XML deck reader: bytes -> typed :class:`~poise.deck.spec.DeckSpec` (then validated).

Layout (deck_format.md §1.1): the root may have any name; model elements come from ``<Model>``
(or from directly under the root when there is no ``<Model>``); commands come from ``<Command>``
or directly under the root, in document order. Command-only elements (``Simulate``, ``Stop``, ...)
are commands wherever they appear. Element and attribute names are case-insensitive. lxml runs
with ``resolve_entities=False, no_network=True, load_dtd=False, dtd_validation=False,
huge_tree=False`` after :mod:`poise.deck.scan` refused entity declarations; every failure is a
located :class:`~poise.core.errors.DeckError`. Values are typed by :mod:`poise.deck.values`,
elements built by :mod:`poise.deck.build`; locations are the lines of :mod:`poise.deck.scan`.
"""
from __future__ import annotations

import gc
import hashlib
import io
from typing import Any

import numpy as np
from lxml import etree

from poise.deck.build import Builder, local_name, local_tag, place
from poise.deck.scan import as_utf8, refuse_entities, start_tag_scan
from poise.deck.spec import DeckSpec
from poise.deck.validate import FileProblem, validate
from poise.core.errors import DeckError, SourceLoc
from poise.core.memory import release

_SECTIONS = ("model", "command")
_FEED = 1 << 16                       # bytes fed to lxml at a time


# --------------------------------------------------------------------------- document walk
_CONTAINERS = ("root", *_SECTIONS)
_LOWER_TAG: dict[str, str] = {}      # element tag as written -> lower-case local name
_FLUSH = 4096                         # records typed per batch (bounded memory)


def _lower_tag(tag: str) -> str:
    v = _LOWER_TAG.get(tag)
    if v is None:
        v = _LOWER_TAG[tag] = local_tag(tag).lower()
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
    the byte scan (:func:`poise.deck.scan.start_tag_scan`), flushed to the builder in batches."""

    def __init__(self, path: str, lines: np.ndarray, b: Builder):
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
                name = local_name(tag)
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


_SCAN = object()   # "scan the bytes" (the default of the walks' ``lines``)


def _walk_fast(data: bytes, path: str, lines: Any = _SCAN) -> tuple[Builder, bool] | None:
    """Parse with an lxml target (no tree) and the byte-scan line numbers (``lines``: the scan
    of ``data`` when already done); None when the scan does not apply or anything is unusual
    (the tree walk then reports)."""
    if lines is _SCAN:
        lines = start_tag_scan(data)
    if lines is None:
        return None
    b = Builder(path)
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


def _walk_tree(data: bytes, path: str, lines: Any = _SCAN) -> tuple[Builder, bool]:
    """The general walk: lxml iterparse (secure options). Lines from the byte scan (``lines``:
    the scan of ``data`` when already done) when it applies and counts as many start tags as
    the parser found elements, else libxml2's (the convention of poise.deck.scan)."""
    if lines is _SCAN:
        lines = start_tag_scan(data)
    b = Builder(path)
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
                nested.append((event, ordinal, elem.sourceline or 0, local_name(elem.tag)))
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
def parse_deck_bytes(data: bytes, path: str, *, check: bool = True, ignore=()) -> DeckSpec:
    """Parse deck bytes into a :class:`DeckSpec`.

    Parameters
    ----------
    data : bytes
        Raw deck bytes (their SHA-256 goes to ``DeckSpec.sha256``).
    path : str
        Deck path used in every message.
    check : bool, optional
        Run :func:`poise.deck.validate.validate` (default True).
    ignore : iterable of str, optional
        Adams datasets only: kinds of statements left out instead of refused (``--ignore``).

    Returns
    -------
    DeckSpec

    Raises
    ------
    DeckError
        Malformed XML, entity declarations, or (with ``check``) any validation problem; all
        validation problems of the deck are reported in one error.
    """
    if _is_dataset(path):
        from poise.deck.adm import load_dataset  # lazy: only Adams datasets need the reader
        return load_dataset(path, data, check=check, ignore=ignore)
    with _no_gc():     # millions of small acyclic objects: no cyclic collection meanwhile
        return _parse(data, path, check)


def _is_dataset(path: str) -> bool:
    """An Adams dataset (``.adm``) or command file (``.acf``): read by poise.deck.adm."""
    return str(path).lower().endswith((".adm", ".acf"))


class _no_gc:
    """Cyclic garbage collection off inside the block (restored on exit if it was on)."""

    def __enter__(self):
        self.on = gc.isenabled()
        gc.disable()

    def __exit__(self, *exc):
        if self.on:
            gc.enable()


def _parse(data: bytes, path: str, check: bool) -> DeckSpec:
    spec = DeckSpec(path=path, sha256=hashlib.sha256(data).hexdigest())
    refuse_entities(data, path)
    data = as_utf8(data)
    lines = start_tag_scan(data)
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

    place(spec, b.items, seen_model)
    b.warnings.sort(key=lambda w: w[0])
    spec.warnings.extend(w for _, w in b.warnings)
    if check:
        validate(spec)
    return spec


def load_deck(path, *, check: bool = True, ignore=()) -> DeckSpec:
    """Read, parse and validate a deck file.

    Parameters
    ----------
    path : str or os.PathLike
        Deck path (used as given in every message).
    check : bool, optional
        Validate the deck (default True).
    ignore : iterable of str, optional
        Adams datasets only (``.adm``/``.acf``): kinds left out instead of refused.

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
        data = _read_deck(path, dataset=_is_dataset(path))
    except OSError as e:
        raise DeckError(FileProblem(SourceLoc(path, 0, "xml"),
                                    f"cannot read deck: {e.strerror or e}")) from None
    spec = parse_deck_bytes(data, path, check=check, ignore=ignore)
    size = len(data)
    del data
    release(size)        # the parse's freed records and buffers back to the OS (large decks)
    return spec


#: Largest deck read (bytes). A 100 000-link chain deck is ~130 MB and needs ~3 GiB to solve;
#: the limit only stops endless inputs (``/dev/zero``, a stuck pipe) from exhausting memory.
MAX_DECK_BYTES = 1 << 32
_HEAD = 1 << 16


def _read_deck(path: str, dataset: bool = False) -> bytes:
    """The deck's bytes; a stream that cannot be XML (``/dev/zero``, binary data) is refused
    after its first 64 KiB, and any input beyond :data:`MAX_DECK_BYTES` is refused."""
    def refuse(msg):
        raise DeckError(FileProblem(SourceLoc(path, 0, "xml"), msg))

    with open(path, "rb") as f:
        head = f.read(_HEAD)
        # after byte-order marks, whitespace (and the NULs of UTF-16/32) a deck starts with '<'
        start = head.lstrip(b"\xef\xbb\xbf\xfe\xff\x00 \t\r\n")[:1]
        if start and start != b"<" and not dataset:
            refuse(f"not an XML deck: expected '<' at the start of the file, found byte "
                   f"0x{start[0]:02x}")
        if dataset and b"\x00" in head:
            refuse("not an Adams dataset: the file holds binary data (NUL bytes)")
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
