"""Deck reader: parser, schema, validation and the invalid-deck corpus (decks/invalid)."""
from __future__ import annotations

import hashlib
import re

import pytest

from poise.deck.parser import load_deck, parse_deck_bytes
from poise.deck.values import parse_number
from poise.deck.schema import SCHEMAS, element_schema, render_markdown
from poise.deck.spec import Expr
from poise.core.errors import DeckError

from support.paths import ROOT


INVALID = ROOT / "decks" / "invalid"

# (deck, line, message fragment) -- several rows per deck when it holds several problems
CASES = [
    ("missing_required.xml", 14, "missing required attribute 'type'"),
    ("dangling_marker.xml", 14, "'j_marker_id' refers to a missing Reference_Marker"),
    ("duplicate_id.xml", 11, "duplicate id 101"),
    ("bad_enum_joint_type.xml", 14, "unknown value for 'type'"),
    ("bad_method.xml", 7, "unknown value for 'method'"),
    ("non_numeric.xml", 11, "attribute 'mass' is not a number; expected a real number, got 'two'"),
    ("negative_mass.xml", 11, "attribute 'mass' out of range; expected >= 0, got -2"),
    ("inertia_not_pd.xml", 11, "inertia tensor is not positive definite"),
    ("unknown_element.xml", 15, "unknown element <Force_Magic>"),
    ("unsupported_element.xml", 15, "<Force_MultiPoint> is not supported yet"),
    ("entity_bomb.xml", 4, "entity declarations"),
    ("external_entity.xml", 4, "entity declarations"),
    ("malformed_xml.xml", 11, "malformed XML"),
    ("truncated.xml", 13, "malformed XML: Premature end of data"),
    ("two_grounds.xml", 11, "more than one ground body"),
    ("non_orthonormal_marker.xml", 12, "direction cosines are not orthonormal"),
    ("no_ground.xml", 8, "no ground body"),
    ("bad_tolerance.xml", 7, "attribute 'max_imbalance' out of range; expected >= 1e-100"),
    ("bad_analysis_type.xml", 17, "unknown value for 'analysis_type'"),
    ("end_before_start.xml", 17, "end_time before start_time"),
    ("several_errors.xml", 11, "attribute 'mass' out of range"),
    ("several_errors.xml", 13, "'body_id' refers to a missing Body_Rigid"),
    ("several_errors.xml", 14, "unknown value for 'type'"),
    ("several_errors.xml", 15, "unknown element <Force_Magic>"),
    # the element's line (its start tag opens on 14), not the attribute's (15)
    ("expr_syntax.xml", 14, "val_expression col 24: expected ')'"),
]


@pytest.mark.parametrize("deck,line,fragment", CASES)
def test_invalid_deck(deck, line, fragment):
    path = str(INVALID / deck)
    with pytest.raises(DeckError) as ei:
        load_deck(path)
    msg = str(ei.value)
    matching = [m for m in msg.splitlines() if fragment in m]
    assert matching, msg
    assert any(m.startswith(f"{path}:{line}: ") for m in matching), msg
    assert ei.value.exit_code == 3


def test_every_invalid_deck_is_in_the_table_and_documents_its_line():
    decks = sorted(p.name for p in INVALID.glob("*.xml"))
    assert set(decks) == {c[0] for c in CASES}
    for name in decks:
        head = (INVALID / name).read_text().splitlines()[1]
        lines = {c[1] for c in CASES if c[0] == name}
        assert head.startswith("<!--"), (name, head)
        assert all(str(n) in head for n in lines), (name, head)


def test_several_errors_reported_together():
    with pytest.raises(DeckError) as ei:
        load_deck(str(INVALID / "several_errors.xml"))
    assert len(ei.value.problems) >= 3
    lines = [p.loc.line for p in ei.value.problems]
    assert lines == sorted(lines)


def test_validation_messages_say_expected_and_got():
    for name in ("missing_required.xml", "dangling_marker.xml", "non_numeric.xml", "bad_method.xml",
                 "inertia_not_pd.xml", "two_grounds.xml", "non_orthonormal_marker.xml"):
        with pytest.raises(DeckError) as ei:
            load_deck(str(INVALID / name))
        for line in str(ei.value).splitlines():
            assert "; expected " in line and ", got " in line, line


# --------------------------------------------------------------------------- a valid base deck
DCM = ('a00="1." a10="0." a20="0." a01="0." a11="1." a21="0." a02="0." a12="0." a22="1."')


