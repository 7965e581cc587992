"""The expression language against the MotionSolve function reference, for statics.

What statics can use is evaluated: AXU/AYU/AZU (the unwrapped angles: poise's AX/AY/AZ already
count turns), FITSPL (FITPACK's interpolating quadratic B-spline, against scipy's FITPACK),
PINVAL/POUVAL (the variables a plant input/output lists), the element-force functions of the
elements poise has (BEAM, FIELD, PTCV, CVCV: equal to their results datasets). Velocity and
acceleration measures are 0: a static equilibrium is a state at rest (MotionSolve's FIM sets
the velocity and acceleration terms to zero), also in quasi-static runs. Functions poise does
not evaluate are located errors wherever they appear, also in a variable nothing reads.
"""

import numpy as np
import pytest
from scipy.interpolate import splev, splrep

from poise.app.api import run_deck
from poise.core.errors import DeckError
from poise.deck.parser import load_deck
from poise.model.compile import compile_model

from support.paths import DECKS


def _with_request(tmp_path, deck, exprs, extra=""):
    text = (DECKS / deck).read_text()
    attrs = " ".join(f'expr{k + 1}="{e}"' for k, e in enumerate(exprs))
    text = text.replace("</Model>", f'<Post_Request id="99" type="EXPRESSION" {attrs}/>{extra}'
                                    "\n  </Model>")
    p = tmp_path / deck
    p.write_text(text)
    a = run_deck(str(p)).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    k = list(d["requests/id"]).index(99)
    return d, d["requests/values"][-1, k]


@pytest.mark.parametrize("deck,exprs,want", [
    ("elem_beam_cantilever.xml", ["BEAM(2,0,2,0)", "BEAM(2,0,3,0)", "BEAM(2,0,8,0)",
                                  "BEAM(3,1,4,0)"],
     lambda d: [_f(d, "Force_Beam", 2)[0][0], _f(d, "Force_Beam", 2)[0][1],
                _f(d, "Force_Beam", 2)[1][2], None]),
    ("elem_field.xml", ["FIELD(1,0,2,0)", "FIELD(1,0,3,0)", "FIELD(1,0,1,0)", "FIELD(1,0,8,0)"],
     lambda d: [_f(d, "Force_Field", 1)[0][0], _f(d, "Force_Field", 1)[0][1],
                np.linalg.norm(_f(d, "Force_Field", 1)[0]), _f(d, "Force_Field", 1)[1][2]]),
    ("elem_ptcv_parabola.xml", ["PTCV(1,0,2,0)", "PTCV(1,0,3,0)", "PTCV(1,0,5,0)"],
     lambda d: [*d["curves/force"][-1, 0, :2], np.linalg.norm(d["curves/torque"][-1, 0])]),
    ("elem_cvcv_cam.xml", ["CVCV(1,0,2,0)", "CVCV(1,0,3,0)", "CVCV(1,0,8,0)"],
     lambda d: [*d["curves/force"][-1, 0, :2], d["curves/torque"][-1, 0, 2]]),
])
def test_element_force_functions_read_the_element_loads(tmp_path, deck, exprs, want):
    d, v = _with_request(tmp_path, deck, exprs)
    for got, w in zip(v, want(d)):
        if w is not None:
            assert got == pytest.approx(w, rel=1e-12, abs=1e-12 * max(1.0, abs(w)))


def _f(d, tag, id):
    tags = [t.decode() if isinstance(t, bytes) else str(t) for t in d["forces/tag"]]
    k = next(i for i, (t, j) in enumerate(zip(tags, d["forces/id"])) if t == tag and j == id)
    return d["forces/force"][-1, k], d["forces/torque"][-1, k]


def test_beam_j_side_is_the_opposite_load(tmp_path):
    """jflag = 1: the action on J (the equal and opposite force)."""
    d, v = _with_request(tmp_path, "elem_beam_cantilever.xml", ["BEAM(2,1,2,0)", "BEAM(2,0,2,0)"])
    assert v[0] == pytest.approx(-v[1], rel=1e-12)


def test_unwrapped_angles_are_the_continuous_angles(tmp_path):
    """pendulum_multiturn winds 3.14 turns: AZU = AZ = the continuous angle (19.72 rad)."""
    d, v = _with_request(tmp_path, "pendulum_multiturn.xml",
                         ["AZU(201,101)", "AZ(201,101)", "AXU(201,101)", "AX(201,101)",
                          "AYU(201,101)", "AY(201,101)"])
    assert v[0] == pytest.approx(19.72365702162824, abs=1e-8)
    assert v[1] == v[0] and v[2] == v[3] and v[4] == v[5]


SPLINE = ('<Reference_Spline id="8" num_xy_pair="7" linear_extrap="FALSE">0 -220  200 -220  '
          '230 -220  373.224 -110  500 -10  510 -120  600 -133</Reference_Spline>')


