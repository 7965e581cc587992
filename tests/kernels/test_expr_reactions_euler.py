"""Element-force functions inside forces (reaction channels evaluated inside
Model.evaluate, closed-form equilibrium), MOTION() channels, PSI/THETA/PHI at gimbal lock
against a constructive 3-1-3 decomposition."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from poise.core.errors import DeckError
from poise.expr.measures import eval_measure
from poise.app.runner import run

from support.expr import Rx, Rz
from support.paths import DECKS


def _solve(path):
    ar = run(str(path)).analyses[0]
    assert ar.status == "converged", ar.message
    return ar.datasets


# ---------------------------------------------------------------- reactions inside forces
def test_reaction_dependent_load_closed_form_and_convergence():
    W, kt, ell, a = 3.0 * 9.81, 4000.0, 200.0, 100.0
    fx, fy = 20.0 / 0.9, -0.25 * W          # fixed point of fx = 20 + 0.1 fx, fy = -0.2(W - fy)
    th = brentq(lambda t: -1.01 * kt * t + ell * math.cos(t) * fy - ell * math.sin(t) * fx
                - a * W * math.cos(t), -1.5, 0.0, xtol=1e-15)
    d = _solve(DECKS / "expr_reaction_load.xml")
    c, s = math.cos(th), math.sin(th)
    np.testing.assert_allclose(d["bodies/position"][0, 0], [100 * c, 100 * s, 0.0], atol=1e-8)
    r = d["requests/values"][0, 0]
    np.testing.assert_allclose(r[:5], [-fx, W - fy, fx, fy, th], atol=1e-8)
    np.testing.assert_allclose(r[5], -kt * th, rtol=1e-8)    # spring torque read by SPDP()
    e = np.asarray(d["iterations/imbalance"], float)
    # exact Jacobian through the channels, d/d(lambda) (without it: ~18 iterations at rate
    # 0.2) and d/dq at fixed multipliers (the SPDP channel's angle dependence; without it: 7
    # imbalances at rate ~0.004): quadratic, 6 imbalances
    assert len(e) <= 6, e
    e = e[e > 1e-11]
    assert e[-1] <= 1e-3 * e[-2] ** 2, e


def test_reaction_feed_jacobian_columns_exact():
    """KKT Jacobian columns w.r.t. the multipliers and the coordinates vs central differences
    (jflag=1, |F|, torque, moving RM channels): exact."""
    from poise.deck.parser import load_deck
    from poise.model.compile import compile_model
    txt = (DECKS / "expr_reaction_load.xml").read_text().replace(
        'fx_expression="20 - 0.1*JOINT(1,0,2,0)"',
        'fx_expression="20 - 0.1*JOINT(1,1,2,202) + 0.05*JOINT(1,0,1,0) - 0.01*JOINT(1,1,8,0)"')
    import tempfile
    with tempfile.TemporaryDirectory() as td:
        p = Path(td) / "v.xml"
        p.write_text(txt)
        m = compile_model(load_deck(str(p)))
    rng = np.random.default_rng(0)
    st = m.retract(m.initial_state(), 0.03 * rng.normal(size=m.nq), 10 * rng.normal(size=m.nc))
    J = m.evaluate(st).J
    J = np.asarray(J.todense() if hasattr(J, "todense") else J)
    h = 1e-6
    for k in range(m.N):
        dq, dl = np.zeros(m.nq), np.zeros(m.nc)
        if k < m.nq:
            dq[k] = h
        else:
            dl[k - m.nq] = h
        a = m.evaluate(m.retract(st, dq, dl), need_jac=False)
        b = m.evaluate(m.retract(st, -dq, -dl), need_jac=False)
        fd = (np.r_[a.r, a.phi] - np.r_[b.r, b.phi]) / (2 * h)
        np.testing.assert_allclose(J[:, k], fd, atol=1e-6 * max(1.0, np.abs(J).max() * 1e-3))


def _write_variant(tmp_path, fx):
    txt = (DECKS / "expr_reaction_load.xml").read_text()
    txt = txt.replace('fx_expression="20 - 0.1*JOINT(1,0,2,0)"', f'fx_expression="{fx}"')
    p = tmp_path / "variant.xml"
    p.write_text(txt)
    return p


@pytest.mark.parametrize("fx,msg", [
    ("VFORCE(3,0,2,0)", r"<Force_Vector_OneBody id=3> fx_expression: reads the element force "
                        r"of <Force_Vector_OneBody id=3>"),
    ("FX(202,0,0)", r"fx_expression: reads the element force of a resultant"),
])
def test_cyclic_reaction_read_is_located_deck_error(tmp_path, fx, msg):
    with pytest.raises(DeckError, match=msg):
        run(str(_write_variant(tmp_path, fx)))


def test_gravity_still_rejects_reactions(tmp_path):
    txt = (DECKS / "expr_reaction_load.xml").read_text().replace(
        'grav_y="-9810."', 'grav_y="-9810.+0*JOINT(1,0,2,0)"')
    p = tmp_path / "g.xml"
    p.write_text(txt)
    with pytest.raises(DeckError, match="not supported in gravity"):
        run(str(p))


# ---------------------------------------------------------------- MOTION()
def test_motion_channels_match_motion_torque():
    d = _solve(DECKS / "qs_slider_crank_11b.xml")
    v = d["requests/values"][:, 0]
    tq = d["motions/torque"][:, 0]
    assert v.shape[0] == tq.shape[0] >= 10
    assert np.abs(tq).max() > 100.0
    np.testing.assert_allclose(v[:, 1:4], tq, rtol=1e-12, atol=1e-9)


# ---------------------------------------------------------------- Euler angles at lock
def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def _rand_rot(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 2] *= -1
    return q


def _euler(AI, AJ):
    out = []
    for name, cols in (("PSI", ((0, 2), (1, 1), (1, 0), (0, 0))),
                       ("THETA", ((0, 2), (1, 0), (1, 1), (1, 2))),
                       ("PHI", ((1, 2), (0, 1), (0, 0)))):
        vecs = [((AI, AJ)[w][:, k])[None, :] for w, k in cols]
        v, g = eval_measure(name, vecs)
        out.append((float(v[0]), [gg[0] for gg in g], cols))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_euler_313_random_and_locked(seed):
    rng = np.random.default_rng(100 + seed)
    AJ = _rand_rot(rng)
    psi, phi = rng.uniform(-math.pi, math.pi, 2)
    th = rng.uniform(0.05, math.pi - 0.05)
    # generic orientation: the constructed angles come back
    (p, _, _), (t, _, _), (f, _, _) = _euler(AJ @ Rz(psi) @ Rx(th) @ Rz(phi), AJ)
    np.testing.assert_allclose([_wrap(p - psi), t - th, _wrap(f - phi)], 0.0, atol=1e-10)
    # locked at theta = 0 (planar rotation): phi = 0, psi = psi + phi
    (p, gp, cp), (t, _, _), (f, gf, _) = _euler(AJ @ Rz(psi) @ Rz(phi), AJ)
    assert abs(_wrap(p - (psi + phi))) < 1e-12 and abs(t) < 1e-7 and f == 0.0
    assert all(not np.any(g) for g in gf)
    # lock branch derivative: rotating I about z_J by h changes psi by h
    w = AJ[:, 2]
    dpsi = sum(g @ np.cross(w, ((AJ @ Rz(psi + phi), AJ)[m][:, k]))
               for g, (m, k) in zip(gp, cp) if m == 0)
    assert abs(dpsi - 1.0) < 1e-12
    dpsi_j = sum(g @ np.cross(w, ((AJ @ Rz(psi + phi), AJ)[m][:, k]))
                 for g, (m, k) in zip(gp, cp) if m == 1)
    assert abs(dpsi_j + 1.0) < 1e-12
    # locked at theta = pi: R = Rz(psi) Rx(pi) Rz(phi) = Rz(psi - phi) Rx(pi)
    (p, _, _), (t, _, _), (f, _, _) = _euler(AJ @ Rz(psi) @ Rx(math.pi) @ Rz(phi), AJ)
    assert abs(_wrap(p - (psi - phi))) < 1e-12 and abs(t - math.pi) < 1e-7 and f == 0.0


def test_euler_fd_derivative_away_from_lock():
    rng = np.random.default_rng(7)
    for _ in range(5):
        AI, AJ = _rand_rot(rng), _rand_rot(rng)
        for k, (_v0, g, cols) in enumerate(_euler(AI, AJ)):
            for slot, (m, c) in enumerate(cols):
                for comp in range(3):
                    vals = []
                    for h in (1e-7, -1e-7):
                        M = [AI.copy(), AJ.copy()]
                        M[m][comp, c] += h
                        vals.append(_euler(*M)[k][0])
                    fd = (vals[0] - vals[1]) / 2e-7
                    assert abs(fd - g[slot][comp]) < 1e-6, (k, slot, comp)


def test_planar_deck_psi_not_pi():
    """Every planar rotation is a gimbal lock: PSI equals the rotation angle, PHI = 0."""
    th = math.pi / 5
    AJ = np.eye(3)
    (p, _, _), (t, _, _), (f, _, _) = _euler(Rz(th), AJ)
    assert abs(p - th) < 1e-14 and t == 0.0 and f == 0.0
    (p, _, _), _, _ = _euler(np.eye(3), AJ)
    assert p == 0.0
