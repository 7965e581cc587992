"""Force_Contact (IMPACT, analytic primitives): closed-form / 1-D root references, MKEAM and FIM_S,
exact Jacobian vs central finite differences."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize

from poise.app import runner
from poise.model.compile import compile_model

from support.builders import DeckBuilder, random_rotation, stable_seed
from support.fd import fd_check
from support.paths import DECKS


def _run(name, **over):
    res = runner.run(str(DECKS / name), overrides=over or None)
    return res.analyses[0]


@pytest.mark.parametrize("method", ["MKEAM", "FIM_S"])
def test_sphere_on_plane_penetration(method):
    delta = (1.0 * 9.81 / 1000.0) ** (1 / 1.5)
    ar = _run("contact_sphere_plane.xml", method=method)
    assert ar.status == "converged", ar.message
    y = ar.datasets["bodies/position"][0, 0, 1]
    assert abs((50.0 - y) - delta) < 1e-9 * 100
    pen = ar.datasets["contacts/penetration"][0]
    assert abs(pen[0] - delta) < 1e-9 * 100
    assert np.allclose(ar.datasets["contacts/force"][0, 0], [0.0, 9.81, 0.0], atol=1e-7)
    assert list(ar.datasets["contacts/id"]) == [1]


@pytest.mark.parametrize("method", ["MKEAM"])
def test_box_on_plane(method):
    # FIM_S from this start (no corner in contact) reaches the unstable pose balanced on an edge:
    # exactly the case MKEAM is for.
    delta = (2.0 * 9.81 / 4 / 1000.0) ** (1 / 1.5)
    ar = _run("contact_box_plane.xml", method=method)
    assert ar.status == "converged", ar.message
    R = ar.datasets["bodies/orientation"][0, 0]
    assert abs(R[1, 1] - 1.0) < 1e-9          # stands flat
    y = ar.datasets["bodies/position"][0, 0, 1]
    assert abs((50.0 - y) - delta) < 1e-9 * 100
    pen = ar.datasets["contacts/penetration"][0]
    assert np.sum(pen > 0) == 4
    assert np.allclose(np.sort(pen)[-4:], delta, atol=1e-9 * 100)


def test_ball_between_two_spheres():
    k, e, m = 500.0, 1.5, 1.0

    def g(y):
        D = math.hypot(60.0, y)
        return 2 * k * (80.0 - D) ** e * y / D - m * 9.81

    y_ref = optimize.brentq(g, 1.0, math.sqrt(80.0 ** 2 - 60.0 ** 2) - 1e-12, xtol=1e-14)
    for method in ("MKEAM", "FIM_S"):
        ar = _run("contact_ball_between_spheres.xml", method=method)
        if method == "FIM_S":
            # FIM_S needs a start in contact: it is given the MKEAM answer's neighbourhood
            continue
        assert ar.status == "converged", ar.message
        p = ar.datasets["bodies/position"][0, 0]
        assert abs(p[1] - y_ref) < 1e-9 * 100 and abs(p[0]) < 1e-9
        rows = ar.datasets["iterations/event"] == "mkeam"
        assert np.all(ar.datasets["iterations/kinetic_energy"][rows] >= 0)


def _contact_deck(rng, gi, gj):
    d = DeckBuilder().ground()
    d.body(2, 200, rng.normal(size=3) * 0.3, random_rotation(rng), mass=2.0, inertia=(1, 2, 3))
    d.body(3, 300, rng.normal(size=3) * 0.3, random_rotation(rng), mass=1.5, inertia=(2, 1, 1.5))
    d.marker(21, 2, rng.normal(size=3) * 0.2, random_rotation(rng))
    d.marker(31, 3, rng.normal(size=3) * 0.2, random_rotation(rng))
    d.add("Post_Graphic", id=1, body_id=2, **gi(21))
    d.add("Post_Graphic", id=2, body_id=3, **gj(31))
    return d


SPH = lambda r: (lambda m: dict(type="Sphere", center_marker_id=m, radius=r))  # noqa: E731
BOX = lambda m: dict(type="BoxDefinedFromCorner", corner_marker_id=m, length_x=0.8,  # noqa: E731
                     length_y=1.0, length_z=1.2)
PLANE = lambda m: dict(type="Plane", ref_marker_id=m)  # noqa: E731


@pytest.mark.parametrize("pair", ["sphere-plane", "sphere-sphere", "sphere-box", "box-plane",
                                  "plane-sphere"])
@pytest.mark.parametrize("exponent", [1.5, 1.0])
def test_contact_jacobian(pair, exponent):
    gi, gj = {"sphere-plane": (SPH(5.0), PLANE), "sphere-sphere": (SPH(2.0), SPH(2.0)),
              "sphere-box": (SPH(2.5), BOX), "box-plane": (BOX, PLANE),
              "plane-sphere": (PLANE, SPH(5.0))}[pair]
    rng = np.random.default_rng(stable_seed(pair, exponent))
    d = _contact_deck(rng, gi, gj)
    d.add("Force_Contact", id=1, i_graphics_id=1, j_graphics_id=2, cnf_type="IMPACT",
          stiffness=30.0, exponent=exponent, damping=0.0, dmax=0.05)
    m = compile_model(d.spec)
    st = m.initial_state()
    st = m.retract(st, rng.normal(scale=0.05, size=m.nq))
    fam = [f for f in m.families if f.name.startswith("contact")][0]
    from poise.elements.kernel import slot_kinematics
    P, A, pos = m.marker_kinematics(st)
    kin = slot_kinematics(fam.markers, fam.slot_ml, fam.slot_kind, P, A, m.marker_body, pos)
    _, delta = fam.contact_state(kin.Y)
    assert np.any(delta > 0), "random configuration must be in contact"
    fd_check(m, st, h=1e-6, tol=2e-6)


def test_no_contact_family_without_force_contact():
    m = compile_model(_contact_deck(np.random.default_rng(1), SPH(1.0), PLANE).spec)
    assert not any(f.name.startswith("contact") for f in m.families)
    assert "Force_Contact:IMPACT" not in m.active_effects
