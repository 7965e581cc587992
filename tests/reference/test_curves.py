"""Higher-pair constraints on curves and surfaces (PTCV, CVCV, PTSF, CVSF, SFSF).

Jacobians are checked against central differences of the residual on random configurations
with random multipliers (``fd_check``); solves are checked against independent references.
"""
import numpy as np
import pytest

from poise.deck.spec import Expr
from poise.core.errors import SourceLoc
from poise.model.compile import compile_model

from support.builders import DeckBuilder, random_rotation, stable_seed
from support.fd import fd_check
from support.paths import DECKS


def _x(text, tag="Reference_ParamCurve", id=1, attr="x_expression"):
    return Expr(text, SourceLoc("<built>", 1, tag, id), attr)


def curve_analytic(d, id, x, y, z, u0=0.0, u1=1.0, closed=False):
    tag = "Reference_ParamCurve"
    return d.add(tag, id=id, u_start=u0, u_end=u1, is_u_closed=closed,
                 x_expression=_x(x, tag, id), y_expression=_x(y, tag, id, "y_expression"),
                 z_expression=_x(z, tag, id, "z_expression"))


def surface_analytic(d, id, x, y, z, u0=-1.0, u1=1.0, v0=-1.0, v1=1.0):
    tag = "Reference_ParamSurface"
    return d.add(tag, id=id, u_start=u0, u_end=u1, v_start=v0, v_end=v1,
                 x_expression=_x(x, tag, id), y_expression=_x(y, tag, id, "y_expression"),
                 z_expression=_x(z, tag, id, "z_expression"))


def curve_points(d, id, pts, closed=False):
    from poise.deck.spec import Element
    d.add("Reference_ParamCurve", id=id, is_u_closed=closed, num_pts=len(pts))
    el = d.spec.model[-1]
    el.text = " ".join(f"{p[0]} {p[1]} {p[2]}" for p in pts)
    assert isinstance(el, Element)
    return d


def _rand_deck(rng):
    d = DeckBuilder().ground()
    d.body(2, 200, rng.normal(size=3), random_rotation(rng), mass=2.0, inertia=(1, 2, 3))
    d.body(3, 300, rng.normal(size=3), random_rotation(rng), mass=1.5, inertia=(2, 1, 1.5))
    d.marker(21, 2, rng.normal(size=3), random_rotation(rng))
    d.marker(31, 3, rng.normal(size=3), random_rotation(rng))
    return d


def _check(d, rng):
    m = compile_model(d.spec)
    st = m.initial_state()
    st = m.retract(st, rng.normal(scale=0.3, size=m.nq))
    st.lam = rng.normal(size=m.nc)
    return fd_check(m, st, tol=1e-5)


@pytest.mark.parametrize("form", ["analytic", "spline", "closed"])
def test_ptcv_jacobian(form):
    rng = np.random.default_rng(stable_seed("ptcv", form))
    d = _rand_deck(rng)
    if form == "analytic":
        curve_analytic(d, 7, "U", "0.5*U**2 + 0.1*U**3", "0.2*SIN(U)", -2, 2)
    else:
        th = np.linspace(0, 2 * np.pi, 13)[:-1 if form == "closed" else None]
        if form == "closed":
            th = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        pts = np.stack([np.cos(th), 0.5 * np.sin(th), 0.1 * th], 1)
        if form == "closed":
            pts[:, 2] = 0.1 * np.sin(th)
        curve_points(d, 7, pts, closed=form == "closed")
    d.add("Constraint_PTCV", id=1, i_marker_id=21, j_marker_id=31, curve_id=7)
    _check(d, rng)


def _run(name, **over):
    from poise.app import runner
    res = runner.run(str(DECKS / name), overrides=over or None)
    return res.analyses[0]


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_ptcv_parabola_vertex(method):
    ar = _run("elem_ptcv_parabola.xml", method=method)
    assert ar.status == "converged", ar.message
    np.testing.assert_allclose(ar.datasets["bodies/position"][0, 0], [0, 0, 0], atol=1e-8)
    assert abs(ar.datasets["curves/parameters"][0, 0, 0]) < 1e-8
    assert np.isnan(ar.datasets["curves/parameters"][0, 0, 1:]).all()
    np.testing.assert_allclose(ar.datasets["curves/point"][0, 0], [0, 0, 0], atol=1e-8)
    np.testing.assert_allclose(ar.datasets["curves/force"][0, 0], [0, 9.81, 0], atol=1e-8)
    assert list(ar.datasets["curves/tag"]) == ["Constraint_PTCV"]


def _circle(d, id, r, cx=0.0):
    return curve_analytic(d, id, f"{cx}+{r}*COS(U)", f"{r}*SIN(U)", "0", 0.0, 2 * np.pi, True)


def test_cvcv_jacobian():
    rng = np.random.default_rng(stable_seed("cvcv"))
    d = _rand_deck(rng)
    _circle(d, 1, 0.3)
    curve_analytic(d, 2, "0.8*COS(U)", "0.5*SIN(U)", "0", 0.0, 2 * np.pi, True)
    d.add("Constraint_CVCV", id=1, i_marker_id=21, i_curve_id=1, j_marker_id=31, j_curve_id=2)
    _check(d, rng)


