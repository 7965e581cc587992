"""The Adams dataset reader (poise.deck.adm): syntax, abbreviations, frames, translation, located
problems, skipped and refused statements, command files."""
from __future__ import annotations

import numpy as np
import pytest

from poise.core.errors import DeckError
from poise.deck.parser import load_deck
from poise.deck.spec import Expr
from poise.model.compile import compile_model

HEAD = """title line: anything at all
UNITS/FORCE = NEWTON, MASS = KILOGRAM, LENGTH = METER, TIME = SECOND
PART/1, GROUND
MARKER/10, PART = 1
"""
BODY = """PART/2, MASS = 2, CM = 20, IP = 1, 1, 1
MARKER/20, PART = 2, QP = 1, 0, 0
MARKER/21, PART = 2
"""


def load(tmp_path, text, name="m.adm", **kw):
    p = tmp_path / name
    p.write_text(text)
    return load_deck(str(p), **kw)


def problems(tmp_path, text, name="m.adm", **kw):
    with pytest.raises(DeckError) as e:
        load(tmp_path, text, name, **kw)
    return [str(p) for p in e.value.problems]


def el(spec, tag, i=None):
    return next(e for e in spec.model if e.tag == tag and (i is None or e.id == i))


def test_syntax_continuations_comments_abbreviations_and_degrees(tmp_path):
    spec = load(tmp_path, HEAD + BODY + """! a comment line
!                 adams_view_name='hinge'
joint/1, rev  ! abbreviated type, lower case
, I = 21
, J = 10
mark/30, part = 2, qp = 2.5D0, 0, 0, reuler = 90D, 0, 0
SFORCE/4, TRANSLATIONAL, I = 30, J = 10, FUNCTION = 10 + STEP(TIME, 0, 0,
, 1, 5) - 2
, * DM(30, 10)
END
PART/99, THIS IS NOT READ
""")
    j = el(spec, "Constraint_Joint", 1)
    assert (j.attrs["type"], j.attrs["i_marker_id"], j.attrs["j_marker_id"]) == ("REVOLUTE", 21, 10)
    assert j.attrs["label"] == "hinge"
    assert j.loc.prefix() == f"{tmp_path / 'm.adm'}:10: JOINT/1:"
    m = el(spec, "Reference_Marker", 30)
    assert m.attrs["pos_x"] == 2.5                       # 2.5D0: a Fortran exponent
    a = np.array([[m.attrs[f"a{r}{c}"] for c in range(3)] for r in range(3)])
    assert np.array_equal(a, [[0, -1, 0], [1, 0, 0], [0, 0, 1]])     # 90D about z, exactly
    f = el(spec, "Force_Scalar_TwoBody", 4)
    assert f.attrs["type"] == "FORCE"                    # TRANSLATIONAL read as TRANSLATION
    expr = f.attrs["val_expression"]
    assert isinstance(expr, Expr) and expr.attr == "FUNCTION"
    assert expr.text == "10 + STEP(TIME, 0, 0, 1, 5) - 2 * DM(30, 10)"
    assert not any(e.id == 99 for e in spec.model)       # after END


def test_an_expression_ends_where_a_keyword_line_begins(tmp_path):
    spec = load(tmp_path, HEAD + BODY + """SFORCE/1, I = 20, J = 10, FUNCTION = 3*DM(20,10)
, ACTIONONLY, TRANSLATION
VFORCE/2, I = 20, JFLOAT = 11, FX = 1\\FY = 2 +
, 3\\FZ = 0
MARKER/11, PART = 1, FLOATING
""")
    f = el(spec, "Force_Scalar_TwoBody", 1)
    assert f.attrs["val_expression"].text == "3*DM(20,10)" and f.attrs["is_action_only"] is True
    v = el(spec, "Force_Vector_OneBody", 2)           # JFLOAT on ground: one body
    assert (v.attrs["fx_expression"], v.attrs["fy_expression"].text, v.attrs["fz_expression"]) \
        == (1.0, "2 + 3", 0.0)
    assert "ref_marker_id" not in v.attrs and v.attrs["marker_id"] == 20
    assert not any(e.tag == "Reference_Marker" and e.id == 11 for e in spec.model)


