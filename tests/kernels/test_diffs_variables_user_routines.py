"""Control_Diff, implicit Reference_Variable, Python user routines.

FD Jacobian checks of every family on random constraint-violating states, and reference decks
(decks/elem_diff*.xml, decks/elem_var*.xml, decks/elem_user*.xml) against closed forms or the
equivalent built-in deck, with FIM_S, MKEAM and FIM_D where the method applies.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from poise.deck.spec import Expr
from poise.core.errors import SourceLoc
from poise.model.compile import compile_model
from poise.app.runner import run

from support.builders import stable_seed
from support.fd import fd_check, perturbed_state, two_body_deck
from support.paths import DECKS


def X(text, tag, id, attr="expr", line=9):
    return Expr(text, SourceLoc("deck.xml", line, tag, id), attr)


def _run(name, method=None):
    res = run(str(DECKS / name), {"method": method} if method else None,
              allow_user_code=name.startswith("elem_user"))   # user routines: opt-in
    ar = res.analyses[0]
    assert ar.status == "converged", ar.message
    return ar


# ============================================================================ Jacobians
@pytest.mark.parametrize("point_b", [False, True])
def test_diff_and_implicit_variable_jacobian(point_b):
    rng = np.random.default_rng(stable_seed("diffvar", point_b))
    d = two_body_deck(rng, point_b)
    d.add("Control_Diff", id=1, ic=0.3,
          expr=X("DX(21,31)*DIF(1) - AZ(21,31) + VARVAL(2)**2 + TIME", "Control_Diff", 1))
    d.add("Control_Diff", id=2, ic=-0.2, is_implicit=True,
          expr=X("DIF1(2) + SIN(DIF(2))*DM(32,11) - DIF(1)", "Control_Diff", 2))
    d.add("Control_Diff", id=3, ic=0.7, is_static_hold=True, expr=X("1 - DIF(3)", "Control_Diff", 3))
    d.add("Reference_Variable", id=2, is_implicit=True, ic=0.4,
          expr=X("EXP(VARVAL(2)) - DY(22,32,11) - DIF(2)*DIF(3)", "Reference_Variable", 2))
    # forces read the scalar unknowns (scalar columns G_ys)
    d.add("Force_Scalar_TwoBody", id=5, type="FORCE", i_marker_id=21, j_marker_id=31,
          val_expression=X("3*DIF(1) - VARVAL(2)*DM(21,31)", "Force_Scalar_TwoBody", 5,
                           "val_expression"))
    d.add("Force_Vector_TwoBody", id=6, type="FORCEANDTORQUE", i_marker_id=22,
          j_floating_marker_id=32, ref_marker_id=21,
          **{f"{c}_expression": X(e, "Force_Vector_TwoBody", 6, f"{c}_expression") for c, e in
             dict(fx="DIF(2)*DX(22,32)", fy="VARVAL(2)", fz="1.5", tx="DIF(1)*DIF(2)",
                  ty="0", tz="DIF(3)*AZ(22)").items()})
    d.add("Constraint_Joint", id=1, type="SPHERICAL", i_marker_id=22, j_marker_id=11)
    m = compile_model(d.spec)
    assert m.n_extra == 3              # y1, y2, v2; Control_Diff 3 is held (a constant)
    st = perturbed_state(m, rng)
    st.extra = st.extra + rng.normal(scale=0.3, size=m.n_extra)
    st.t = 0.4
    fd_check(m, st)


# ============================================================================ reference decks
def test_diff_integrator_static_all_methods():
    """y' = 0.4 - DX, F = 500 y, spring 200 (x - 1): x = 0.4, y = 200 (0.4 - 1) / 500."""
    for method in ("FIM_S", "MKEAM", "FIM_D"):
        d = _run("elem_diff_integrator.xml", method).datasets
        np.testing.assert_allclose(d["bodies/position"][0, 0], [0.4, 0, 0], atol=1e-9)
        np.testing.assert_allclose(d["diffs/value"][0], [-0.24], atol=1e-9)
        np.testing.assert_array_equal(d["diffs/id"], [1])


