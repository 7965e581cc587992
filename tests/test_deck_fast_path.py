"""The deck reader's fast paths report exactly what the element-by-element paths report.

* Parsing: the lxml target walk with byte-scan line numbers (``parser._walk_fast``) against the
  tree walk with libxml2's line numbers (``parser._walk_tree``) — same elements, typed
  attributes, locations (FILE:LINE), texts, sections and warnings — on every deck in ``decks/``
  and on documents with multi-line tags, ``>`` and quotes in attribute values, ``<`` in
  comments / CDATA / processing instructions, nested elements, CRLF line ends and more than
  65 535 lines.
* Validation: the per-shape screen (``validate._Screen``) against a screen that sends every
  element through the element-by-element checks — same problems in the same order, same
  warnings — on randomly broken decks.
* Compile: vectorised marker poses (``rm_id`` chains composed level by level) against the
  marker-by-marker resolution.
"""
from __future__ import annotations

import random
import re
from pathlib import Path

import numpy as np
import pytest

from poise.deck import parser as P
from poise.deck import validate as V
from poise.errors import DeckError

ROOT = Path(__file__).resolve().parents[1]
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
    markers = "\n".join(f'<Reference_Marker id="{1000 + k}" body_id="1"\n   pos_x="{k}."/>'
                        f'<!-- <Fake/> -->' for k in range(23_000))
    return (f'<MotionSolve><Model>\n<Body_Rigid id="1" isground="TRUE"/>\n{markers}\n'
            '<Force_Gravity\n grav_x="TIME*2"\n bogus="1"/>\n<Body_Point id="2"\n cg_id="1000">'
            '<Nested/></Body_Point></Model></MotionSolve>').encode()


SAMPLES = [(p.name, p.read_bytes()) for p in DECKS] + [
    ("tricky", TRICKY), ("tricky_crlf", TRICKY.replace(b"\n", b"\r\n")),
    ("no_declaration", TRICKY.split(b"\n", 1)[1]), ("big", _big())]


@pytest.mark.parametrize("name,data", SAMPLES, ids=[s[0] for s in SAMPLES])
def test_fast_walk_matches_tree_walk(name, data):
    fast = P._walk_fast(data, name)
    assert fast is not None, "the fast path should apply"
    assert _summary(fast) == _summary(P._walk_tree(data, name))


def test_big_deck_lines_follow_the_documented_convention():
    data = _big()
    lines = P._start_tag_scan(data)
    text = data.decode()
    starts = [m.start() for m in re.finditer(r"<!--.*?-->|<[A-Za-z_]", text, re.S)
              if not m.group().startswith("<!--")]
    assert len(starts) == len(lines)
    for i, ln in zip(starts, lines.tolist()):
        close = text.count("\n", 0, text.index(">", i)) + 1
        assert ln == (close if close < 65535 else text.count("\n", 0, i) + 1)


@pytest.mark.parametrize("data", [
    TRICKY.replace(b"<MotionSolve>", b"<!DOCTYPE MotionSolve>\n<MotionSolve>"),
    TRICKY.decode().replace('encoding="UTF-8"', 'encoding="UTF-16"').encode("utf-16"),
    TRICKY.replace(b"</Model>", b"</Modle>"),            # malformed: the tree walk reports
    b"",
])
def test_fast_walk_declines_unusual_documents(data):
    assert P._walk_fast(data, "x.xml") is None


class _NoScreen(V._Screen):
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
    monkeypatch.setattr(V, "_Screen", _NoScreen)
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