def test_parts_frames_compose_and_points_orient_markers(tmp_path):
    spec = load(tmp_path, HEAD + """PART/2, QG = 10, 0, 0, REULER = 90D, 0D, 0D, MASS = 1, CM = 20
MARKER/20, PART = 2, QP = 1, 2, 3
MARKER/21, PART = 2, QP = 0, 0, 0, ZP = 1, 0, 0, XP = 0, 0, 1
MARKER/22, PART = 2, QP = 0, 0, 0, XP = 0, 1, 0, ZP = 1, 0, 0, USEXP
PART/3
MARKER/30, PART = 3, QP = 5, 5, 5
""")
    m = el(spec, "Reference_Marker", 20)
    assert (m.attrs["pos_x"], m.attrs["pos_y"], m.attrs["pos_z"]) == (8.0, 1.0, 3.0)

    def axes(i):
        e = el(spec, "Reference_Marker", i)
        return np.array([[e.attrs[f"a{r}{c}"] for c in range(3)] for r in range(3)])

    # marker 21: z along the part's x (global y), x along the part's z (global z)
    assert np.array_equal(axes(21)[:, 2], [0, 1, 0]) and np.array_equal(axes(21)[:, 0], [0, 0, 1])
    # marker 22 (USEXP): x along the part's y (global -x), z along the part's x (global y)
    assert np.array_equal(axes(22)[:, 0], [-1, 0, 0]) and np.array_equal(axes(22)[:, 2], [0, 1, 0])
    # a massless part without CM: a CG marker at its frame, above every marker id
    b = el(spec, "Body_Rigid", 3)
    cg = el(spec, "Reference_Marker", b.attrs["cg_id"])
    assert b.attrs["cg_id"] > 30 and (cg.attrs["pos_x"], cg.attrs["body_id"]) == (0.0, 3)


def test_translations_of_forces_joints_and_data(tmp_path):
    spec = load(tmp_path, HEAD + BODY + """JOINT/1, RACKPIN, I = 21, J = 10, PD = 0.2
JOINT/2, CONVEL, I = 21, J = 10
MOTION/3, JOINT = 2, ROTATION, VELOCITY, ICDISP = 0.5, FUNCTION = 2
SPRINGDAMPER/1, ROTATION, I = 21, J = 10, KT = 5, CT = 1, ANGLE = 0.3, TORQUE = 2
BUSHING/2, I = 20, J = 10, K = 1, 2, 3, KT = 4, 5, 6, FORCE = 7, 8, 9
FIELD/3, I = 20, J = 10, KMATRIX = 1,2,3,4,5,6, 7,8,9,10,11,12, 13,14,15,16,17,18,
, 19,20,21,22,23,24, 25,26,27,28,29,30, 31,32,33,34,35,36
ACCGRAV/KGRAV = -9.81
SPLINE/5, X = 0, 1, 2, Z = 0, 1, Y = 0, 1, 2, 0, 2, 4
ARRAY/6, NUMBERS = 1.5, 2.5
EQUILIBRIUM/ERROR = 1E-7, DYNAMIC, KINETIC_ENERGY_ERROR = 1E-6
""")
    j = el(spec, "Constraint_Joint", 1)
    assert (j.attrs["type"], j.attrs["pitch_diameter"]) == ("RACK_PINION", 0.2)
    assert el(spec, "Constraint_Joint", 2).attrs["type"] == "CONSTANT_VELOCITY"
    mo = el(spec, "Motion_Joint", 3)
    assert (mo.attrs["joint_type"], mo.attrs["val_type"], mo.attrs["ic_disp"]) == ("R", "V", 0.5)
    s = el(spec, "Force_SpringDamper", 1)
    assert (s.attrs["type"], s.attrs["stiffness"], s.attrs["length"], s.attrs["preload"]) == \
        ("ROTATIONAL", 5.0, 0.3, 2.0)
    b = el(spec, "Force_Bushing", 2)
    assert (b.attrs["ky"], b.attrs["ktz"], b.attrs["preload_z"], b.attrs["preload_tx"]) == \
        (2.0, 6.0, 9.0, 0.0)
    f = el(spec, "Force_Field", 3)                     # KMATRIX by columns
    assert (f.attrs["k21"], f.attrs["k12"], f.attrs["k16"]) == (2.0, 7.0, 31.0)
    assert el(spec, "Force_Gravity").attrs["grav_z"] == -9.81
    sp = el(spec, "Reference_Spline", 5)
    assert (sp.attrs["num_x"], sp.attrs["num_z"]) == (3, 2)
    assert [float(x) for x in sp.text.split()] == [0, 1, 0, 0, 0, 1, 1, 2, 2, 2, 4]
    assert [float(x) for x in el(spec, "Reference_Array", 6).text.split()] == [1.5, 2.5]
    p = el(spec, "Param_Static")
    assert (p.attrs["max_error"], p.attrs["method"], p.attrs["max_ke_tol"]) == (1e-7, "MKEAM", 1e-6)
    assert [c.tag for c in spec.commands] == ["Simulate", "Stop"]     # no command file