@pytest.mark.parametrize("method", ["FIM_D", "FIM_S"])
def test_diff_integrator_quasi_static_ramp(method):
    ar = _run("elem_diff_integrator_qs.xml", method)
    d = ar.datasets
    t = np.asarray(d["time"])
    assert len(t) == 11
    x = 0.4 + 0.1 * t
    np.testing.assert_allclose(d["bodies/position"][:, 0, 0], x, atol=1e-7)
    np.testing.assert_allclose(d["diffs/value"][:, 0], 200 * (x - 1) / 500, atol=1e-7)


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM", "FIM_D"])
def test_implicit_variable_and_held_states(method):
    d = _run("elem_var_implicit.xml", method).datasets
    x = -2 + np.sqrt(8.4)
    np.testing.assert_allclose(d["bodies/position"][0, 0], [x, 0, 0], atol=1e-9)
    np.testing.assert_array_equal(d["diffs/id"], [2, 3])
    np.testing.assert_allclose(d["diffs/value"][0], [0.3 * x, 0.5], atol=1e-9)
    np.testing.assert_array_equal(d["variables/id"], [1, 4])
    np.testing.assert_allclose(d["variables/value"][0], [x * x / 2, 0.2], atol=1e-9)


def test_diff_unknown_id_is_located_error(tmp_path):
    src = (DECKS / "elem_diff_integrator.xml").read_text().replace("500*DIF(1)", "500*DIF(7)")
    p = tmp_path / "bad.xml"
    p.write_text(src)
    r = subprocess.run([sys.executable, "-m", "poise_cli", "solve", str(p), "-o",
                        str(tmp_path / "o.h5")], capture_output=True, text=True)
    assert r.returncode == 3, r.stderr
    assert "Control_Diff id 7" in r.stderr and "bad.xml:" in r.stderr


# ============================================================================ user routines
def _user_el(tag, id, fnc, par, **kw):
    # in-memory decks resolve scripts in the current directory (absolute paths are refused)
    return dict(usrsub_param_string=par, usrsub_fnc_name=fnc, interpreter="PYTHON",
                script_name="elem_user_routines.py", **kw)


@pytest.mark.parametrize("point_b", [False, True])
def test_user_routine_jacobians(point_b, monkeypatch):
    """UCOSUB with and without derivatives (FD fallback), SFOSUB, GFOSUB, VARSUB."""
    monkeypatch.chdir(DECKS)
    rng = np.random.default_rng(stable_seed("user", point_b))
    d = two_body_deck(rng, point_b)
    d.add("Constraint_UserConstr", id=1, **_user_el("c", 1, "ucosub_spherical", "USER(22, 11)"))
    d.add("Constraint_Usrconstr", id=2, **_user_el("c", 2, "ucosub_inplane", "USER(32, 21)"))
    d.add("Force_Scalar_TwoBody", id=3, type="FORCE", i_marker_id=21, j_marker_id=31,
          **_user_el("f", 3, "sfosub_spring", "USER(21, 31, 7.0, 0.4)"))
    d.add("Force_Vector_TwoBody", id=4, type="FORCEANDTORQUE", i_marker_id=32,
          j_floating_marker_id=22, ref_marker_id=21,
          **_user_el("f", 4, "gfosub_restraint", "USER(32, 3.0, 2.0)"))
    d.add("Reference_Variable", id=5, type="USERSUB", ic=0.1,
          **_user_el("v", 5, "varsub_distance", "USER(31, 22)"))
    d.add("Force_Scalar_TwoBody", id=6, type="FORCE", i_marker_id=31, j_marker_id=22,
          val_expression=X("-4*(VARVAL(5) - 0.3)", "Force_Scalar_TwoBody", 6, "val_expression"))
    m = compile_model(d.spec, user_code="run")
    assert m.n_extra == 1
    st = perturbed_state(m, rng)
    st.extra = st.extra + 0.2
    # FD Hessians (user inplane) are central differences of FD gradients: looser tolerance
    fd_check(m, st, tol=2e-5)


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])   # FIM_D: static -> FIM_S
def test_user_constraint_equals_builtin_joints(method):
    a = _run("elem_user_constraint.xml", method).datasets
    b = _run("elem_user_constraint_builtin.xml", method).datasets
    np.testing.assert_allclose(a["bodies/position"], b["bodies/position"], atol=1e-9)
    np.testing.assert_allclose(a["bodies/orientation"], b["bodies/orientation"], atol=1e-9)
    np.testing.assert_array_equal(a["userconstrs/id"], [1, 2])
    # reactions on the first marker read (I) = the built-in joint / jprim reactions
    np.testing.assert_allclose(a["userconstrs/force"][0, 0], b["joints/force"][0, 0], atol=1e-7)
    np.testing.assert_allclose(a["userconstrs/force"][0, 1], b["jprims/force"][0, 0], atol=1e-7)
    np.testing.assert_allclose(a["forces/force"], b["forces/force"], atol=1e-7)


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM", "FIM_D"])
def test_user_forces_equal_builtin(method):
    a = _run("elem_user_forces.xml", method).datasets
    b = _run("elem_user_forces_builtin.xml", method).datasets
    np.testing.assert_allclose(a["bodies/position"], b["bodies/position"], atol=1e-8)
    np.testing.assert_allclose(a["bodies/orientation"], b["bodies/orientation"], atol=1e-8)
    # the SFOSUB spring's force output equals Force_SpringDamper's
    np.testing.assert_allclose(a["forces/force"][0, 0], b["forces/force"][0, 0], atol=1e-7)
    dm = np.linalg.norm(a["bodies/position"][0, 0] * 0 + _marker_pos(a, b))
    np.testing.assert_allclose(a["variables/value"][0, 0], dm, atol=1e-9)