def test_fitspl_is_fitpacks_quadratic_interpolating_spline(tmp_path):
    x = np.array([0, 200, 230, 373.224, 500, 510, 600.0])
    y = np.array([-220, -220, -220, -110, -10, -120, -133.0])
    tck = splrep(x, y, k=2, s=0)
    q = 345.6
    d, v = _with_request(tmp_path, "pendulum_multiturn.xml",
                         [f"FITSPL({q},0,8)", f"FITSPL({q},0,8,1)", f"FITSPL({q},0,8,2)",
                          "FITSPL(500,0,8)", "FITSPL(650,0,8)"], SPLINE)
    np.testing.assert_allclose(v[:3], [splev(q, tck, der=n) for n in range(3)], rtol=1e-12)
    assert v[3] == pytest.approx(-10.0, abs=1e-9)                  # interpolates the data
    assert v[4] == pytest.approx(float(splev(650, tck)), rel=1e-12)  # end piece continued


def test_plant_values_are_their_variables(tmp_path):
    extra = ('<Reference_Variable id="5" type="EXPRESSION" expr="DX(202,101)"/>'
             '<Reference_Variable id="6" type="EXPRESSION" expr="2*VARVAL(5)"/>'
             '<Control_PlantInput id="1" num_element="2" variable_id_list="6, 5"/>'
             '<Control_PlantOutput id="3" num_element="1" variable_id_list="5"/>')
    d, v = _with_request(tmp_path, "pendulum_multiturn.xml",
                         ["PINVAL(1,1)", "PINVAL(1,2)", "POUVAL(3,1)", "DX(202,101)"], extra)
    assert v[1] == v[3] and v[2] == v[3] and v[0] == pytest.approx(2 * v[3], rel=1e-15)


def test_velocity_and_acceleration_measures_are_zero_at_rest(tmp_path):
    """Also in a quasi-static run where the mechanism moves with TIME."""
    text = (DECKS / "qs_pendulum_ramp.xml").read_text()
    text = text.replace("</Model>", '<Post_Request id="99" type="EXPRESSION" '
                        'expr1="VX(20)" expr2="WZ(20)" expr3="ACCM(20)" expr4="VR(20,10)"'
                        ' expr5="DIF1(1)"/><Control_Diff id="1" ic="0" expr="DIF(1) - 1"/>'
                        "\n  </Model>")
    p = tmp_path / "qs.xml"
    p.write_text(text)
    a = run_deck(str(p)).analyses[0]
    assert a.converged, a.message
    d = a.datasets
    k = list(d["requests/id"]).index(99)
    assert np.ptp(d["bodies/position"][:, 0, 0]) > 0          # it really moved
    np.testing.assert_array_equal(d["requests/values"][:, k, :5], 0.0)


@pytest.mark.parametrize("expr,msg", [
    ("FOO(1) + 2", "unknown function 'FOO'; did you mean FORCOS?"),
    ("SWEEP(TIME, 1, 0, 1, 1, 2, 0.1)", "SWEEP is a MotionSolve function poise does not evaluate"),
    ("CONTACT(1, 0, 2, 0)", "CONTACT is a MotionSolve function poise does not evaluate"),
    ("DX(4711)", "unknown marker id 4711"),
    ("PINVAL(3, 1)", "unknown Control_PlantInput id 3"),
    ("JOINT(77, 0, 2, 0)", "JOINT: unknown element id 77"),
])
def test_problem_in_a_variable_nothing_reads_is_located(tmp_path, expr, msg):
    text = (DECKS / "pendulum_multiturn.xml").read_text()
    text = text.replace("</Model>", f'<Reference_Variable id="42" expr="{expr}"/>\n  </Model>')
    p = tmp_path / "v.xml"
    p.write_text(text)
    line = 1 + text.split('<Reference_Variable id="42"')[0].count("\n")
    with pytest.raises(DeckError) as e:
        compile_model(load_deck(str(p)))
    assert f"v.xml:{line}: <Reference_Variable id=42> expr col" in str(e.value)
    assert msg in str(e.value)
    assert len(e.value.problems) == 1


def test_problem_in_a_used_variable_is_reported_once(tmp_path):
    text = (DECKS / "pendulum_multiturn.xml").read_text()
    text = text.replace("</Model>", '<Reference_Variable id="42" expr="FOO(1)"/>'
                        '<Post_Request id="1" type="EXPRESSION" expr1="VARVAL(42)"/>\n  </Model>')
    p = tmp_path / "u.xml"
    p.write_text(text)
    with pytest.raises(DeckError) as e:
        compile_model(load_deck(str(p)))
    msgs = [str(x) for x in e.value.problems]
    assert sum("<Reference_Variable id=42>" in m and "FOO" in m for m in msgs) == 1