def test_units_systems_and_ucf(tmp_path):
    spec = load(tmp_path, "t\nUNITS/SYSTEM = IPS\nPART/1, GROUND\n")
    u = el(spec, "Param_Unit")
    assert (u.attrs["force_unit"], u.attrs["mass_unit"], u.attrs["length_unit"]) == \
        ("POUND_FORCE", "POUND_MASS", "INCH")
    spec = load(tmp_path, "t\nUNITS/UCF = 386.088\nPART/1, GROUND\n")
    assert el(spec, "Param_Unit").attrs["mass_mult_factor"] == 1 / 386.088
    assert "FORCE=NEWTONS: unknown unit" in " ".join(
        problems(tmp_path, "t\nUNITS/FORCE = NEWTONS\nPART/1, GROUND\n"))


def test_every_problem_located_at_once_with_did_you_mean(tmp_path):
    probs = problems(tmp_path, HEAD + BODY + """MARKR/5, PART = 2
JOINT/1, REVOLUTE, I = 21, J = 99
JOINT/2, SPHERICAL, I = 21, J = 10, PRAT = 3
MARKER/40, PART = 2, QP = 1, x, 3
JOINT/3, C, I = 21, J = 10
JOINT/1, HOOKE, I = 21, J = 10
, I = 3
CONTACT/7, I = 20
""")
    f = str(tmp_path / "m.adm")
    text = "\n".join(probs)
    assert f"{f}:8: MARKR: unknown statement 'MARKR'; did you mean MARKER?" in probs
    assert f"{f}:9: JOINT/1: J=99: no MARKER/99 in the dataset" in probs
    assert f"{f}:10: JOINT/2: unknown keyword 'PRAT'; expected one of" in text
    assert f"{f}:11: MARKER/40: QP: 'x' is neither a number nor a keyword" in probs
    assert f"{f}:12: JOINT/3: ambiguous option 'C'; it abbreviates CONVEL, CYLINDRICAL" in probs
    assert f"{f}:13: JOINT/1: JOINT/1 is defined twice (also at line 9)" in probs
    assert f"{f}:15: CONTACT/7: poise does not support contact between CAD solids; " \
           "`--ignore CONTACT` solves without it" in text
    assert len(probs) >= 7


def test_refused_physics_left_out_with_ignore_and_recorded(tmp_path):
    text = HEAD + BODY + """JOINT/1, REVOLUTE, I = 21, J = 10
FRICTION/3, JOINT = 1, MU_STATIC = 0.1
SFORCE/4, ROTATION, I = 21, J = 10, FUNCTION = USER(1, 2, 3)
"""
    probs = problems(tmp_path, text)
    assert any("FRICTION/3: poise does not support joint friction" in p for p in probs)
    assert any("SFORCE/4: poise does not support a Fortran/C user subroutine "
               "(FUNCTION=USER(...))" in p for p in probs)
    spec = load(tmp_path, text, ignore=("FRICTION", "USER"))
    assert [(d["kind"], d["statement"], d["line"]) for d in spec.ignored] == \
        [("FRICTION", "FRICTION/3", 9), ("USER", "SFORCE/4", 10)]
    assert not any(e.tag == "Force_Scalar_TwoBody" for e in spec.model)
    assert any("left out (--ignore USER)" in str(w) for w in spec.warnings)


def test_skipped_statements_one_warning_per_kind(tmp_path):
    spec = load(tmp_path, HEAD + BODY + """GRAPHICS/1, CYLINDER, CM = 20, LENGTH = 1, RADIUS = 0.1
GRAPHICS/2, OUTLINE = 20, 21
OUTPUT/REQSAVE
PART/3, MASS = 1, CM = 30, IP = 1, 1, 1, VX = 2, MATERIAL = steel
MARKER/30, PART = 3
""")
    w = [str(x) for x in spec.warnings]
    assert any(":8: GRAPHICS/1: 2 GRAPHICS statements skipped (graphics" in x for x in w)
    assert any("OUTPUT/: 1 OUTPUT statement skipped" in x for x in w)
    assert any("VX ignored in 1 PART statement (no effect on statics)" in x for x in w)


