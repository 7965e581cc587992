"""Example decks vs. independent reference solutions.

Three groups of tests:

1. ``test_reference_*`` check the reference computations in ``tests/support/reference.py`` on their own
   (catenary closed form vs. constrained minimisation, residuals, stability, uniqueness). They do not
   need poise.
2. ``test_deck_*`` parse every deck with lxml (not with poise) and check the geometry: orthonormal
   right-handed markers, existing bodies/markers, joint origins coincident in the input
   configuration, axis conditions per joint type, the constraint-Jacobian rank (DOF and number of
   redundant equations as documented), and that the deck carries the reference's parameters.
3. ``test_solve_*`` run the solver through the public CLI (``poise solve deck -o out.h5 --json``)
   as a subprocess and compare the HDF5 results with the reference: positions to 1e-6 x model size,
   orientations to 1e-6, reactions to 1e-6 x force scale.
"""
from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from support import reference as R
from support.paths import DECKS


DECK_NAMES = ["pendulum_multiturn", "fourbar_spring", "slider_crank_load", "double_pendulum",
              "bushing_block", "chain_10", "chain_10_spherical"]
REL = 1e-6


def _load_gen_chain():
    spec = importlib.util.spec_from_file_location("gen_chain", DECKS / "gen_chain.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


gen_chain = _load_gen_chain()


# =============================================================================================
# lxml deck reader (independent of poise)
# =============================================================================================
class Deck:
    def __init__(self, path):
        self.path = Path(path)
        self.tree = etree.parse(str(path))
        self.root = self.tree.getroot()
        model = self.root.find("Model")
        assert model is not None, "no <Model>"
        self.model = model
        self.bodies = {int(e.get("id")): e for e in model.iter("Body_Rigid")}
        self.markers = {}
        for e in model.iter("Reference_Marker"):
            mid = int(e.get("id"))
            assert mid not in self.markers, f"duplicate marker {mid}"
            pos = np.array([float(e.get(k)) for k in ("pos_x", "pos_y", "pos_z")])
            A = np.array([[float(e.get(f"a{r}{c}")) for c in range(3)] for r in range(3)])
            self.markers[mid] = dict(body=int(e.get("body_id")), pos=pos, A=A, el=e)
        self.joints = {int(e.get("id")): e for e in model.iter("Constraint_Joint")}

    def elements(self, tag):
        return list(self.model.iter(tag))

    def one(self, tag, **match):
        for e in self.model.iter(tag):
            if all(e.get(k) == v for k, v in match.items()):
                return e
        raise KeyError((tag, match))

    def ground_id(self):
        g = [i for i, b in self.bodies.items() if (b.get("isground") or "").upper() == "TRUE"]
        assert len(g) == 1
        return g[0]

    def cg(self, body_id):
        return self.markers[int(self.bodies[body_id].get("cg_id"))]


def deck(name) -> Deck:
    return Deck(DECKS / f"{name}.xml")


# ---------------------------------------------------------------------------------------------
# constraint equations (working definitions of deck_format.md 3.1), used for the rank check
# ---------------------------------------------------------------------------------------------
def _skew(w):
    return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def _expm(w):
    t = np.linalg.norm(w)
    if t < 1e-300:
        return np.eye(3)
    K = _skew(w / t)
    return np.eye(3) + math.sin(t) * K + (1 - math.cos(t)) * K @ K


def joint_residuals(dk: Deck, q):
    """Constraint residuals of all joints; q = per moving body (dx, dy, dz, rx, ry, rz) applied
    about the body's CG in global axes to the input configuration."""
    moving = [b for b in sorted(dk.bodies) if b != dk.ground_id()]
    idx = {b: i for i, b in enumerate(moving)}

    def marker_now(mid):
        m = dk.markers[mid]
        b = m["body"]
        if b not in idx:
            return m["pos"], m["A"]
        d = q[6 * idx[b]: 6 * idx[b] + 3]
        Rw = _expm(q[6 * idx[b] + 3: 6 * idx[b] + 6])
        c = dk.cg(b)["pos"]
        return c + d + Rw @ (m["pos"] - c), Rw @ m["A"]

    res = []
    for j in dk.joints.values():
        pi, Ai = marker_now(int(j.get("i_marker_id")))
        pj, Aj = marker_now(int(j.get("j_marker_id")))
        d = pi - pj
        xi, yi, zi = Ai.T
        xj, yj, zj = Aj.T
        t = j.get("type").upper()
        if t == "SPHERICAL":
            res += list(d)
        elif t == "REVOLUTE":
            res += list(d) + [zi @ xj, zi @ yj]
        elif t == "UNIVERSAL":
            res += list(d) + [zi @ zj]
        elif t == "TRANSLATIONAL":
            res += [d @ xj, d @ yj, zi @ xj, zi @ yj, xi @ yj]
        elif t == "FIXED":
            res += list(d) + [zi @ xj, zi @ yj, xi @ yj]
        else:
            raise NotImplementedError(t)
    return np.array(res), 6 * len(moving)


def dof_and_redundancy(dk: Deck):
    r0, n = joint_residuals(dk, np.zeros(6 * (len(dk.bodies) - 1)))
    h = 1e-7
    J = np.empty((len(r0), n))
    for k in range(n):
        e = np.zeros(n)
        e[k] = h
        J[:, k] = (joint_residuals(dk, e)[0] - joint_residuals(dk, -e)[0]) / (2 * h)
    s = np.linalg.svd(J, compute_uv=False)
    rank = int(np.sum(s > 1e-6 * s[0])) if len(s) else 0
    return n - rank, len(r0) - rank, r0


# =============================================================================================
# 1. reference self-checks (no solver)
# =============================================================================================
@pytest.mark.parametrize("n", [5, 6])
def test_reference_catenary_matches_minimisation(n):
    a, m, span = 100.0, 1.0, 0.8 * n * 100.0
    theta, H = R.catenary_angles(n, a, m, span)
    res = R.catenary_by_minimisation(n, a, m, span)
    assert res.success, res.message
    # minimisation uses phi = direction ccw from +X; closed form uses theta = descent angle
    np.testing.assert_allclose(-res.x, theta, atol=1e-6)
    cat = R.catenary(n, a, m, span)
    assert cat["closure_error"] < 1e-9 * span
    # link-by-link statics with the closed-form pin forces: every link in equilibrium
    w = R.weight(m)
    for k in range(1, n + 1):
        f_left = np.array([-H, n * w / 2 - (k - 1) * w])      # on link k at its start pin
        f_right = np.array([H, (k * w) - n * w / 2])            # on link k at its end pin
        assert np.allclose(f_left + f_right + [0, -w], 0, atol=1e-9 * n * w)
        r_end = cat["nodes"][k, :2] - cat["cg"][k - 1, :2]
        r_start = cat["nodes"][k - 1, :2] - cat["cg"][k - 1, :2]
        mom = R._cross2(r_start, f_left) + R._cross2(r_end, f_right)
        assert abs(mom) < 1e-9 * n * w * a


def test_reference_pendulum():
    p = R.PENDULUM_PARAMS
    ref = R.pendulum_multiturn()
    wl = R.weight(p["mass"]) * p["l_cg"]
    assert p["k"] > wl                                   # unique equilibrium
    assert ref["turns"] > 3.0                            # it really winds several turns
    t = ref["theta"]
    assert abs(-p["k"] * (t - p["ref_angle"]) - wl * math.cos(t)) < 1e-9 * p["k"]
    # moment about the hinge from gravity at the CG + spring = 0
    g_mom = R._cross2(ref["cg"], [0.0, -R.weight(p["mass"])])
    assert abs(g_mom + ref["spring_torque"]) < 1e-9 * wl


def test_reference_fourbar():
    p = R.FOURBAR_PARAMS
    eq = R.fourbar_equilibrium()
    assert len(eq["minima"]) == 1
    P = eq["points"]
    for (u, v), L in {("A", "B"): p["a"], ("B", "C"): p["b"], ("D", "C"): p["c"]}.items():
        assert abs(np.linalg.norm(P[u] - P[v]) - L) < 1e-9 * L
    assert abs(R.fourbar_dV(eq["phi"])) < 1e-8
    h = 1e-5
    assert (R.fourbar_dV(eq["phi"] + h) - R.fourbar_dV(eq["phi"] - h)) / (2 * h) > 0   # stable
    # complex-step derivative agrees with a finite difference of the potential
    x = eq["phi"] + 0.3
    fd = (np.real(R.fourbar_potential(x + 1e-6)) - np.real(R.fourbar_potential(x - 1e-6))) / 2e-6
    assert abs(fd - R.fourbar_dV(x)) < 1e-5 * max(1.0, abs(fd))
    # no other stationary point between the input configuration and the equilibrium
    inp = R.fourbar_input()
    ph = np.linspace(eq["phi"], inp["phi"], 400)[1:]
    g = np.array([R.fourbar_dV(v) for v in ph])
    assert np.all(g > 0)


def test_reference_slider_crank():
    p = R.SLIDER_CRANK_PARAMS
    sc = R.slider_crank()
    assert abs(R.slider_crank_dV(sc["phi"])) < 1e-8
    assert abs(sc["moment_residual"]) < 1e-7            # statics agrees with virtual work
    h = 1e-5
    assert (R.slider_crank_dV(sc["phi"] + h) - R.slider_crank_dV(sc["phi"] - h)) / (2 * h) > 0
    # virtual work with a finite difference of positions (independent of the analytic dV)

    def V(phi):
        _, A, B = R.slider_crank_points(phi)
        return (R.weight(p["m_crank"]) * A[1] / 2 + R.weight(p["m_rod"]) * (A[1] + B[1]) / 2
                - p["fx"] * B[0] + 0.5 * p["k"] * (phi - p["phi0"] - p["ref_angle"]) ** 2)

    x = sc["phi"] - 0.2
    assert abs((V(x + 1e-6) - V(x - 1e-6)) / 2e-6 - R.slider_crank_dV(x)) < 1e-4
    assert abs(np.linalg.norm(sc["points"]["A"] - sc["points"]["B"]) - p["l"]) < 1e-9
    # rod and slider force balance
    wr = R.weight(p["m_rod"])
    assert np.allclose(sc["crankpin_force_on_rod"] + sc["wristpin_force_on_rod"] + [0, -wr, 0], 0,
                       atol=1e-9)


def test_reference_double_pendulum():
    p = R.DOUBLE_PENDULUM_PARAMS
    dp = R.double_pendulum()
    assert np.allclose(dp["grad"], 0, atol=1e-7)
    assert np.all(np.linalg.eigvalsh(0.5 * (dp["hessian"] + dp["hessian"].T)) > 0)
    np.testing.assert_allclose(dp["theta"], dp["minimise_theta"], atol=1e-6)
    # analytic gradient vs finite differences of the potential
    x = dp["theta"] + np.array([0.1, -0.2])
    h = 1e-6
    fd = [(R.double_pendulum_potential(x + h * e) - R.double_pendulum_potential(x - h * e)) / (2 * h)
          for e in np.eye(2)]
    np.testing.assert_allclose(fd, R.double_pendulum_grad(x), rtol=1e-6, atol=1e-4)
    # link 2 moment about the elbow: spring 2 + gravity + tip load = 0 (statics cross-check)
    t1, t2 = dp["theta"]
    E, T = dp["points"]["elbow"], dp["points"]["tip"]
    spring2 = -p["k2"] * (t2 - t1 - p["ref2"])
    mom = (spring2 + R._cross2(dp["cg"]["link2"] - E, [0, -R.weight(p["m2"])])
           + R._cross2(T - E, p["tip_force"]))
    assert abs(mom) < 1e-6


def test_reference_bushing_6d():
    """Solve the full 6-D bushing equilibrium independently (rotation vector unknowns, small-angle
    AX/AY/AZ taken as the rotation-vector components, which is exact here because the answer is a
    pure z rotation) and compare with the closed form."""
    from scipy import optimize
    p = R.BUSHING_PARAMS
    ref = R.bushing_block()
    K = np.array([p["kx"], p["ky"], p["kz"]])
    Kt = np.array([p["ktx"], p["kty"], p["ktz"]])
    pre = np.array([0.0, p["preload_y"], 0.0])
    W = np.array([0.0, -R.weight(p["mass"]), 0.0])
    P = np.array(p["load"])
    e = np.array(p["offset"])

    def resid(x):
        d, rv = x[:3], x[3:]
        Rm = _expm(rv)
        F = -K * d + pre + W + P
        T = -Kt * rv + np.cross(Rm @ e, P)
        return np.concatenate([F, T / 100.0])

    sol = optimize.root(resid, np.zeros(6), tol=1e-13)
    assert np.abs(resid(sol.x)).max() < 1e-9, sol.message
    np.testing.assert_allclose(sol.x[:3], ref["displacement"], atol=1e-12)
    np.testing.assert_allclose(sol.x[3:], [0, 0, ref["theta"]], atol=1e-12)


def test_reference_chain_arc_is_generator_arc():
    for n, span in [(5, 400.0), (10, 800.0), (7, 150.0)]:
        a = R.chain_arc(n, 100.0, span)
        b = np.array(gen_chain.arc_nodes(n, 100.0, span))
        np.testing.assert_allclose(a[:, :2], b, atol=1e-9)
        assert np.allclose(np.linalg.norm(np.diff(a, axis=0), axis=1), 100.0, atol=1e-9)


# =============================================================================================
# 2. deck geometry and parameters (lxml, no solver)
# =============================================================================================
EXPECTED_DOF = {  # name -> (dof, redundant equations)
    "pendulum_multiturn": (1, 0), "fourbar_spring": (1, 3), "slider_crank_load": (1, 0),
    "double_pendulum": (2, 0), "bushing_block": (6, 0), "chain_10": (8, 3),
    "chain_10_spherical": (27, 0),
}


@pytest.mark.parametrize("name", DECK_NAMES)
def test_deck_geometry(name):
    dk = deck(name)
    root = dk.root
    assert root.tag == "MotionSolve"
    cmd = root.find("Command")
    assert [c.tag for c in cmd if isinstance(c.tag, str)] == ["Simulate", "Stop"]
    assert cmd.find("Simulate").get("analysis_type") == "Static"
    u = dk.one("Param_Unit")
    assert (u.get("force_unit"), u.get("mass_unit"), u.get("length_unit"), u.get("time_unit")) == \
        ("NEWTON", "KILOGRAM", "MILLIMETER", "SECOND")
    g = dk.one("Force_Gravity")
    assert [float(g.get(k)) for k in ("grav_x", "grav_y", "grav_z")] == [0.0, -9810.0, 0.0]
    assert dk.one("Param_Static").get("method") == "FIM_S"
    dk.ground_id()
    scale = max(1.0, max(np.abs(m["pos"]).max() for m in dk.markers.values()))
    for mid, m in dk.markers.items():
        assert m["body"] in dk.bodies, f"marker {mid}: body {m['body']} missing"
        A = m["A"]
        assert np.allclose(A.T @ A, np.eye(3), atol=1e-12), f"marker {mid} not orthonormal"
        assert abs(np.linalg.det(A) - 1) < 1e-12, f"marker {mid} left-handed"
    for bid, b in dk.bodies.items():
        assert int(b.get("cg_id")) in dk.markers
        assert dk.markers[int(b.get("cg_id"))]["body"] == bid
        if (b.get("isground") or "").upper() != "TRUE":
            assert float(b.get("mass")) > 0
    ids = set()
    for jid, j in dk.joints.items():
        mi, mj = dk.markers[int(j.get("i_marker_id"))], dk.markers[int(j.get("j_marker_id"))]
        assert mi["body"] != mj["body"], f"joint {jid} connects a body to itself"
        ids.add(jid)
        t = j.get("type").upper()
        d = mi["pos"] - mj["pos"]
        zi, zj = mi["A"][:, 2], mj["A"][:, 2]
        if t in ("REVOLUTE", "SPHERICAL", "UNIVERSAL", "FIXED"):
            assert np.linalg.norm(d) < 1e-12 * scale, f"joint {jid}: origins differ by {d}"
        if t == "REVOLUTE":
            assert zi @ zj > 1 - 1e-14, f"joint {jid}: revolute z axes not aligned"
        if t == "UNIVERSAL":
            assert abs(zi @ zj) < 1e-14
        if t == "TRANSLATIONAL":
            assert zi @ zj > 1 - 1e-14
            assert abs(mi["A"][:, 0] @ mj["A"][:, 1]) < 1e-14
            assert abs(d @ mj["A"][:, 0]) < 1e-12 * scale and abs(d @ mj["A"][:, 1]) < 1e-12 * scale
    for s in dk.elements("Force_SpringDamper"):
        mi, mj = dk.markers[int(s.get("i_marker_id"))], dk.markers[int(s.get("j_marker_id"))]
        if s.get("type") == "ROTATIONAL":
            assert mi["A"][:, 2] @ mj["A"][:, 2] > 1 - 1e-14
        assert float(s.get("stiffness")) > 0
    for f in dk.elements("Force_Vector_OneBody"):
        assert int(f.get("marker_id")) in dk.markers
        assert dk.markers[int(f.get("ref_marker_id"))]["body"] == dk.ground_id()
        assert np.allclose(dk.markers[int(f.get("ref_marker_id"))]["A"], np.eye(3))
    for f in dk.elements("Force_Bushing"):
        assert int(f.get("i_marker_id")) in dk.markers and int(f.get("j_marker_id")) in dk.markers
    # constraint Jacobian rank: documented DOF and redundancy, and residuals zero at input
    dof, red, r0 = dof_and_redundancy(dk)
    assert np.abs(r0).max(initial=0.0) < 1e-12 * scale
    assert (dof, red) == EXPECTED_DOF[name]


def test_deck_parameters_match_reference():
    # pendulum
    dk = deck("pendulum_multiturn")
    p = R.PENDULUM_PARAMS
    s = dk.one("Force_SpringDamper", type="ROTATIONAL")
    assert float(s.get("stiffness")) == p["k"] and float(s.get("length")) == p["ref_angle"]
    assert float(dk.bodies[2].get("mass")) == p["mass"]
    assert np.allclose(dk.cg(2)["pos"], [p["l_cg"], 0, 0])
    assert dk.markers[int(s.get("i_marker_id"))]["body"] == 2
    # fourbar: input configuration = reference input configuration
    dk = deck("fourbar_spring")
    p = R.FOURBAR_PARAMS
    inp = R.fourbar_input()
    for bid, name, mass in [(2, "crank", "m_crank"), (3, "coupler", "m_coupler"), (4, "rocker", "m_rocker")]:
        assert float(dk.bodies[bid].get("mass")) == p[mass]
        np.testing.assert_allclose(dk.cg(bid)["pos"], inp["cg"][name], atol=1e-9)
        np.testing.assert_allclose(dk.cg(bid)["A"], inp["orientation"][name], atol=1e-12)
    s = dk.one("Force_SpringDamper")
    assert float(s.get("stiffness")) == p["k"] and float(s.get("length")) == p["free_length"]
    mi, mj = dk.markers[int(s.get("i_marker_id"))], dk.markers[int(s.get("j_marker_id"))]
    assert mi["body"] == 4 and mj["body"] == 1
    np.testing.assert_allclose(mi["pos"], inp["points"]["C"], atol=1e-9)
    np.testing.assert_allclose(mj["pos"], inp["points"]["A"], atol=1e-12)
    # slider crank
    dk = deck("slider_crank_load")
    p = R.SLIDER_CRANK_PARAMS
    s = dk.one("Force_SpringDamper")
    assert float(s.get("stiffness")) == p["k"] and float(s.get("length")) == p["ref_angle"]
    assert np.allclose(dk.markers[int(s.get("i_marker_id"))]["A"], np.eye(3))   # AZ = phi - phi0
    f = dk.one("Force_Vector_OneBody")
    assert float(f.get("fx_expression")) == p["fx"]
    assert dk.markers[int(f.get("marker_id"))]["body"] == 4
    _, A, B = R.slider_crank_points(p["phi0"])
    np.testing.assert_allclose(dk.cg(3)["pos"][:2], (A + B) / 2, atol=1e-9)
    for bid, key in [(2, "m_crank"), (3, "m_rod"), (4, "m_slider")]:
        assert float(dk.bodies[bid].get("mass")) == p[key]
    # double pendulum
    dk = deck("double_pendulum")
    p = R.DOUBLE_PENDULUM_PARAMS
    s1, s2 = dk.elements("Force_SpringDamper")
    assert (float(s1.get("stiffness")), float(s1.get("length"))) == (p["k1"], p["ref1"])
    assert (float(s2.get("stiffness")), float(s2.get("length"))) == (p["k2"], p["ref2"])
    f = dk.one("Force_Vector_OneBody")
    assert tuple(float(f.get(k)) for k in ("fx_expression", "fy_expression", "fz_expression")) == p["tip_force"]
    np.testing.assert_allclose(dk.markers[int(f.get("marker_id"))]["pos"][:2],
                               R.double_pendulum_tip([p["theta1_0"], p["theta2_0"]])[1], atol=1e-9)
    # spring markers' x axes: AZ(I,J) at input equals the reference's angle measure
    for s, expect in [(s1, p["theta1_0"]), (s2, p["theta2_0"] - p["theta1_0"])]:
        Ai = dk.markers[int(s.get("i_marker_id"))]["A"]
        Aj = dk.markers[int(s.get("j_marker_id"))]["A"]
        xi = Aj.T @ Ai[:, 0]
        assert abs(math.atan2(xi[1], xi[0]) - expect) < 1e-12
    # bushing
    dk = deck("bushing_block")
    p = R.BUSHING_PARAMS
    b = dk.one("Force_Bushing")
    for k in ("kx", "ky", "kz", "ktx", "kty", "ktz", "preload_y"):
        assert float(b.get(k)) == p[k]
    for k in ("preload_x", "preload_z", "preload_tx", "preload_ty", "preload_tz"):
        assert float(b.get(k)) == 0.0
    mi, mj = dk.markers[int(b.get("i_marker_id"))], dk.markers[int(b.get("j_marker_id"))]
    assert np.allclose(mi["pos"], p["cg0"]) and np.allclose(mj["pos"], p["cg0"])
    assert np.allclose(dk.cg(2)["pos"], p["cg0"]) and np.allclose(mj["A"], np.eye(3))
    f = dk.one("Force_Vector_OneBody")
    assert tuple(float(f.get(k)) for k in ("fx_expression", "fy_expression", "fz_expression")) == p["load"]
    np.testing.assert_allclose(dk.markers[int(f.get("marker_id"))]["pos"],
                               np.array(p["cg0"]) + p["offset"], atol=1e-12)
    assert float(dk.bodies[2].get("mass")) == p["mass"]


@pytest.mark.parametrize("name,joint", [("chain_10", "revolute"), ("chain_10_spherical", "spherical")])
def test_committed_chain_decks_are_generated(name, joint):
    assert (DECKS / f"{name}.xml").read_text() == gen_chain.build_chain_deck(10, joint)
    dk = deck(name)
    ps = dk.one("Param_Static")
    assert (ps.get("stability") is not None) == (joint == "spherical")


def test_gen_chain_cli(tmp_path):
    out = tmp_path / "c.xml"
    r = subprocess.run([sys.executable, str(DECKS / "gen_chain.py"), "7", "--joint", "spherical",
                        "--span", "450", "-o", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    dk = Deck(out)
    assert len(dk.joints) == 8 and len(dk.bodies) == 8
    assert dof_and_redundancy(dk)[:2] == (18, 0)
    r = subprocess.run([sys.executable, str(DECKS / "gen_chain.py"), "7", "--span", "800"],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode != 0                       # span >= N * link length is impossible


# =============================================================================================
# 3. solver vs reference (through the CLI)
# =============================================================================================
def poise_cmd():
    exe = Path(sys.executable).parent / "poise"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "poise_cli.main"]


class Solution:
    def __init__(self, h5path, stdout):
        import h5py
        self.stdout = stdout
        with h5py.File(h5path, "r") as h:
            st = h.attrs["status"]
            self.status = st.decode() if isinstance(st, bytes) else str(st)
            g = h["analysis_000"]
            self.d = {}
            g.visititems(lambda k, v: self.d.__setitem__(k, v[()]) if hasattr(v, "shape") else None)
        self.body_ids = [int(i) for i in self.d["bodies/id"]]
        self.joint_ids = [int(i) for i in self.d["joints/id"]] if "joints/id" in self.d else []

    def pos(self, body):
        return np.asarray(self.d["bodies/position"])[-1, self.body_ids.index(body)]

    def ori(self, body):
        return np.asarray(self.d["bodies/orientation"])[-1, self.body_ids.index(body)]

    def jforce(self, jid):
        return np.asarray(self.d["joints/force"])[-1, self.joint_ids.index(jid)]

    def jtorque(self, jid):
        return np.asarray(self.d["joints/torque"])[-1, self.joint_ids.index(jid)]


def solve(deck_path, tmp_path, timeout=900) -> Solution:
    out = Path(tmp_path) / "out.h5"
    cmd = poise_cmd() + ["solve", str(deck_path), "-o", str(out), "--json"]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    assert r.returncode == 0, f"exit {r.returncode}\nstdout:\n{r.stdout}\nstderr:\n{r.stderr}"
    sol = Solution(out, r.stdout)
    sol.wall = wall
    assert sol.status == "converged"
    assert bool(np.all(np.asarray(sol.d["frames/converged"])))
    try:
        json.loads(r.stdout)
    except ValueError:
        pytest.fail(f"--json did not print JSON: {r.stdout[:500]}")
    return sol


def close(actual, expected, tol, what):
    err = float(np.max(np.abs(np.asarray(actual, float) - np.asarray(expected, float))))
    assert err <= tol, f"{what}: |error| {err:.3e} > {tol:.1e}\n actual   {actual}\n expected {expected}"


def test_solve_pendulum_multiturn(tmp_path):
    p = R.PENDULUM_PARAMS
    ref = R.pendulum_multiturn()
    s = solve(DECKS / "pendulum_multiturn.xml", tmp_path)
    L = p["length"]
    close(s.pos(2), ref["cg"], REL * L, "pendulum CG")
    close(s.ori(2), ref["orientation"], REL, "pendulum orientation")
    F = R.weight(p["mass"])
    close(s.jforce(1), ref["hinge_force"], REL * F, "hinge force on pendulum")
    close(s.jtorque(1), ref["hinge_torque"], REL * F * L, "hinge torque on pendulum")


def test_solve_fourbar_spring(tmp_path):
    p = R.FOURBAR_PARAMS
    ref = R.fourbar_equilibrium()
    s = solve(DECKS / "fourbar_spring.xml", tmp_path)
    for bid, name in [(2, "crank"), (3, "coupler"), (4, "rocker")]:
        close(s.pos(bid), ref["cg"][name], REL * p["b"], f"{name} CG")
        close(s.ori(bid), ref["orientation"][name], REL, f"{name} orientation")


def test_solve_slider_crank_load(tmp_path):
    p = R.SLIDER_CRANK_PARAMS
    ref = R.slider_crank()
    s = solve(DECKS / "slider_crank_load.xml", tmp_path)
    for bid, name in [(2, "crank"), (3, "rod"), (4, "slider")]:
        close(s.pos(bid), ref["cg"][name], REL * p["l"], f"{name} CG")
        close(s.ori(bid), ref["orientation"][name], REL, f"{name} orientation")
    # non-redundant mechanism: the crank-pivot reaction is unique
    Fs = max(abs(p["fx"]), R.weight(p["m_crank"] + p["m_rod"] + p["m_slider"]))
    close(s.jforce(1), ref["pivot_force"], REL * Fs, "crank pivot force on crank")
    close(s.jtorque(1), ref["pivot_torque"], REL * Fs * p["r"], "crank pivot torque on crank")


def test_solve_double_pendulum(tmp_path):
    p = R.DOUBLE_PENDULUM_PARAMS
    ref = R.double_pendulum()
    s = solve(DECKS / "double_pendulum.xml", tmp_path)
    for bid, name in [(2, "link1"), (3, "link2")]:
        close(s.pos(bid), ref["cg"][name], REL * p["l1"], f"{name} CG")
        close(s.ori(bid), ref["orientation"][name], REL, f"{name} orientation")
    Fs = max(np.abs(ref["base_force"]))
    close(s.jforce(1), ref["base_force"], REL * Fs, "base hinge force on link 1")
    close(s.jforce(2), ref["elbow_force"], REL * Fs, "elbow hinge force on link 2")
    # revolute torques: z component is zero (springs carry the z moment), planar -> all zero
    close(s.jtorque(1), np.zeros(3), REL * Fs * p["l1"], "base hinge torque")
    close(s.jtorque(2), np.zeros(3), REL * Fs * p["l1"], "elbow hinge torque")


def test_solve_bushing_block(tmp_path):
    ref = R.bushing_block()
    s = solve(DECKS / "bushing_block.xml", tmp_path)
    # model size: the 150 mm load offset; displacements are ~0.1 mm so also check them relatively
    close(s.pos(2), ref["cg"], REL * 150.0, "block CG")
    close(s.pos(2) - np.array(R.BUSHING_PARAMS["cg0"]), ref["displacement"],
          1e-6 * np.abs(ref["displacement"]).max(), "block displacement")
    close(s.ori(2), ref["orientation"], REL, "block orientation")


def _check_chain(s, n, a, m, span, joint):
    cat = R.catenary(n, a, m, span)
    P = np.array([s.pos(k + 1) for k in range(1, n + 1)])
    close(P, cat["cg"], REL * a, f"chain N={n} link CGs")
    X = np.array([s.ori(k + 1)[:, 0] for k in range(1, n + 1)])
    close(X, cat["xaxis"], REL, f"chain N={n} link x axes")
    if joint == "revolute":
        Z = np.array([s.ori(k + 1)[:, 2] for k in range(1, n + 1)])
        close(Z, np.tile([0, 0, 1.0], (n, 1)), REL, "chain link z axes")
    # in-plane end-pin reactions are statically determinate (also with the redundant revolutes);
    # out-of-plane components carry no load
    Fs = n * R.weight(m)
    close(s.jforce(1)[:2], cat["left_force"][:2], REL * Fs, "left pin force on link 1")
    close(s.jforce(n + 1)[:2], cat["right_force"][:2], REL * Fs, "right pin force on link N")


def test_solve_chain_10(tmp_path):
    s = solve(DECKS / "chain_10.xml", tmp_path)
    _check_chain(s, 10, 100.0, 1.0, 800.0, "revolute")


def test_solve_chain_10_spherical(tmp_path):
    s = solve(DECKS / "chain_10_spherical.xml", tmp_path)
    _check_chain(s, 10, 100.0, 1.0, 800.0, "spherical")


def test_solve_chain_100_revolute(tmp_path):
    f = tmp_path / "chain_100.xml"
    f.write_text(gen_chain.build_chain_deck(100, "revolute"))
    s = solve(f, tmp_path)
    _check_chain(s, 100, 100.0, 1.0, 8000.0, "revolute")


def test_solve_chain_1000_revolute(tmp_path):
    f = tmp_path / "chain_1000.xml"
    f.write_text(gen_chain.build_chain_deck(1000, "revolute"))
    s = solve(f, tmp_path)
    _check_chain(s, 1000, 100.0, 1.0, 80000.0, "revolute")