def model(extra: str = "", ground_tag: str = "Body_Rigid") -> str:
    return f"""
    <Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="MILLIMETER" time_unit="SECOND"/>
    <Force_Gravity grav_y="-9810."/>
    <{ground_tag} id="1" isground="TRUE" cg_id="100"/>
    <Reference_Marker id="100" body_id="1" pos_x="0." pos_y="0." pos_z="0." {DCM}/>
    <Reference_Marker id="101" body_id="1" {DCM}/>
    <Body_Rigid id="2" cg_id="200" mass="2." inertia_xx="1." inertia_yy="2." inertia_zz="2."/>
    <Reference_Marker id="200" body_id="2" pos_x="200." {DCM}/>
    <Reference_Marker id="201" body_id="2" {DCM}/>
    <Constraint_Joint id="1" type="REVOLUTE" i_marker_id="201" j_marker_id="101"/>
    {extra}"""


def deck(body: str) -> bytes:
    return f'<?xml version="1.0"?>\n<MotionSolve>{body}</MotionSolve>\n'.encode()


def full(extra: str = "", commands: str = '<Simulate analysis_type="Static"/><Stop/>') -> bytes:
    return deck(f"<Model>{model(extra)}</Model><Command>{commands}</Command>")


def test_valid_base_deck():
    spec = parse_deck_bytes(full(), "base.xml")
    assert [e.tag for e in spec.commands] == ["Simulate", "Stop"]
    assert spec.commands[0].get("analysis_type") == "STATIC"
    assert all(c.is_command for c in spec.commands)
    assert not any(e.is_command for e in spec.model)
    assert spec.warnings == []
    assert spec.by_id("Reference_Marker")[200].get("pos_x") == 200.0
    assert spec.elements("Force_Gravity")[0].attrs == {"grav_x": 0.0, "grav_y": -9810.0, "grav_z": 0.0}


def test_case_insensitive_tags_attrs_and_enums():
    body = f"""<MODEL>
      <param_unit FORCE_UNIT="newton"/>
      <BODY_RIGID ID="1" IsGround="true" CG_ID="100"/>
      <reference_marker Id="100" BODY_ID="1" {DCM.upper()}/>
      <Reference_Marker id="101" body_id="1"/>
      <body_rigid id="2" cg_id="200" MASS="1." Inertia_XX="1." inertia_yy="1." inertia_zz="1."/>
      <REFERENCE_MARKER id="200" body_id="2"/>
      <constraint_joint id="1" TYPE="Revolute" i_marker_id="200" j_marker_id="101"/>
      <force_vector_onebody id="1" marker_id="200" type="ForceOnly" fy_expression="-1."/>
      <force_scalar_twobody id="1" i_marker_id="200" j_marker_id="101" type="Force" val="3."/>
    </MODEL><command><simulate ANALYSIS_TYPE="quasi-static" end_time="1." num_step="10"/></command>"""
    spec = parse_deck_bytes(deck(body), "ci.xml")
    assert spec.by_id("Body_Rigid")[1].get("isground") is True
    assert spec.by_id("Constraint_Joint")[1].get("type") == "REVOLUTE"
    assert spec.by_id("Force_Vector_OneBody")[1].get("type") == "FORCEONLY"
    assert spec.elements("Param_Unit")[0].get("force_unit") == "NEWTON"
    sim = spec.commands[0]
    assert (sim.tag, sim.get("analysis_type"), sim.get("num_steps")) == ("Simulate", "QUASISTATIC", 10)
    assert spec.warnings == []
    assert element_schema("FORCE_SPRINGDAMPER").tag == "Force_SpringDamper"
    assert element_schema("constraint_usrconstr").tag == "Constraint_UserConstr"
    assert element_schema("Nope") is None


def test_commands_directly_under_root_in_document_order():
    body = (f"<Model>{model()}</Model>"
            '<Param_Static method="mkeam"/><Simulate analysis_type="Static"/>'
            '<Force_Gravity grav_y="-1000."/><Simulate analysis_type="Static" end_time="1."/><Stop/>')
    spec = parse_deck_bytes(deck(body), "root.xml")
    assert [e.tag for e in spec.commands] == ["Param_Static", "Simulate", "Force_Gravity", "Simulate", "Stop"]
    # command versions carry only what was written (they modify live settings)
    assert spec.commands[0].attrs == {"method": "MKEAM"}
    assert spec.commands[2].attrs == {"grav_y": -1000.0}
    assert [e.tag for e in spec.elements("Force_Gravity")] == ["Force_Gravity"]