def test_translated_model_compiles(tmp_path):
    spec = load(tmp_path, HEAD + BODY + "JOINT/1, REVOLUTE, I = 21, J = 10\nACCGRAV/JGRAV=-9.81\n")
    m = compile_model(spec)
    assert (m.nq, m.nc) == (6, 5)
    assert np.allclose(m.deck_mass(), [2.0])


ACF_MODEL = HEAD + BODY + """JOINT/1, REVOLUTE, I = 21, J = 10
SPRINGDAMPER/2, ROTATION, I = 21, J = 10, KT = 100, ANGLE = 0
SFORCE/3, ROTATION, I = 21, J = 10, FUNCTION = 1
ACCGRAV/JGRAV = -9.81
"""


def test_command_file_commands(tmp_path):
    (tmp_path / "model.adm").write_text(ACF_MODEL)
    spec = load(tmp_path, """model
out
SIMULATE/STATIC
SFORCE/3, FUNCTION = 2*TIME
SPRINGDAMPER/2, KT = 50
DEACTIVATE/SFORCE, ID = 3
SIMULATE/KINEMATIC, END = 1, STEPS = 4
ACTIVATE/SFORCE, ID = 3
EQUILIBRIUM/IMBALANCE = 1E-9
SIMULATE/STATIC, DURATION = 1, DTOUT = 0.5
STOP
""", "run.acf")
    cmds = [(c.tag, {k: (v.text if isinstance(v, Expr) else v) for k, v in c.attrs.items()})
            for c in spec.commands]
    assert cmds == [
        ("Simulate", {"analysis_type": "STATIC"}),
        ("Force_Scalar_TwoBody", {"id": 3, "val_expression": "2*TIME"}),
        ("Force_SpringDamper", {"id": 2, "stiffness": 50.0}),
        ("Force_Scalar_TwoBody", {"id": 3, "val_expression": 0.0}),
        ("Simulate", {"analysis_type": "STATIC", "end_time": 1.0, "num_steps": 4}),
        ("Force_Scalar_TwoBody", {"id": 3, "val_expression": "2*TIME"}),
        ("Param_Static", {"max_imbalance": 1e-9}),
        ("Simulate", {"analysis_type": "STATIC", "duration": 1.0, "print_interval": 0.5}),
        ("Stop", {})]
    assert spec.input_files == {str(tmp_path / "model.adm"): pytest.approx(spec.input_files[
        str(tmp_path / "model.adm")])}
    assert any("SIMULATE/KINEMATIC is solved as a quasi-static analysis" in str(w)
               for w in spec.warnings)


def test_command_file_problems(tmp_path):
    (tmp_path / "model.adm").write_text(ACF_MODEL)
    probs = problems(tmp_path, """FILE/MODEL = model
SIMULATE/STATIC
DEACTIVATE/JOINT, ID = 1
SIMULATE/TRANSIENT
SFORCE/9, FUNCTION = 3
LINEAR/EIGENSOL
MARKER/20, QP = 1, 1, 1
""", "run.acf")
    f = str(tmp_path / "run.acf")
    assert f"{f}:3: DEACTIVATE/JOINT: deactivating JOINT/1 between analyses would change the " \
           "model's structure (its equations or unknowns), which poise cannot do; expected it " \
           "before the first SIMULATE" in probs
    assert f"{f}:4: SIMULATE/TRANSIENT: SIMULATE/TRANSIENT needs END= or DURATION=" in probs
    assert f"{f}:5: SFORCE/9: no SFORCE/9 in the model to change" in probs
    assert any(p.startswith(f"{f}:6: LINEAR/") and "linear" in p for p in probs)
    assert f"{f}:7: MARKER/20: changing QP of MARKER/20 between analyses would move markers, " \
           "which poise cannot do; expected changes of values such as MASS or IP" in probs
    missing = problems(tmp_path, "nothere\nout\nSIMULATE/STATIC\n", "other.acf")
    assert missing[0].startswith(f"{tmp_path / 'other.acf'}:1: cannot read the model")


def test_binary_input_refused(tmp_path):
    p = tmp_path / "bin.adm"
    p.write_bytes(b"\x00\x01\x02" * 100)
    with pytest.raises(DeckError, match="not an Adams dataset"):
        load_deck(str(p))