def _marker_pos(a, b):
    """DM(22, 12) at the solution: marker 22 = body 2 origin + R (0.3, -0.1, 0.2)."""
    R = np.asarray(a["bodies/orientation"][0, 0])
    p = np.asarray(a["bodies/position"][0, 0])
    return p + R @ np.array([0.3, -0.1, 0.2]) - np.array([0.6, 0.4, 0.2])


def _cli(tmp_path, deck_text, name="d.xml"):
    p = tmp_path / name
    p.write_text(deck_text)
    (tmp_path / "elem_user_routines.py").write_text((DECKS / "elem_user_routines.py").read_text())
    r = subprocess.run([sys.executable, "-m", "poise_cli", "solve", str(p), "-o",
                        str(tmp_path / "o.h5"), "--allow-user-code"], capture_output=True, text=True)
    return r


@pytest.mark.parametrize("fnc,what", [("sfosub_raises", "raised ValueError: spring table"),
                                      ("sfosub_nan", "non-finite value")])
def test_user_function_failure_fails_cleanly(tmp_path, fnc, what):
    src = (DECKS / "elem_user_forces.xml").read_text().replace(
        'usrsub_fnc_name="sfosub_spring"', f'usrsub_fnc_name="{fnc}"')
    r = _cli(tmp_path, src)
    assert r.returncode == 1, r.stderr
    out = r.stdout + r.stderr
    assert what in out and "Force_Scalar_TwoBody id=1" in out and "elem_user_routines.py" in out
    assert (tmp_path / "o.h5").exists()


@pytest.mark.parametrize("edit,what", [
    (('script_name="elem_user_routines.py" interpreter="PYTHON"/>\n    <Force_Vector',
      'script_name="missing.py" interpreter="PYTHON"/>\n    <Force_Vector'), "missing.py not found"),
    (('usrsub_fnc_name="sfosub_spring"', 'usrsub_fnc_name="nope"'), "has no function 'nope'"),
    (('usrsub_fnc_name="sfosub_spring" script_name="elem_user_routines.py" interpreter="PYTHON"',
      'usrsub_dll_name="libspring.so" usrsub_fnc_name="sfosub"'), "DLL user subroutines"),
])
def test_user_routine_deck_errors_exit_3(tmp_path, edit, what):
    src = (DECKS / "elem_user_forces.xml").read_text()
    assert edit[0] in src
    r = _cli(tmp_path, src.replace(edit[0], edit[1]))
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert what in r.stderr and "Force_Scalar_TwoBody id=1" in r.stderr and "d.xml:" in r.stderr


def test_user_param_string():
    from poise.core.user_routines import parse_par
    assert parse_par("USER(1, 2.5,-3e-1)") == (1.0, 2.5, -0.3)
    assert parse_par("user( 4 5 )") == (4.0, 5.0)
    assert parse_par(None) == ()