def test_no_model_element_everything_under_root():
    spec = parse_deck_bytes(deck(model('<Param_Static method="FIM_S"/>') +
                                 '<Simulate analysis_type="Static"/><Stop/>'), "flat.xml")
    assert spec.elements("Param_Static")[0].get("max_num_iter") == 100
    assert [e.tag for e in spec.commands] == ["Simulate", "Stop"]


def test_commands_inside_command_section():
    cmds = ('<Param_Static method="FIM_S" max_residual="1e-6"/><Simulate analysis_type="Static"/>'
            f'<Reference_Marker id="200" pos_x="250." {DCM}/><Simulate analysis_type="Static"/><Stop/>')
    spec = parse_deck_bytes(full(commands=cmds), "cmd.xml")
    assert [e.tag for e in spec.commands] == ["Param_Static", "Simulate", "Reference_Marker", "Simulate", "Stop"]
    assert spec.commands[0].attrs == {"method": "FIM_S", "max_error": 1e-6}
    assert spec.commands[2].get("pos_x") == 250.0 and spec.commands[2].is_command


def test_command_for_missing_model_element_is_an_error():
    with pytest.raises(DeckError, match=r"cmd.xml:\d+: <Reference_Marker id=999>: command modifies a missing"):
        parse_deck_bytes(full(commands=f'<Reference_Marker id="999" pos_x="1." {DCM}/>'), "cmd.xml")


def test_model_element_in_command_section_is_an_error():
    with pytest.raises(DeckError, match="is a model element"):
        parse_deck_bytes(full(commands='<Param_Unit force_unit="NEWTON"/>'), "c.xml")


def test_unknown_attribute_is_a_warning_not_an_error():
    data = full('<Force_SpringDamper id="1" type="TRANSLATIONAL" i_marker_id="200" j_marker_id="101" '
                'stiffness="2." length="100." body1_id="2" foo="1"/>')
    spec = parse_deck_bytes(data, "w.xml")
    texts = [str(w) for w in spec.warnings]
    line = data.decode().splitlines().index(next(x for x in data.decode().splitlines() if "body1_id" in x)) + 1
    assert f"w.xml:{line}: <Force_SpringDamper id=1>: unknown attribute 'body1_id' ignored" in texts
    assert f"w.xml:{line}: <Force_SpringDamper id=1>: unknown attribute 'foo' ignored" in texts
    sd = spec.by_id("Force_SpringDamper")[1]
    assert "foo" not in sd.attrs and sd.get("damping") == 0.0 and sd.get("preload") == 0.0


def test_post_graphic_keeps_unknown_attributes_without_warning():
    spec = parse_deck_bytes(full('<Post_Graphic id="5" type="Sphere" body_id="2" radius="12.5" cm_id="200" '
                                 'style="shaded"/>'), "g.xml")
    g = spec.by_id("Post_Graphic")[5]
    assert g.get("radius") == 12.5 and g.get("style") == "shaded" and g.get("body_id") == 2
    assert spec.warnings == []


def test_spring_angle_alias():
    spec = parse_deck_bytes(full('<Force_SpringDamper id="1" type="ROTATIONAL" i_marker_id="201" '
                                 'j_marker_id="101" stiffness="5." damping="0." angle="0.5"/>'), "a.xml")
    assert spec.by_id("Force_SpringDamper")[1].get("length") == 0.5


@pytest.mark.parametrize("text,value", [
    ("1.E-3", 1e-3), ("1.5D0", 1.5), ("-9810.", -9810.0), (".5", 0.5), ("1e3", 1000.0),
    ("+2.5d-2", 0.025), ("7", 7.0), (" 3. ", 3.0), ("1.0E+003", 1000.0),
])
def test_fortran_numbers(text, value):
    assert parse_number(text) == pytest.approx(value)


@pytest.mark.parametrize("text", ["180D", "1.5.2", "abc", "", "1e", "nan", "inf", "PI"])
def test_not_plain_numbers(text):
    assert parse_number(text) is None


def test_fortran_numbers_in_a_deck():
    spec = parse_deck_bytes(full('<Force_Bushing id="1" i_marker_id="200" j_marker_id="101" kx="1.5D2" '
                                 'ky="1.E-3" kz="2." preload_x="-9810."/>'), "n.xml")
    b = spec.by_id("Force_Bushing")[1]
    assert (b.get("kx"), b.get("ky"), b.get("kz"), b.get("preload_x"), b.get("ktz")) == (150.0, 1e-3, 2.0, -9810.0, 0.0)


