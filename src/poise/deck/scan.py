"""Byte-level scans of a deck before lxml reads it: refused entities, encodings, element lines.

Entity declarations (expansion bombs, external entities) are refused before parsing; decks the
line scan cannot read are re-encoded as UTF-8; one vectorised scan gives the line of every start
tag (the convention is written below, at "element lines"). Kept apart from the lxml walks
because it works on raw bytes with numpy and knows nothing of elements.
"""
from __future__ import annotations

import re

import numpy as np

from poise.deck.validate import FileProblem
from poise.core.errors import DeckError, SourceLoc

_ENTITY = re.compile(rb"<!ENTITY", re.IGNORECASE)


# --------------------------------------------------------------------------- security pre-scan
def _line_of(data: bytes, offset: int) -> int:
    return data.count(b"\n", 0, offset) + 1


def refuse_entities(data: bytes, path: str) -> None:
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


# --------------------------------------------------------------------------- element lines
# One convention for every located message (FILE:LINE): an element's line is the line of the
# '<' that opens its start tag -- the line an editor shows for ``<Force_Vector_TwoBody`` however
# many lines its attributes take. Its expression attributes (:class:`Expr`) carry the same
# location: the reader does not track attribute lines; messages name the attribute and the column
# in its value. Lines are counted at LF: CRLF is one line end, a lone CR (classic Mac OS) is not
# one, as libxml2 does not count it either (its syntax-error lines stay comparable).
# Both walks take these lines from one vectorised byte scan (:func:`start_tag_scan`). Decks the
# scan cannot read -- UTF-16/32, or a declared encoding outside _ASCII_ENCODINGS -- are first
# re-encoded as UTF-8 (:func:`as_utf8`: same characters, same line ends). Only bytes that do not
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


def _positions(a: np.ndarray, values: tuple) -> list:
    """Offsets of each byte value in ``a`` (scanned in chunks: bounded temporaries)."""
    out: list[list] = [[] for _ in values]
    for i in range(0, a.size, _CHUNK):
        c = a[i:i + _CHUNK]
        for k, v in enumerate(values):
            out[k].append(np.flatnonzero(c == v) + i)
    return [np.concatenate(o) if o else np.zeros(0, np.intp) for o in out]


def start_tag_scan(data: bytes) -> np.ndarray | None:
    """Line of the ``<`` opening every start tag, in document order (the convention above).

    None when the bytes cannot be scanned reliably: UTF-16/32 or a declared encoding outside
    ``_ASCII_ENCODINGS`` (:func:`poise.deck.parser._parse` re-encodes those as UTF-8 first; only undecodable bytes
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


_BOMS = ((b"\x00\x00\xfe\xff", "utf-32-be"), (b"\xff\xfe\x00\x00", "utf-32-le"),
         (b"\xfe\xff", "utf-16-be"), (b"\xff\xfe", "utf-16-le"))
_NO_BOM = ((b"\x00\x00\x00<", "utf-32-be"), (b"<\x00\x00\x00", "utf-32-le"),
           (b"\x00<\x00?", "utf-16-be"), (b"<\x00?\x00", "utf-16-le"))
_DECL_ENCODING = re.compile(r"""^(\s*<\?xml[^>]*?encoding\s*=\s*)(["'])[^"']*\2""")


def as_utf8(data: bytes) -> bytes:
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
