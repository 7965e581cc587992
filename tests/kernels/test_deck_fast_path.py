"""The deck reader's fast paths report exactly what the element-by-element paths report.

* Parsing: the lxml target walk (``parser._walk_fast``) against the tree walk
  (``parser._walk_tree``) — same elements, typed attributes, locations (FILE:LINE), texts,
  sections and warnings — on every deck in ``decks/`` and on documents with multi-line tags,
  ``>`` and quotes in attribute values, ``<`` in comments / CDATA / processing instructions / a
  DOCTYPE, nested elements, CRLF line ends, a BOM, Latin-1 and more than 65 535 lines. Both
  walks take lines from the byte scan (``scan.start_tag_scan``): the line of the ``<`` that
  opens each start tag, checked against an independent parser (expat) on the same documents.
  UTF-16/32 decks and encodings the scan cannot read are re-encoded as UTF-8 first (same lines).
* Validation: the per-shape screen (``screen.Screen``) against a screen that sends every
  element through the element-by-element checks — same problems in the same order, same
  warnings — on randomly broken decks.
* Compile: vectorised marker poses (``rm_id`` chains composed level by level) against the
  marker-by-marker resolution.
"""
from __future__ import annotations

import random
from xml.parsers import expat

import numpy as np
import pytest

from poise.deck import parser as P
from poise.deck import scan as S
from poise.deck import screen
from poise.deck import validate as V
from poise.deck.spec import Expr
from poise.core.errors import DeckError

from support.paths import ROOT


DECKS = sorted((ROOT / "decks").glob("*.xml"))

TRICKY = b"""<?xml version="1.0" encoding="UTF-8"?>
<!-- a comment with <Fake_Tag a="1"/> and a > inside -->
<MotionSolve>
 <Model>
  <Body_Rigid id="1" isground="TRUE"
     label="a > b"
     cg_id="10"/>
  <Reference_Marker id="10" body_id="1" label='it&apos;s "q" &gt; x >'
      pos_x="1." POS_Y="2" a00="1." a10="0." a20="0." a01="0." a11="1." a21="0." a02="0."
      a12="0." a22="1." bogus="3"/>
  <?pi <not a tag> ?>
  <Reference_Spline id="3"><![CDATA[ 1 2 <x> ]]> 3 4 <!-- c <y/> --> 5 6 <Nested_Thing
      a="1"/> 7 8</Reference_Spline>
  <Force_Gravity grav_x="0." grav_y="-9.81D0"
   grav_z="0."></Force_Gravity>
  <Param_Static max_residual="1e-6" max_error="1e-5"/>
  <Unknown_Thing id="7" x="1.5" y="abc"/>
 </Model>
 <Command><Simulate analysis_type="Static" end_time="1"/><Stop/></Command>
</MotionSolve>
"""


def _summary(walked):
    b, seen_model = walked
    items = [(el.tag, repr(el.attrs), el.loc, el.text, where, shp.kind, shp.defaults)
             for el, where, shp in b.items]
    return items, [(k, str(w), w.loc) for k, w in b.warnings], seen_model


def _big() -> bytes:
    """About 69 000 lines: three-line start tags below and beyond libxml2's 16-bit line limit."""
    markers = "\n".join(f'<Reference_Marker id="{1000 + k}"\n   body_id="1"\n   pos_x="{k}."/>'
                        f'<!-- <Fake/> -->' for k in range(23_000))
    return (f'<MotionSolve><Model>\n<Body_Rigid id="1" isground="TRUE"/>\n{markers}\n'
            '<Force_Gravity\n grav_x="TIME*2"\n bogus="1"/>\n<Body_Point id="2"\n cg_id="1000">'
            '<Nested/></Body_Point></Model></MotionSolve>').encode()


DOCTYPE = TRICKY.replace(b"<MotionSolve>", b"""<!DOCTYPE MotionSolve SYSTEM "ms.dtd" [
  <!-- ]> <Fake_In_Dtd a="1"/> -->
  <!ELEMENT Fake (#PCDATA)>
  <?pi <Fake/> ]> ?>
]>
<MotionSolve>""", 1)
LATIN1 = (TRICKY.replace(b'encoding="UTF-8"', b'encoding="ISO-8859-1"')
          .replace(b'label="a > b"', 'label="é > ü"'.encode("latin-1")))

