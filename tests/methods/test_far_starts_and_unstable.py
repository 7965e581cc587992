"""Far starts, fallback switches, toggle poses, unstable equilibria (FIM_S vs MKEAM)."""
import numpy as np
from scipy.optimize import brentq

from poise.gen.deck import Deck, rot_y, rot_z

G = 9.81


def pendulum(th0, k=0.0, ref=0.0, m=2.0, l=400.0, joint="REVOLUTE", method="FIM_S"):
    d = Deck(method=method)
    d.ground()
    R = rot_z(th0)
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 20, R @ [l / 2, 0, 0], R, mass=m, inertia=(10, m * l * l / 12, m * l * l / 12))
    d.marker(21, 2, (0, 0, 0), R if joint == "REVOLUTE" else rot_y(np.pi / 2))
    if joint == "REVOLUTE":
        d.joint(1, "REVOLUTE", 21, 101)
    else:
        d.joint(1, joint, 21, 101)
    if k:
        d.spring(1, 21, 101, k, ref, rotational=True)
    return d


def numeric_modes(a, frame=0):
    """The described modes of a frame as (class, body, kind, direction) from ``modes/*`` (flat
    in frame order, ``frames/n_modes`` per frame)."""
    d = a.datasets
    n = d["frames/n_modes"]
    start = int(np.sum(n[:frame]))
    return [(str(d["modes/class"][j]), int(d["modes/body"][j]), str(d["modes/kind"][j]),
             np.asarray(d["modes/direction"][j])) for j in range(start, start + int(n[frame]))]


def angle(a):
    R = a.datasets["bodies/orientation"][0, 0]
    return np.arctan2(R[1, 0], R[0, 0])


def test_spring_pendulum_wound_five_turns(runner):
    k, m, l = 2e4, 2.0, 400.0
    ref = 10 * np.pi + 0.5
    a = runner.api(pendulum(0.0, k, ref))
    assert a.converged, a.message
    th = brentq(lambda t: -k * (t - ref) - m * G * l / 2 * np.cos(t), ref - 1, ref + 1)
    assert abs(np.mod(angle(a) - th + np.pi, 2 * np.pi) - np.pi) < 1e-9
    # the spring torque proves the turns were counted (a wrapped angle would give ~10 pi k)
    T = a.datasets["forces/torque"][0, 0]
    assert abs(abs(T[2]) - abs(k * (th - ref))) < 1e-6 * k
    assert a.datasets["frames/iterations"][0] <= 8
    assert set(a.datasets["iterations/event"]) == {"newton"}


def cubic_slider(x0):
    """Point body sliding along X under fx = -(u^3 - 2u + 2), u = x/100: the merit function
    |F|^2 has a local minimum at u = sqrt(2/3) with F != 0 between the start u = 0 and the only
    root u* = -1.7693 (Newton from 0 cycles 0 -> 1 -> 0 and, with the line search, stalls there)."""
    d = Deck(grav=None, static=dict(max_num_iter=30))
    d.ground()
    d.marker(101, 1, (0, 0, 0), rot_y(np.pi / 2))
    d.point(2, 20, (x0, 0, 0), mass=1.0)
    d.marker(21, 2, (x0, 0, 0), rot_y(np.pi / 2))
    d.jprim(1, "INLINE", 21, 101)
    d.add('<Force_Vector_OneBody id="1" type="FORCEONLY" marker_id="21" ref_marker_id="0" '
          'fx_expression="-((DX(21,101)/100)**3 - 2*DX(21,101)/100 + 2)" fy_expression="0" '
          'fz_expression="0"/>')
    return d


def test_far_start_plain_newton_stalls_fallback_converges(runner):
    u = [r.real for r in np.roots([1, 0, -2, 2]) if abs(r.imag) < 1e-12][0]
    off = runner.api(cubic_slider(0.0), "plain.xml", fallback=False)
    assert not off.converged
    assert off.datasets["frames/status"][0] == "max_iterations"
    # the merit function has a valley between the start and the root (F >= 0.911 N for u >= 0):
    # Newton's line search stalls there and its steps go down the potential instead, towards
    # the root, but one model size (L = 1 mm: every marker at the origin) per iteration
    assert 100 * u < off.datasets["bodies/position"][0, 0, 0] < 0
    assert "newton-downhill" in set(off.datasets["iterations/event"])
    assert off.datasets["frames/imbalance"][0] > 0.9
    # the chain's budget counts MKEAM's integration steps too: 1 mm steps need more than 30
    a = runner.api(cubic_slider(0.0), "fallback.xml", fallback_max_num_iter=1000)
    assert a.converged, a.message
    assert abs(a.datasets["bodies/position"][0, 0, 0] - 100 * u) < 1e-7
    ev = list(a.datasets["iterations/event"])
    switches = [e for e in ev if e.startswith("fallback:")]
    assert switches and switches[0] == "fallback: stability=0.01: max_iterations"
    assert "fallback strategy" in a.message
    assert ev.index(switches[0]) > ev.index("newton")     # the plain Newton rows come first
    assert a.datasets["frames/stability"][0] == "stable"