def test_ptsf_jacobian():
    rng = np.random.default_rng(stable_seed("ptsf"))
    d = _rand_deck(rng)
    surface_analytic(d, 5, "U + 0.1*V**2", "V", "0.3*U**2 + 0.2*U*V + 0.1*SIN(V)")
    d.add("Constraint_PTSF", id=1, i_marker_id=21, j_marker_id=31, surface_id=5)
    _check(d, rng)


def test_cvsf_jacobian():
    rng = np.random.default_rng(stable_seed("cvsf"))
    d = _rand_deck(rng)
    curve_analytic(d, 1, "0.4*COS(U)", "0.3*SIN(U)", "0.1*SIN(2*U)", 0.0, 2 * np.pi, True)
    surface_analytic(d, 5, "U", "V", "0.3*U**2 + 0.2*U*V - 0.1*V**2")
    d.add("Constraint_CVSF", id=1, i_marker_id=21, curve_id=1, j_marker_id=31, surface_id=5)
    _check(d, rng)


def test_sfsf_jacobian():
    rng = np.random.default_rng(stable_seed("sfsf"))
    d = _rand_deck(rng)
    surface_analytic(d, 4, "U", "V", "0.5*U**2 + 0.3*V**2 + 0.1*U*V")
    surface_analytic(d, 5, "U + 0.2*V", "V", "-0.3*U**2 + 0.2*U*V - 0.1*V**3")
    d.add("Constraint_SFSF", id=1, i_marker_id=21, i_surface_id=4, j_marker_id=31, j_surface_id=5)
    _check(d, rng)


def _cam_yc(th, a=50.0, b=30.0, r=10.0):
    """Roller-centre height on the cam's offset curve at x = 0 (cam ellipse turned by th)."""
    from scipy.optimize import brentq
    c, s = np.cos(th), np.sin(th)

    def C(p):
        E = np.array([a * np.cos(p), b * np.sin(p)])
        n = np.array([b * np.cos(p), a * np.sin(p)])
        P = E + r * n / np.linalg.norm(n)
        return np.array([c * P[0] - s * P[1], s * P[0] + c * P[1]])

    ps = np.linspace(0, 2 * np.pi, 721)
    xs = [C(p)[0] for p in ps]
    ys = [C(brentq(lambda q: C(q)[0], ps[k], ps[k + 1], xtol=1e-15))[1]
          for k in range(720) if xs[k] * xs[k + 1] <= 0]
    return max(ys)


@pytest.mark.parametrize("method", ["FIM_S", "MKEAM"])
def test_cvcv_cam_follower(method):
    ar = _run("elem_cvcv_cam.xml", method=method)
    assert ar.status == "converged", ar.message
    y = ar.datasets["bodies/position"][0, 1, 1]
    assert abs(y - _cam_yc(0.4)) < 1e-8
    # reaction on the follower: spring (k 2 N/mm, compressed by y) + weight, along +Y
    F = ar.datasets["curves/force"][0, 0]
    assert abs(F[1] - (2.0 * y + 0.5 * 9.81)) < 1e-7
    # contact point on the roller (radius 10 about the follower centre)
    p = ar.datasets["curves/point"][0, 0]
    assert abs(np.linalg.norm(p - [0, y, 0]) - 10.0) < 1e-8


@pytest.mark.parametrize("method", ["FIM_S", "FIM_D"])
def test_cvcv_cam_quasistatic(method):
    ar = _run("elem_cvcv_cam_qs.xml", method=method)
    assert ar.status == "converged", ar.message
    t = ar.datasets["time"]
    y = ar.datasets["bodies/position"][:, 1, 1]
    assert len(t) == 21 and abs(t[-1] - 1.0) < 1e-12
    ref = np.array([_cam_yc(0.4 + ti) for ti in t])
    tol = 1e-8 if method == "FIM_S" else 1e-4      # FIM_D: IDA tolerance 1e-6 (relative)
    assert np.max(np.abs(y - ref)) < tol
    assert ar.datasets["curves/parameters"].shape == (21, 1, 4)


@pytest.mark.parametrize("deck,method", [(d, m) for d in ("elem_ptsf_paraboloid.xml",
                                                          "elem_cvsf_disk_plane.xml",
                                                          "elem_sfsf_ball_plane.xml")
                                         for m in ("FIM_S", "MKEAM")])
def test_surface_decks(deck, method):
    ar = _run(deck, method=method)
    assert ar.status == "converged", ar.message
    pos = ar.datasets["bodies/position"][0, 0]
    mg = {"elem_ptsf_paraboloid.xml": 2 * 9.81}.get(deck, 9.81)
    centre = [0, 0, 0] if "ptsf" in deck else [0, 0.2, 0]     # bottom / radius 0.2 above floor
    np.testing.assert_allclose(pos, centre, atol=1e-8)
    np.testing.assert_allclose(ar.datasets["curves/point"][0, 0], [0, 0, 0], atol=1e-8)
    np.testing.assert_allclose(ar.datasets["curves/force"][0, 0], [0, mg, 0], atol=1e-7)
    npar = {"ptsf": 2, "cvsf": 3, "sfsf": 4}[deck.split("_")[1]]
    par = ar.datasets["curves/parameters"][0, 0]
    assert np.isfinite(par[:npar]).all() and np.isnan(par[npar:]).all()