SAMPLES = [(p.name, p.read_bytes()) for p in DECKS] + [
    ("tricky", TRICKY), ("tricky_crlf", TRICKY.replace(b"\n", b"\r\n")),
    ("no_declaration", TRICKY.split(b"\n", 1)[1]), ("bom", b"\xef\xbb\xbf" + TRICKY),
    ("bom_no_declaration", b"\xef\xbb\xbf" + TRICKY.split(b"\n", 1)[1]),
    ("doctype", DOCTYPE), ("doctype_crlf", DOCTYPE.replace(b"\n", b"\r\n")),
    ("latin1", LATIN1), ("big", _big())]


@pytest.mark.parametrize("name,data", SAMPLES, ids=[s[0] for s in SAMPLES])
def test_fast_walk_matches_tree_walk(name, data):
    fast = P._walk_fast(data, name)
    assert fast is not None, "the fast path should apply"
    assert _summary(fast) == _summary(P._walk_tree(data, name))


def _expat_starts(data: bytes) -> list[tuple]:
    """``(name, line, role)`` of every start tag, in document order, from an independent parser:
    expat reports, at a start tag, the line where the tag begins (its ``<``), with no 16-bit cap.
    ``role``: "deck" for deck elements (children of the root, or of a ``<Model>`` / ``<Command>``
    directly under it), "nested" for the children of a deck element, else "other"."""
    p = expat.ParserCreate()
    out: list[tuple] = []
    roles: list[str] = []

    def start(name, attrs):
        low = name.lower()
        if not roles:
            role = "root"
        elif roles[-1] == "root":
            role = "section" if low in ("model", "command") else "deck"
        elif roles[-1] == "section":
            role = "deck"
        else:
            role = "nested" if roles[-1] == "deck" else "other"
        out.append((name, p.CurrentLineNumber, role))
        roles.append(role)

    p.StartElementHandler = start
    p.EndElementHandler = lambda name: roles.pop()
    p.Parse(data, True)
    return out


@pytest.mark.parametrize("name,data", SAMPLES, ids=[s[0] for s in SAMPLES])
def test_lines_are_those_of_the_opening_angle_bracket(name, data):
    starts = _expat_starts(data)
    assert S.start_tag_scan(data).tolist() == [line for _, line, _ in starts]
    deck = [line for _, line, role in starts if role == "deck"]
    nested = [(n, line) for n, line, role in starts if role == "nested"]
    for walk in (P._walk_fast, P._walk_tree):
        b, _ = walk(data, name)
        assert [el.loc.line for el, _, _ in b.items] == deck
        got = [(w.loc.tag, w.loc.line) for _, w in b.warnings if "nested element" in w.message]
        assert got == nested
        # expression attributes carry their element's location
        for el, _, _ in b.items:
            for v in el.attrs.values():
                if isinstance(v, Expr):
                    assert v.loc == el.loc


def test_multi_line_start_tags_below_and_beyond_65535():
    """The pinned cases, computed from the raw text: ``<Reference_Marker`` below and beyond line
    65 535 (three-line start tags), ``<Force_Gravity`` (beyond) with an unknown attribute two
    lines further down, ``<Nested>`` inside a two-line ``<Body_Point>``."""
    data = _big()
    text = data.decode()

    def line_of(s: str, start: int = 0) -> int:
        return text.count("\n", 0, text.index(s, start)) + 1

    below, beyond = line_of('<Reference_Marker id="1001"'), line_of('<Reference_Marker id="23999"')
    assert below < 65_535 < beyond
    assert text.count("\n", 0, text.index("/>", text.index('id="23999"'))) + 1 == beyond + 2
    grav = line_of("<Force_Gravity")
    for walk in (P._walk_fast, P._walk_tree):
        b, _ = walk(data, "big.xml")
        els = {(el.tag, el.get("id")): el for el, _, _ in b.items}
        assert els[("Reference_Marker", 1001)].loc.line == below
        assert els[("Reference_Marker", 23999)].loc.line == beyond
        g = els[("Force_Gravity", None)]
        assert g.loc.line == grav and g.get("grav_x").loc.line == grav
        assert els[("Body_Point", 2)].loc.line == line_of("<Body_Point")
        assert [str(w) for _, w in sorted(b.warnings, key=lambda w: w[0])] == [
            f"big.xml:{grav}: <Force_Gravity>: unknown attribute 'bogus' ignored",
            f"big.xml:{line_of('<Nested/>')}: nested element <Nested> ignored"]