def slider_crank_tdc(P, k=0.0, r=100.0, l=300.0):
    """Slider-crank at top dead centre (crank and rod along +X), no gravity, force P on the
    slider along +X (P < 0 pushes the slider towards the crank: the toggle is compressed).
    Joints: REVOLUTE, SPHERICAL, UNIVERSAL, TRANSLATIONAL (17 = 18 - 1, not redundant)."""
    d = Deck(grav=None)
    d.ground()
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, (r + l, 0, 0), rot_y(np.pi / 2))
    d.body(2, 20, (r / 2, 0, 0), mass=0.5, inertia=(1, 420, 420))
    d.marker(21, 2, (0, 0, 0))
    d.marker(22, 2, (r, 0, 0))
    d.body(3, 30, (r + l / 2, 0, 0), mass=1.0, inertia=(1, 7500, 7500))
    d.marker(31, 3, (r, 0, 0))
    d.marker(32, 3, (r + l, 0, 0), rot_y(np.pi / 2))
    d.body(4, 40, (r + l, 0, 0), mass=2.0, inertia=(500, 500, 500))
    d.marker(41, 4, (r + l, 0, 0))
    d.marker(42, 4, (r + l, 0, 0), rot_y(np.pi / 2))
    d.joint(1, "REVOLUTE", 21, 101)
    d.joint(2, "SPHERICAL", 31, 22)
    d.joint(3, "UNIVERSAL", 32, 41)
    d.joint(4, "TRANSLATIONAL", 42, 102)
    if k:
        d.spring(1, 21, 101, k, 0.0, rotational=True)
    d.force(1, 41, (float(P), 0.0, 0.0))
    return d


def test_toggle_slider_crank_top_dead_centre(runner):
    """A load along the rod at TDC is compatible (the joints carry it, no crank torque): the
    answer is the TDC pose itself. Whether it holds is the stability class: compressed, the
    toggle is unstable unless the crank spring exceeds P r (1 + r/l) = 13 333 N mm/rad;
    in tension it holds. TDC is also a change of mobility: the rod axis coincides with the
    UNIVERSAL's free axis z_I, so the rod can spin about its own axis (one zero mode, named
    "body 3 rotation about (±1,0,0)"): holding poses are ``neutral`` with n_zero = 1, not
    ``stable``."""
    P, r, l = 100.0, 100.0, 300.0
    kcrit = P * r * (1 + r / l)
    cases = [(-P, 0.0, "unstable"), (-P, 0.75 * kcrit, "unstable"), (-P, 1.5 * kcrit, "neutral"),
             (+P, 0.0, "neutral")]
    for n, (load, k, klass) in enumerate(cases):
        a = runner.api(slider_crank_tdc(load, k, r, l), f"tdc{n}.xml")
        assert a.converged, (load, k, a.message)
        pos = a.datasets["bodies/position"][0]
        np.testing.assert_allclose(pos[2], [r + l, 0, 0], atol=1e-9)
        np.testing.assert_allclose(pos[0], [r / 2, 0, 0], atol=1e-9)
        # the crank pivot carries the whole load along X
        F = a.datasets["joints/force"][0, 0]
        np.testing.assert_allclose(F, [-load, 0, 0], atol=1e-8)
        assert a.datasets["frames/stability"][0] == klass, (load, k)
        assert a.datasets["frames/n_negative"][0] == (1 if klass == "unstable" else 0)
        assert a.datasets["frames/n_zero"][0] == 1
        modes = numeric_modes(a)
        if klass == "unstable":
            # the toggle's motion: the crank turns by a about its pivot and the rod by -a/3
            # about the slider end; crank and rod move alike (CG 50 a, rotation x lever 50 a
            # each), so either may be named: the tie is broken by rounding
            [(_, b, kind, axis)] = [m for m in modes if m[0] == "unstable"]
            assert b in (2, 3) and kind == "rotation"
            np.testing.assert_allclose(np.abs(axis), [0.0, 0.0, 1.0], atol=1e-6)
        # the rod's spin about its own axis (global X), sign-normalised (largest component +)
        (neutral,) = [m for m in modes if m[0] == "neutral"]
        assert neutral[1:3] == (3, "rotation")
        np.testing.assert_allclose(neutral[3], [1.0, 0.0, 0.0], atol=1e-6)


def test_fim_s_at_unstable_equilibrium_and_mkeam_finds_the_stable_one(runner):
    """Inverted pendulum on a UNIVERSAL joint, started exactly upright: FIM_S stays (it is an
    equilibrium) and says unstable with two negative modes (tilts about X and Z) named by body;
    MKEAM from the same start falls to the hanging pose."""
    m, l = 2.0, 400.0
    d = Deck()
    d.ground()
    R = rot_z(np.pi / 2)                      # body x axis along +Y (upright)
    d.marker(101, 1, (0, 0, 0))               # J: z along global Z
    d.body(2, 20, (0, l / 2, 0), R, mass=m, inertia=(10, m * l * l / 12, m * l * l / 12))
    d.marker(21, 2, (0, 0, 0), rot_y(np.pi / 2))   # I: z along global X (z_I perpendicular z_J)
    d.joint(1, "UNIVERSAL", 21, 101)
    a = runner.api(d, "up.xml")
    assert a.converged, a.message
    np.testing.assert_allclose(a.datasets["bodies/position"][0, 0], [0, l / 2, 0], atol=1e-9)
    assert a.datasets["frames/stability"][0] == "unstable"
    assert a.datasets["frames/n_negative"][0] == 2
    modes = numeric_modes(a)
    assert [(m[0], m[1], m[2]) for m in modes] == [("unstable", 2, "rotation")] * 2
    # the two tilts span the plane normal to the upright link (global Y): about X and about Z
    D = np.array([m[3] for m in modes])
    np.testing.assert_allclose(D[:, 1], 0.0, atol=1e-6)
    np.testing.assert_allclose(np.abs(np.linalg.det(D[:, [0, 2]])), 1.0, atol=1e-6)
    b = runner.api(d, "up_mkeam.xml", method="MKEAM")
    assert b.converged, b.message
    np.testing.assert_allclose(b.datasets["bodies/position"][0, 0], [0, -l / 2, 0], atol=1e-3 * l)
    assert b.datasets["frames/stability"][0] == "stable"