def test_expr_typing():
    data = deck(f"<Model>{model()}</Model>".replace(
        '<Force_Gravity grav_y="-9810."/>', '<Force_Gravity grav_y="-9810*STEP(TIME,0,0,1,1)" grav_x="0"/>')
        .replace("</Model>", '<Force_Vector_OneBody id="3" marker_id="200" type="FORCEANDTORQUE" '
                             'fx_expression="10." fy_expression=" 180D " tz_expression="-DX(200,101)"/></Model>')
        + '<Simulate analysis_type="Static"/>')
    spec = parse_deck_bytes(data, "e.xml")
    g = spec.elements("Force_Gravity")[0]
    assert g.get("grav_x") == 0.0
    gy = g.get("grav_y")
    assert isinstance(gy, Expr) and gy.text == "-9810*STEP(TIME,0,0,1,1)" and gy.attr == "grav_y"
    assert gy.loc.tag == "Force_Gravity" and gy.loc.line == 4
    f = spec.by_id("Force_Vector_OneBody")[3]
    assert f.get("fx_expression") == 10.0
    assert f.get("fy_expression") == Expr("180D", f.loc, "fy_expression")
    assert isinstance(f.get("tz_expression"), Expr) and f.get("fz_expression") == 0.0


def test_bools_and_int_lists():
    cmds = ('<Simulate analysis_type="Static" freq_input_id_list="1, 2 3"/>'
            '<DebugOutput switch_on="yes" debug_anim="0" screen_output="False"/><Stop/>')
    spec = parse_deck_bytes(full(commands=cmds), "b.xml")
    assert spec.commands[0].get("freq_input_id_list") == (1, 2, 3)
    assert spec.commands[1].attrs == {"switch_on": True, "debug_anim": False, "screen_output": False}
    with pytest.raises(DeckError, match="attribute 'switch_on' is invalid value; expected TRUE or FALSE"):
        parse_deck_bytes(full(commands='<DebugOutput switch_on="maybe"/>'), "b.xml")


def test_sha256(tmp_path):
    data = full()
    assert parse_deck_bytes(data, "s.xml").sha256 == hashlib.sha256(data).hexdigest()
    f = tmp_path / "s.xml"
    f.write_bytes(data)
    spec = load_deck(str(f))
    assert spec.sha256 == hashlib.sha256(data).hexdigest() and spec.path == str(f)


def test_param_static_defaults():
    d = element_schema("Param_Static").defaults()
    assert d == {"method": "FIM_D", "max_ke_tol": 1e-5, "max_dq_tol": 1e-3, "max_num_iter": 100,
                 "max_imbalance": 1e-4, "max_error": 1e-4, "stability": 1e-10, "compliance_delta": 1e-3}
    spec = parse_deck_bytes(full('<Param_Static method="mkeam" max_residual="1.000E-04" max_num_iter="50"/>'), "p.xml")
    ps = spec.elements("Param_Static")[0]
    assert ps.attrs == {**d, "method": "MKEAM", "max_num_iter": 50}


def test_massless_moving_body_warns():
    spec = parse_deck_bytes(full('<Body_Rigid id="3" cg_id="300"/><Reference_Marker id="300" body_id="3"/>'
                                 '<Constraint_Joint id="2" type="FIXED" i_marker_id="300" j_marker_id="200"/>'),
                            "m.xml")
    assert any("moving body has no mass" in str(w) for w in spec.warnings)


def test_inertia_products_convention():
    # xy = +integral(xy dm): tensor [[1, -0.5], [-0.5, 1]] is positive definite either sign; a
    # product larger than the moments is not, whatever the sign
    parse_deck_bytes(full().replace(b'inertia_zz="2."', b'inertia_zz="2." inertia_xy="0.5"'), "i.xml")
    with pytest.raises(DeckError, match="not positive definite"):
        parse_deck_bytes(full().replace(b'inertia_zz="2."', b'inertia_zz="2." inertia_yz="-3."'), "i.xml")


# --------------------------------------------------------------------------- robustness
@pytest.mark.parametrize("data", [
    b"", b"   ", b"\x00\x01\x02binary", b"<MotionSolve>", b"<a><b></a>", b"not xml at all",
    "<?xml version='1.0' encoding='UTF-16'?><!DOCTYPE x [<!ENTITY e 'x'>]><x>&e;</x>".encode("utf-16"),
    b"<MotionSolve>&undefined;</MotionSolve>",
    b'<!DOCTYPE MotionSolve SYSTEM "http://example.invalid/x.dtd"><MotionSolve/>',
])
def test_every_failure_is_a_deck_error(data):
    with pytest.raises(DeckError) as ei:
        parse_deck_bytes(data, "bad.xml")
    assert str(ei.value).startswith("bad.xml:")