def _encoded(text: str, enc: str, bom: bool = True) -> bytes:
    text = text.replace('encoding="UTF-8"', f'encoding="{enc.upper().removesuffix("-SIG")}"')
    data = text.encode(enc)
    if not bom:
        for mark in (b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff", b"\xff\xfe", b"\xfe\xff"):
            if data.startswith(mark):
                return data[len(mark):]
    return data


@pytest.mark.parametrize("enc,bom", [("utf-16", True), ("utf-16-le", False), ("utf-16-be", False),
                                     ("utf-32", True), ("utf-32-be", False), ("shift_jis", True),
                                     ("iso-2022-jp", True)])
def test_other_encodings_follow_the_same_line_convention(enc, bom):
    """Decks in UTF-16/32 (with or without byte-order mark) or an encoding the byte scan cannot
    read are re-encoded as UTF-8 before parsing: the same elements, values and '<' lines as the
    UTF-8 deck, also beyond line 65 535 (where libxml2's own numbers are unreliable)."""
    text = TRICKY.decode()
    want = P.parse_deck_bytes(TRICKY, "u.xml", check=False)
    got = P.parse_deck_bytes(_encoded(text, enc, bom), "u.xml", check=False)
    key = [(e.tag, e.loc.line, sorted(map(str, e.attrs.items()))) for e in want.model + want.commands]
    assert [(e.tag, e.loc.line, sorted(map(str, e.attrs.items())))
            for e in got.model + got.commands] == key
    assert [str(w) for w in got.warnings] == [str(w) for w in want.warnings]
    assert got.sha256 != want.sha256            # the hash is of the bytes as given


def test_utf16_big_deck_lines():
    data = _big()
    text = data.decode()
    u16 = _encoded(text, "utf-16")
    spec = P.parse_deck_bytes(u16, "big16.xml", check=False)
    ref = P.parse_deck_bytes(data, "big.xml", check=False)
    lines = [e.loc.line for e in spec.model]
    assert lines == [e.loc.line for e in ref.model] and max(lines) > 65_535


def test_binary_and_endless_inputs_are_refused_early(tmp_path):
    z = tmp_path / "zeros.xml"
    z.write_bytes(bytes(1 << 17))
    with pytest.raises(DeckError, match="only NUL bytes and whitespace in the first 65536"):
        P.load_deck(str(z))
    r = tmp_path / "bin.xml"
    r.write_bytes(b"\x89PNG\r\n" + bytes(100))
    with pytest.raises(DeckError, match="expected '<' at the start of the file, found byte 0x89"):
        P.load_deck(str(r))
    with pytest.raises(DeckError, match="only NUL bytes"):
        P.load_deck("/dev/zero")                 # endless: refused after its first 64 KiB


@pytest.mark.parametrize("data", [
    TRICKY.decode().replace('encoding="UTF-8"', 'encoding="UTF-16"').encode("utf-16"),
    TRICKY.replace(b"</Model>", b"</Modle>"),            # malformed: the tree walk reports
    TRICKY.replace(b'encoding="UTF-8"', b'encoding="ISO-2022-JP"'),   # not scanned
    TRICKY.replace(b"<MotionSolve>", b"<!DOCTYPE MotionSolve [\n<!ELEMENT x ANY>\n<MotionSolve>"),
    b"",
])
def test_fast_walk_declines_unusual_documents(data):
    assert P._walk_fast(data, "x.xml") is None


class _NoScreen(screen.Screen):
    """Every element through the element-by-element checks."""

    def __init__(self, els):
        super().__init__(els)
        n = len(els)
        self.values = [False] * n
        self.marker = [False] * n
        self.expr = [True] * n

    def refs(self, ids):
        return [False] * len(self.els)

    def body_type(self, bodies):
        out = []
        for el in self.els:
            bad = False
            if el.tag == "Reference_Marker" and not el.is_command:
                body = bodies.get(el.get("body_id"))
                bt = el.get("body_type")
                if body is not None and bt in ("RIGIDBODY", "POINTBODY"):
                    bad = bt != ("POINTBODY" if body.tag == "Body_Point" else "RIGIDBODY")
            out.append(bad)
        return out


VALUES = ["", "abc", "1e308", "1e309", "inf", "nan", "0", "-0", "-1", "-1e-300", "TRUE",
          "1.5.2", "9" * 30, "DX(1,2)", "((((", "2147483648", " 1 ", "1e", "0.5", "7",
          "RIGIDBODY", "POINTBODY", "REVOLUTE", "FOO"]


def _mutate(data: bytes, rnd: random.Random) -> bytes:
    from lxml import etree
    root = etree.fromstring(data, etree.XMLParser(remove_comments=True))
    els = [e for e in root.iter() if isinstance(e.tag, str) and e is not root]
    for _ in range(rnd.randint(1, 4)):
        e = rnd.choice(els)
        op = rnd.randrange(4)
        if op == 0 and e.attrib:
            e.set(rnd.choice(sorted(e.attrib)), rnd.choice(VALUES))
        elif op == 1 and e.attrib:
            del e.attrib[rnd.choice(sorted(e.attrib))]
        elif op == 2 and e.getparent() is not None:
            e.addnext(etree.fromstring(etree.tostring(e)))
        else:
            e.set(rnd.choice(["mass", "id", "body_id", "rm_id", "cg_id", "e0", "psi",
                              "a01", "body_type", "i_marker_id"]), rnd.choice(VALUES))
    return etree.tostring(root, encoding="utf-8")


def _report(data: bytes):
    try:
        spec = P.parse_deck_bytes(data, "m.xml")
        return "ok", [str(w) for w in spec.warnings]
    except DeckError as e:
        return "error", [str(p) for p in e.problems]


def test_validation_screen_matches_element_by_element(monkeypatch):
    rnd = random.Random(20240607)
    sources = [p.read_bytes() for p in DECKS if "invalid" not in str(p)]
    cases = [rnd.choice(sources) for _ in range(150)]
    cases = [_mutate(d, rnd) for d in cases] + sources
    screened = [_report(d) for d in cases]
    monkeypatch.setattr(V, "Screen", _NoScreen)
    assert [_report(d) for d in cases] == screened


RM_DECK = b"""<MotionSolve><Model>
 <Body_Rigid id="1" isground="TRUE" cg_id="1"/>
 <Reference_Marker id="1" body_id="1"/>
 <Reference_Marker id="5" body_id="2" rm_id="4" pos_x="1" psi="0.3"/>
 <Reference_Marker id="4" body_id="2" rm_id="3" pos_y="2" a00="0" a10="1" a20="0" a01="-1"
   a11="0" a21="0" a02="0" a12="0" a22="1"/>
 <Reference_Marker id="3" body_id="2" rm_id="0" pos_z="3" e0="0.9" e1="0.1" e2="0.2" e3="0.3"/>
 <Reference_Marker id="6" body_id="2" rm_id="5" pos_x="-1" yaw="0.2" pitch="0.1" roll="0.4"/>
 <Body_Rigid id="2" cg_id="6" mass="1" inertia_xx="1" inertia_yy="2" inertia_zz="3"
   im_id="4"/>
 <Constraint_Joint id="1" type="SPHERICAL" i_marker_id="3" j_marker_id="1"/>
</Model><Command><Simulate analysis_type="Static"/></Command></MotionSolve>"""


def test_vectorised_marker_poses_match_marker_by_marker():
    from poise.model import compile as C
    spec = P.parse_deck_bytes(RM_DECK, "rm.xml")
    b = C._Builder(spec)
    b.markers()
    fast = b.marker_glob
    b._markers_checked(b.marker_els)
    slow = b.marker_glob
    assert sorted(fast.keys()) == sorted(slow.keys())
    for mid in slow.keys():
        for x, y in zip(fast[mid], slow[mid]):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-14)
