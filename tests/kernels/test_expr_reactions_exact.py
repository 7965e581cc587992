"""Reaction-reading expression forces have an exact, complete Newton Jacobian: the coordinate
derivative of every channel at fixed multipliers is in it (ReactionFeed.coupling), so Newton
converges quadratically. A friction-like deck with a closed form (a slider on an inclined
TRANSLATIONAL joint, friction from the joint's normal reaction and the rail's reaction moment),
decks/expr_reaction_load.xml, and channels of families with scalar unknowns (a curve constraint
on a point body, an expression force reading implicit variables) against central differences."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from poise.deck.parser import load_deck
from poise.model.compile import compile_model
from poise.app.runner import run

from support.fd import check_full_jacobian
from support.paths import DECKS


# ------------------------------------------------------------------ friction-like deck
M, G, ALPHA, K, L0, MU, H, S0 = 2.0, 9.81, math.radians(30.0), 200.0, 1.0, 0.3, 0.4, 0.3
ANCHOR = (1.8821, 0.7402)      # ~ 2.0 e - 0.3 n: off the rail line (the load is nonlinear)


def friction_deck(mu=MU, h=H, s0=S0):
    """A 2 kg slider on a TRANSLATIONAL joint along ``e = (cos 30, sin 30, 0)`` through the
    origin (rail marker 101 on ground: x = n = (-sin 30, cos 30, 0), y = +Z, z = e), gravity
    -Y, a spring k = 200 N/m, free length 1 m, from the slider to a ground anchor off the rail
    line, and a friction-like force up the rail (Force_Vector_OneBody, components in the rail's
    axes)  f = mu (|F| + |T_J| / h):  |F| = JOINT(1,0,1,0) the joint's force on the slider, the
    normal reaction; |T_J| = JOINT(1,1,5,0) the rail's reaction moment about the rail marker
    (jflag=1: -T - (P_I - P_J) x F, its lever grows with the slider's travel). SI units."""
    c, s = math.cos(ALPHA), math.sin(ALPHA)
    ax = (f'a00="{-s!r}" a10="{c!r}" a20="0." a01="0." a11="0." a21="1." a02="{c!r}" '
          f'a12="{s!r}" a22="0."')
    at = f'pos_x="{s0 * c!r}" pos_y="{s0 * s!r}" pos_z="0." {ax}'
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<MotionSolve>
  <Model>
    <Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="METER" time_unit="SECOND"/>
    <Param_Static method="FIM_S" max_num_iter="100" max_imbalance="1.0E-10" max_error="1.0E-10"/>
    <Body_Rigid id="1" isground="TRUE" cg_id="100"/>
    <Reference_Marker id="100" body_id="1"/>
    <Reference_Marker id="101" body_id="1" pos_x="0." pos_y="0." pos_z="0." {ax}/>
    <Reference_Marker id="102" body_id="1" pos_x="{ANCHOR[0]!r}" pos_y="{ANCHOR[1]!r}" pos_z="0."/>
    <Body_Rigid id="2" cg_id="200" mass="{M!r}" inertia_xx="0.01" inertia_yy="0.01"
        inertia_zz="0.01" inertia_xy="0." inertia_yz="0." inertia_xz="0."/>
    <Reference_Marker id="200" body_id="2" {at}/>
    <Reference_Marker id="201" body_id="2" {at}/>
    <Constraint_Joint id="1" type="TRANSLATIONAL" i_marker_id="201" j_marker_id="101"/>
    <Force_SpringDamper id="2" type="TRANSLATIONAL" i_marker_id="201" j_marker_id="102"
        stiffness="{K!r}" damping="0." length="{L0!r}"/>
    <Force_Vector_OneBody id="3" type="FORCEONLY" marker_id="201" ref_marker_id="101"
        fx_expression="0." fy_expression="0."
        fz_expression="{mu!r}*(JOINT(1,0,1,0) + JOINT(1,1,5,0)/{h!r})"/>
    <Force_Gravity grav_x="0." grav_y="{-G!r}" grav_z="0."/>
    <Post_Request id="1" type="EXPRESSION" expr1="JOINT(1,0,1,0)" expr2="JOINT(1,1,8,0)"
        expr3="VFORCE(3,0,4,101)" expr4="DM(201,102)" expr5="JOINT(1,0,2,101)"
        expr6="JOINT(1,0,5,0)" expr7="NULL" expr8="NULL"/>
  </Model>
  <Command>
    <Simulate analysis_type="Static"/>
    <Stop/>
  </Command>
</MotionSolve>
"""


def friction_closed_form(mu=MU, h=H):
    """Statics of the slider at ``P = s e`` (every load acts at P, so the reaction torque on the
    slider about P is 0 and the joint force is the normal force ``N n``):
      spring  F_s = -k (L - L0) (P - A) / L,  L = |P - A|;
      along n:  N - m g cos(a) + F_s . n = 0  ->  N = m g cos(a) - F_s . n;
      rail moment about its marker (the origin):  T_J = -(s e) x (N n) = -s N z, |T_J| = s N;
      along e:  F_s . e - m g sin(a) + mu N (1 + s / h) = 0,
    one equation in s (root with N > 0 on the near side of the anchor: s in (0, 1.4)).
    Returns ``(s, N, L, f)``."""
    c, s = math.cos(ALPHA), math.sin(ALPHA)
    e, n = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    A = np.array([ANCHOR[0], ANCHOR[1], 0.0])

    def parts(x):
        d = x * e - A
        L = float(np.linalg.norm(d))
        Fs = -K * (L - L0) * d / L
        return Fs, M * G * c - float(Fs @ n), L

    def g(x):
        Fs, N, _ = parts(x)
        return float(Fs @ e) - M * G * s + mu * N * (1.0 + x / h)
    x = brentq(g, 0.0, 1.4, xtol=1e-15)
    _, N, L = parts(x)
    return x, N, L, mu * N * (1.0 + x / h)


def quadratic_ratios(e, floor):
    """``e_{k+1} / e_k^2`` of the successive imbalances above ``floor`` (round-off)."""
    e = np.asarray(e, float)
    return np.array([b / a ** 2 for a, b in zip(e[:-1], e[1:]) if b > floor])


def test_friction_deck_closed_form_and_quadratic_convergence(tmp_path):
    p = tmp_path / "friction.xml"
    p.write_text(friction_deck())
    res = run(str(p))
    assert not [w for w in res.warnings if "reaction" in w], res.warnings
    ar = res.analyses[0]
    assert ar.status == "converged", ar.message
    d = ar.datasets
    s, N, L, f = friction_closed_form()
    assert 0.5 < s < 1.4 and N > 10.0 and f > 10.0          # the intended branch, real coupling
    c, sn = math.cos(ALPHA), math.sin(ALPHA)
    np.testing.assert_allclose(d["bodies/position"][0, 0], [s * c, s * sn, 0.0], atol=1e-10)
    r = d["requests/values"][0, 0]
    # |F| = N; rail moment TZ on J = -s N; friction read back; spring length; the normal force
    # along the rail's x = n; no reaction torque on the slider about its marker
    np.testing.assert_allclose(r[:6], [N, -s * N, f, L, N, 0.0], rtol=1e-9, atol=1e-9)
    e = np.asarray(d["iterations/imbalance"], float)
    # exact Jacobian: 6 imbalances (5 iterations) where the Jacobian without the channels'
    # coordinate derivative needed 10 at a linear rate ~0.045; quadratic near the solution
    assert len(e) <= 6, e
    q = quadratic_ratios(e, 1e-11)
    assert len(q) >= 3 and q[-2:].max() < 0.02, (e, q)
    assert e[-2] < 1e-7 * e[-3] ** 0.5, e


@pytest.mark.parametrize("mu,h", [(0.3, 0.4), (0.1, 0.2), (0.5, 1.5)])
def test_friction_deck_full_jacobian(tmp_path, mu, h):
    """The friction deck's KKT Jacobian at a perturbed, non-equilibrium state (random
    multipliers) against central differences."""
    p = tmp_path / "friction.xml"
    p.write_text(friction_deck(mu, h))
    m = compile_model(load_deck(str(p)))
    assert not [w for w in m.spec_warnings if "reaction" in str(w)]
    rng = np.random.default_rng(5)
    st = m.retract(m.initial_state(), 0.02 * rng.normal(size=m.nq), 10 * rng.normal(size=m.nc))
    check_full_jacobian(m, st)


# ------------------------------------------------------------------ expr_reaction_load
def test_expr_reaction_load_quadratic_and_exact():
    """decks/expr_reaction_load.xml (the hinge reaction and the spring's torque SPDP() read by
    forces): no warning, quadratic convergence, 6 imbalances (7 with the channels' coordinate
    derivative lagged, rate ~0.004), and the full Jacobian at a perturbed state is exact."""
    res = run(str(DECKS / "expr_reaction_load.xml"))
    assert not [w for w in res.warnings if "reaction" in w], res.warnings
    ar = res.analyses[0]
    assert ar.status == "converged", ar.message
    e = np.asarray(ar.datasets["iterations/imbalance"], float)
    assert len(e) <= 6, e
    q = quadratic_ratios(e, 1e-11)
    assert len(q) >= 2 and q[-2:].max() < 1e-3, (e, q)
    m = compile_model(load_deck(str(DECKS / "expr_reaction_load.xml")))
    rng = np.random.default_rng(0)
    st = m.retract(m.initial_state(), 0.03 * rng.normal(size=m.nq), 10 * rng.normal(size=m.nc))
    check_full_jacobian(m, st)


# ------------------------------------------------------------------ scalar unknowns
VARIANTS = {
    # resultants of a curve constraint (its curve parameter is a scalar unknown) on a point
    # body, at I and at J (flipped), |F|, a component and |T|
    "ptcv": ("elem_ptcv_parabola.xml", "<Constraint_PTCV",
             '<Force_Vector_OneBody id="5" type="FORCEONLY" marker_id="200" ref_marker_id="0" '
             'fx_expression="0.3*FM(200,101,0) + 0.1*FX(200,101,0)" '
             'fy_expression="0.1*FY(101,200,0)" fz_expression="0.02*TM(101,200,0)"/>\n'
             "    <Constraint_PTCV"),
    # a scalar force reading an expression force whose expression reads implicit variables
    # (G_ys of a force family) and the translational joint's moment on J in a moving RM
    "implicit": ("elem_var_implicit.xml", '<Force_Vector_OneBody id="2"',
                 '<Force_Scalar_TwoBody id="3" type="FORCE" i_marker_id="20" j_marker_id="10" '
                 'val_expression="0.1*VFORCE(2,0,2,0) + 0.05*JOINT(1,1,7,21) '
                 '+ 0.02*VFORCE(2,1,1,21)"/>\n    <Force_Vector_OneBody id="2"'),
}


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_channels_of_families_with_scalar_unknowns_full_jacobian(tmp_path, name):
    deck, old, new = VARIANTS[name]
    txt = (DECKS / deck).read_text()
    assert old in txt
    p = tmp_path / "v.xml"
    p.write_text(txt.replace(old, new, 1))
    m = compile_model(load_deck(str(p)))
    feed = m.reaction_feed
    assert any(m.families[g.fi].U for g in feed.groups)      # a contributor with scalars
    rng = np.random.default_rng(0)
    st = m.retract(m.initial_state(), 0.03 * rng.normal(size=m.nq), 3 * rng.normal(size=m.nc))
    check_full_jacobian(m, st)