def test_docs_name_every_statement_and_command():
    from poise.deck.adm.vocab import ACF, STATEMENTS
    from support.paths import ROOT
    text = (ROOT / "docs" / "adm.md").read_text()
    missing = [n for n in [*STATEMENTS, *ACF] if f"`{n}" not in text and f"**{n}" not in text]
    assert missing == []


def test_request_channels_poise_does_not_compute_are_left_out(tmp_path):
    spec = load(tmp_path, HEAD + BODY + """REQUEST/1, F2 = ORIENT(27, 1, 20, 10)\\F3 = DX(20, 10)
REQUEST/2, F1 = ORIENT(27, 2, 20, 10)
""")
    r = el(spec, "Post_Request", 1)
    assert r.attrs["expr3"].text == "DX(20, 10)" and "expr2" not in r.attrs
    assert not any(e.tag == "Post_Request" and e.id == 2 for e in spec.model)
    w = [str(x) for x in spec.warnings]
    assert any("REQUEST/1: F2 left out: poise does not compute ORIENT (a request is output "
               "only)" in x for x in w)
    assert any("REQUEST/2: F1 left out" in x and "the request is skipped" in x for x in w)


def test_a_name_before_a_commented_out_statement_is_not_the_next_ones(tmp_path):
    """Adams View keeps statements commented out with their ``adams_view_name`` comment above:
    the name is theirs, not the next statement's; an element without a label attribute
    (ACCGRAV -> Force_Gravity) keeps its LABEL= as a comment, without a warning."""
    from poise.app.convert import convert
    text = HEAD + BODY + """!                           adams_view_name='MOTION_3'
!MOTION/3
!, TRANSLATIONAL
!, JOINT = 20
!
ACCGRAV/
, JGRAV = -9.81
!                           adams_view_name='hinge'
!JOINT/7, REVOLUTE, I = 21, J = 10
! the hinge that stays
JOINT/1, REVOLUTE, I = 21, J = 10
EQUILIBRIUM/ERROR = 1E-10, LABEL = tight
"""
    spec = load(tmp_path, text)
    assert "label" not in el(spec, "Force_Gravity").attrs
    assert "label" not in el(spec, "Constraint_Joint", 1).attrs
    assert not [w for w in spec.warnings if "label" in str(w)]
    out = tmp_path / "m.xml"
    convert(str(tmp_path / "m.adm"), str(out))
    xml = out.read_text()
    assert "label 'tight'" in xml and "MOTION_3" not in xml.split("<Force_Gravity")[1][:200]
    assert not [w for w in load_deck(str(out)).warnings if "label" in str(w)]
    assert "adams_view_name='MOTION_3'" in xml.split("<Force_Gravity")[0]    # kept, as written


def test_command_lines_ending_in_ampersand_continue(tmp_path):
    """Adams command files continue a command on the next line after a trailing '&' (with or
    without the comma before it); keywords without effect on statics warn once per kind."""
    (tmp_path / "model.adm").write_text(ACF_MODEL)
    spec = load(tmp_path, """model
out
output/noseparator
integrator/gstiff, &
\terror = 1.0e-4, hmax=1e-5
EQUILIBRIUM/STABILITY=1e-3,   &
            ERROR=1e-2       &
            , MAXIT=50,         &
            ALIMIT=5.0D
simulate/transient, &
\tend=1.0, dtout=0.5
EQUILIBRIUM/ERROR = 1e-3, ALIMIT = 2D
SIMULATE/STATIC
stop
""", "run.acf")
    cmds = [(c.tag, dict(c.attrs)) for c in spec.commands]
    assert cmds == [
        ("Param_Transient", {"integrator_type": "GSTIFF", "integr_tol": 1e-4, "h_max": 1e-5}),
        ("Param_Static", {"stability": 1e-3, "max_error": 1e-2, "max_num_iter": 50}),
        ("Simulate", {"analysis_type": "STATIC", "end_time": 1.0, "print_interval": 0.5}),
        ("Param_Static", {"max_error": 1e-3}),
        ("Simulate", {"analysis_type": "STATIC"}),
        ("Stop", {})]
    assert any("run.acf:6: EQUILIBRIUM/: ALIMIT ignored in 2 EQUILIBRIUM commands" in str(w)
               for w in spec.warnings)