def test_missing_file_is_a_deck_error(tmp_path):
    with pytest.raises(DeckError, match="cannot read deck"):
        load_deck(str(tmp_path / "nope.xml"))


def test_large_deck_line_numbers():
    """Every element is located at the line of the ``<`` opening its start tag, below and beyond
    line 65 535 (where libxml2's own 16-bit line numbers give out)."""
    n = 25_000
    markers = "\n".join(f'<Reference_Marker id="{1000 + k}" body_id="1" pos_x="{k}."/>\n'
                        f'<!-- pad <Fake_Tag/> -->\n' for k in range(n))
    head = '<Force_Vector_TwoBody\n    id="3"\n    bogus="1"/>\n'    # multi-line, below 65535
    tail = ('<![CDATA[ <Not_A_Tag> ]]>\n<Force_Gravity\n   grav_x="TIME*2"\n   bogus="1"/>\n'
            "<?pi <x?>\n<Force_Magic/>")
    data = deck(f"<Model>{model()}\n{head}{markers}\n{tail}</Model>")
    text = data.decode()
    fline = text.count("\n", 0, text.index("<Force_Vector_TwoBody")) + 1
    gline = text.count("\n", 0, text.index("<Force_Gravity\n")) + 1
    mline = text.count("\n", 0, text.index("<Force_Magic")) + 1
    assert fline < 65_535 < gline < mline
    with pytest.raises(DeckError) as ei:
        parse_deck_bytes(data, "big.xml")
    # the vector force misses three required attributes; Force_Magic is unknown
    assert [(p.loc.tag, p.loc.line) for p in ei.value.problems] == (
        [("Force_Vector_TwoBody", fline)] * 3 + [("Force_Magic", mline)])
    spec = parse_deck_bytes(data.replace(b"<Force_Magic/>", b""), "big.xml", check=False)
    g = spec.elements("Force_Gravity")[-1]
    assert g.loc.line == gline and g.get("grav_x").loc.line == gline
    assert spec.by_id("Force_Vector_TwoBody")[3].loc.line == fline
    assert [w.loc.line for w in spec.warnings] == [fline, gline]


def test_schema_table_and_markdown():
    md = render_markdown()
    for tag in SCHEMAS:
        assert f"## `{tag}`" in md
    assert element_schema("Control_Diff").supported is True      # implicit differential equations
    for tag in ("Body_Flexible",):
        assert element_schema(tag).supported is False
    assert element_schema("Force_Contact").supported is True     # contact
    for tag in ("Motion_Joint", "Motion_Marker"):
        assert element_schema(tag).supported is True       # motions
    for tag in ("Post_Request", "Reference_Spline", "Reference_Array", "Reference_Variable"):
        assert element_schema(tag).supported is True       # expressions
    for tag in ("Param_Unit", "UNITS", "Force_Gravity", "Reference_Marker", "Body_Rigid", "Body_Point",
                "Constraint_Joint", "Constraint_Jprim", "Force_SpringDamper", "Force_Bushing",
                "Force_Vector_OneBody", "Force_Vector_TwoBody", "Force_Scalar_TwoBody", "Param_Static",
                "Param_Transient", "Param_Simulation", "Simulate", "Stop", "ResOutput", "DebugOutput",
                "H3DOutput", "Post_Graphic"):
        assert element_schema(tag).supported is True
    assert element_schema("Reference_Marker").attr("i_marker_id") is None
    assert element_schema("Constraint_Joint").attr("i_marker_id").ref == "marker"
    assert element_schema("Body_Rigid").attr("mass").lo == 0
    assert re.search(r"\| `stiffness` \| real \| yes \|", md)


def test_repeated_numbers_of_a_column_share_one_object():
    """A big deck repeats its zeros, ones and ids: typed once per distinct text (memory), the
    values exactly those of float()/int() of each text, in order."""
    from poise.deck.values import ints, reals
    col = ["0.", "1.5", "0.", "-2e3", "0.", "1.5"]
    x = reals(col)
    assert x == [0.0, 1.5, 0.0, -2000.0, 0.0, 1.5]
    assert x[0] is x[2] is x[4] and x[1] is x[5]
    assert reals(["1.0", "abc", "1.0"]) == [1.0, "abc", 1.0]     # non-numbers kept raw
    k = ints(["100001", "7", "100001"])
    assert k == [100001, 7, 100001] and k[0] is k[2]
