"""Independent reference solutions for the example decks in ``decks/``.

Pure numpy/scipy. Nothing here imports or calls poise: every answer is derived from the physics of
the deck (planar kinematics + potential energy / virtual work / statics) using the conventions of
``/work/shared/reference/conventions.md``:

* units N-kg-mm-s, gravity 9810 mm/s^2 along -Y, so the weight of m kg is ``m * 9.81`` N;
* rotational spring torque on I about J's z: ``T = -k (AZ(I,J) - length) + preload``, AZ continuous
  from the input configuration;
* translational spring: ``F = -k (DM - length) + preload`` along J->I;
* bushing: ``F = -K (DX,DY,DZ)(I,J,J) + preload``, ``T = -Kt (AX,AY,AZ)(I,J) + preload_t`` in J axes;
* joint reaction = force/torque the joint applies to the body of its I marker, torque about the I
  marker origin, global axes.

The numeric parameters of every deck live here (``*_PARAMS``) so that the deck builder and the tests
share one source; ``tests/reference/test_decks_reference.py`` also checks that the XML decks carry these values.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize

G_MM = 9810.0  # gravity, mm/s^2


def weight(m: float) -> float:
    """Weight in N of ``m`` kg under 9810 mm/s^2 (1 N = 1000 kg mm/s^2)."""
    return m * G_MM / 1000.0


def rot_z(t: float) -> np.ndarray:
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _cross2(r, f):
    return r[0] * f[1] - r[1] * f[0]


# ---------------------------------------------------------------------------------------------
# 1. pendulum_multiturn
# ---------------------------------------------------------------------------------------------
PENDULUM_PARAMS = dict(
    mass=2.0,            # kg
    length=400.0,        # mm, hinge to tip
    l_cg=200.0,          # mm, hinge to CG
    k=2.0e4,             # N mm / rad  (> m g l_cg = 3924 N mm -> unique equilibrium)
    ref_angle=6.0 * math.pi + 1.0,   # rad, 3 full turns + 1 rad
    theta0=0.0,          # input configuration: pendulum along +X
)


def pendulum_multiturn(p=PENDULUM_PARAMS):
    """Equilibrium of the hinged pendulum wound by a rotational spring.

    theta = angle of the pendulum (its x axis) from global +X, counter-clockwise about +Z; in the
    input configuration theta = 0 and AZ(I,J) = theta (I on the pendulum, J on ground, both aligned
    with global axes at input). Moment about the hinge (z):
        spring  -k (theta - ref)      gravity  r x (0,-w,0) = -w l_cg cos(theta)
    f(theta) = -k (theta - ref) - w l cos(theta) is strictly decreasing (k > w l) -> unique root,
    bracketed by ref -/+ w l / k.
    """
    w = weight(p["mass"])
    wl = w * p["l_cg"]
    k, ref = p["k"], p["ref_angle"]

    def f(t):
        return -k * (t - ref) - wl * math.cos(t)

    lo, hi = ref - 1.01 * wl / k, ref + 1.01 * wl / k
    theta = optimize.brentq(f, lo, hi, xtol=1e-15, rtol=1e-15, maxiter=200)
    cg = np.array([p["l_cg"] * math.cos(theta), p["l_cg"] * math.sin(theta), 0.0])
    return dict(
        theta=theta,
        turns=(theta - p["theta0"]) / (2 * math.pi),
        cg=cg,
        orientation=rot_z(theta),
        # statics of the pendulum: hinge force + weight = 0 (spring is a pure couple);
        # z-moment is carried by the spring, x/y moments vanish (planar) -> hinge torque 0.
        hinge_force=np.array([0.0, w, 0.0]),
        hinge_torque=np.zeros(3),
        spring_torque=-k * (theta - ref),
    )


# ---------------------------------------------------------------------------------------------
# 2. fourbar_spring
# ---------------------------------------------------------------------------------------------
FOURBAR_PARAMS = dict(
    A=(0.0, 0.0),        # crank ground pivot
    D=(400.0, 0.0),      # rocker ground pivot
    a=150.0,             # crank  A-B
    b=350.0,             # coupler B-C
    c=250.0,             # rocker D-C
    m_crank=1.0, m_coupler=2.0, m_rocker=1.5,   # kg, uniform bars (CG at mid-length)
    k=2.0,               # N/mm, spring between C (rocker) and A (ground): diagonal A-C
    free_length=200.0,   # mm
    branch=+1,           # C on the left of B->D (the "open", elbow-up assembly)
    phi_input_offset=math.radians(25.0),   # input crank angle = equilibrium + 25 deg
)


def fourbar_positions(phi, p=FOURBAR_PARAMS):
    """Points A, B, C, D for crank angle phi (algebraic: works with complex phi for complex step)."""
    A = np.array(p["A"], dtype=complex if np.iscomplexobj(phi) else float)
    D = np.array(p["D"], dtype=A.dtype)
    B = A + p["a"] * np.array([np.cos(phi), np.sin(phi)])
    bd = D - B
    d = np.sqrt(bd[0] ** 2 + bd[1] ** 2)
    u = bd / d
    n = np.array([-u[1], u[0]])
    h = (d ** 2 + p["b"] ** 2 - p["c"] ** 2) / (2 * d)
    e = np.sqrt(p["b"] ** 2 - h ** 2)
    C = B + h * u + p["branch"] * e * n
    return A, B, C, D


def fourbar_potential(phi, p=FOURBAR_PARAMS):
    A, B, C, D = fourbar_positions(phi, p)
    y_cr, y_co, y_ro = (A[1] + B[1]) / 2, (B[1] + C[1]) / 2, (C[1] + D[1]) / 2
    vg = weight(p["m_crank"]) * y_cr + weight(p["m_coupler"]) * y_co + weight(p["m_rocker"]) * y_ro
    ac = C - A
    L = np.sqrt(ac[0] ** 2 + ac[1] ** 2)
    return vg + 0.5 * p["k"] * (L - p["free_length"]) ** 2


def fourbar_dV(phi, p=FOURBAR_PARAMS):
    """dV/dphi by complex step (exact to rounding)."""
    h = 1e-30
    return float(np.imag(fourbar_potential(phi + 1j * h, p)) / h)


def _minima_on_circle(dV, n=3600):
    ph = np.linspace(-math.pi, math.pi, n + 1)
    g = np.array([dV(x) for x in ph])
    roots = []
    for i in range(n):
        if g[i] < 0 <= g[i + 1]:           # dV crosses - -> + : a minimum of V
            roots.append(optimize.brentq(dV, ph[i], ph[i + 1], xtol=1e-15, rtol=1e-15))
    return roots


def fourbar_equilibrium(p=FOURBAR_PARAMS):
    """Stable equilibrium (global minimum of V over the full crank revolution)."""
    mins = _minima_on_circle(lambda x: fourbar_dV(x, p))
    phi = min(mins, key=lambda x: float(np.real(fourbar_potential(x, p))))
    return fourbar_state(phi, p) | dict(minima=mins)


def fourbar_state(phi, p=FOURBAR_PARAMS):
    A, B, C, D = (np.real(v) for v in fourbar_positions(phi, p))

    def z3(v):
        return np.array([v[0], v[1], 0.0])

    def ang(v):
        return math.atan2(v[1], v[0])

    return dict(
        phi=phi,
        points=dict(A=z3(A), B=z3(B), C=z3(C), D=z3(D)),
        cg=dict(crank=z3((A + B) / 2), coupler=z3((B + C) / 2), rocker=z3((D + C) / 2)),
        # link body x axes: crank A->B, coupler B->C, rocker D->C; z = global Z
        orientation=dict(crank=rot_z(ang(B - A)), coupler=rot_z(ang(C - B)), rocker=rot_z(ang(C - D))),
        spring_length=float(np.linalg.norm(C - A)),
    )


def fourbar_input(p=FOURBAR_PARAMS):
    eq = fourbar_equilibrium(p)
    return fourbar_state(eq["phi"] + p["phi_input_offset"], p)


# ---------------------------------------------------------------------------------------------
# 3. slider_crank_load
# ---------------------------------------------------------------------------------------------
SLIDER_CRANK_PARAMS = dict(
    r=100.0,             # crank O-A
    l=300.0,             # rod A-B
    m_crank=0.5, m_rod=1.0, m_slider=2.0,   # kg; crank/rod uniform (CG mid-length), slider CG at B
    phi0=math.pi / 2,    # input crank angle
    k=2.0e4,             # N mm / rad rotational spring on the crank pivot (I crank, J ground)
    ref_angle=-0.05,     # rad, spring reference angle = AZ(I,J) with AZ = phi - phi0
    fx=-60.0,            # N, horizontal load on the slider (Force_Vector_OneBody, global axes)
)


def slider_crank_points(phi, p=SLIDER_CRANK_PARAMS):
    r, l = p["r"], p["l"]
    A = np.array([r * math.cos(phi), r * math.sin(phi)])
    B = np.array([r * math.cos(phi) + math.sqrt(l * l - (r * math.sin(phi)) ** 2), 0.0])
    return np.zeros(2), A, B


def slider_crank_dV(phi, p=SLIDER_CRANK_PARAMS):
    """dV/dphi, analytic: V = w_c y_cc + w_r y_rc - fx x_B + k/2 (phi - phi0 - ref)^2."""
    r, l = p["r"], p["l"]
    s, c = math.sin(phi), math.cos(phi)
    dyA = r * c
    dxB = -r * s - (r * r * s * c) / math.sqrt(l * l - (r * s) ** 2)
    return (weight(p["m_crank"]) * dyA / 2 + weight(p["m_rod"]) * dyA / 2
            - p["fx"] * dxB + p["k"] * (phi - p["phi0"] - p["ref_angle"]))


def slider_crank(p=SLIDER_CRANK_PARAMS):
    """Equilibrium by virtual work + crank-pivot reaction by body statics."""
    phi0 = p["phi0"]
    phi = optimize.brentq(lambda x: slider_crank_dV(x, p), phi0 - 1.0, phi0 + 1.0,
                          xtol=1e-15, rtol=1e-15)
    O, A, B = slider_crank_points(phi, p)
    wc, wr = weight(p["m_crank"]), weight(p["m_rod"])
    Gr = (A + B) / 2
    # slider x-balance: force from slider on rod (at B) has x component fx
    FBx = p["fx"]
    FAx = -FBx                                  # rod x-balance
    # rod moment about B: (A-B) x F_A + (Gr-B) x (0,-wr) = 0
    FAy = ((A - B)[1] * FAx + (Gr - B)[0] * wr) / (A - B)[0]
    FA = np.array([FAx, FAy])                   # force of crank on rod at A
    FBy = wr - FAy
    R_O = FA + np.array([0.0, wc])              # crank: R_O - F_A + W_c = 0
    # check crank moment about O (equilibrium equation again)
    spring_t = -p["k"] * (phi - phi0 - p["ref_angle"])
    m_res = spring_t + _cross2(A, -FA) + _cross2(A / 2, [0.0, -wc])

    def z3(v):
        return np.array([v[0], v[1], 0.0])

    u = (B - A) / p["l"]
    return dict(
        phi=phi,
        points=dict(O=z3(O), A=z3(A), B=z3(B)),
        cg=dict(crank=z3(A / 2), rod=z3(Gr), slider=z3(B)),
        # CG marker axes: crank x along O->A, rod x along A->B, slider axes = global
        orientation=dict(crank=rot_z(phi), rod=rot_z(math.atan2(u[1], u[0])), slider=np.eye(3)),
        pivot_force=z3(R_O), pivot_torque=np.zeros(3),
        crankpin_force_on_rod=z3(FA), wristpin_force_on_rod=z3(np.array([FBx, FBy])),
        moment_residual=m_res,
    )


# ---------------------------------------------------------------------------------------------
# 4. double_pendulum
# ---------------------------------------------------------------------------------------------
DOUBLE_PENDULUM_PARAMS = dict(
    l1=300.0, l2=200.0,            # mm
    m1=1.5, m2=1.0,                # kg, uniform links
    k1=3.0e4, k2=1.5e4,            # N mm / rad
    ref1=-0.2,                     # rad, spring 1 reference: AZ(link1, ground) = theta1
    ref2=-0.6,                     # rad, spring 2 reference: AZ(link2, link1) = theta2 - theta1
    theta1_0=-math.pi / 6, theta2_0=-math.pi / 3,   # input absolute link angles
    tip_force=(20.0, -30.0, 0.0),  # N, global, at the tip of link 2
)


def double_pendulum_tip(t, p=DOUBLE_PENDULUM_PARAMS):
    t1, t2 = t
    e1 = np.array([math.cos(t1), math.sin(t1)])
    e2 = np.array([math.cos(t2), math.sin(t2)])
    return p["l1"] * e1, p["l1"] * e1 + p["l2"] * e2


def double_pendulum_potential(t, p=DOUBLE_PENDULUM_PARAMS):
    t1, t2 = t
    elbow, tip = double_pendulum_tip(t, p)
    y1 = elbow[1] / 2
    y2 = (elbow[1] + tip[1]) / 2
    F = p["tip_force"]
    return (0.5 * p["k1"] * (t1 - p["ref1"]) ** 2 + 0.5 * p["k2"] * (t2 - t1 - p["ref2"]) ** 2
            + weight(p["m1"]) * y1 + weight(p["m2"]) * y2 - (F[0] * tip[0] + F[1] * tip[1]))


def double_pendulum_grad(t, p=DOUBLE_PENDULUM_PARAMS):
    t1, t2 = t
    w1, w2 = weight(p["m1"]), weight(p["m2"])
    l1, l2 = p["l1"], p["l2"]
    Fx, Fy = p["tip_force"][:2]
    s2 = p["k2"] * (t2 - t1 - p["ref2"])
    # d(y)/dt1 = l1 cos t1 ; d(x)/dt1 = -l1 sin t1
    g1 = (p["k1"] * (t1 - p["ref1"]) - s2 + (w1 / 2 + w2) * l1 * math.cos(t1)
          - (-Fx * l1 * math.sin(t1) + Fy * l1 * math.cos(t1)))
    g2 = (s2 + w2 / 2 * l2 * math.cos(t2)
          - (-Fx * l2 * math.sin(t2) + Fy * l2 * math.cos(t2)))
    return np.array([g1, g2])


def double_pendulum(p=DOUBLE_PENDULUM_PARAMS):
    """2-D minimisation of the potential from the input configuration, polished with a root solve
    of the analytic gradient; the Hessian is checked positive definite (stable minimum)."""
    x0 = np.array([p["theta1_0"], p["theta2_0"]])
    res = optimize.minimize(double_pendulum_potential, x0, args=(p,), jac=double_pendulum_grad,
                            method="BFGS", options=dict(gtol=1e-10))
    sol = optimize.root(double_pendulum_grad, res.x, args=(p,), tol=1e-14)
    t1, t2 = sol.x
    # numerical Hessian of the analytic gradient
    h = 1e-6
    H = np.column_stack([(double_pendulum_grad(sol.x + h * e, p) - double_pendulum_grad(sol.x - h * e, p)) / (2 * h)
                         for e in np.eye(2)])
    elbow, tip = double_pendulum_tip(sol.x, p)

    def z3(v):
        return np.array([v[0], v[1], 0.0])

    w1, w2 = weight(p["m1"]), weight(p["m2"])
    F = np.array(p["tip_force"])
    return dict(
        theta=sol.x, minimise_theta=res.x, hessian=H, grad=double_pendulum_grad(sol.x, p),
        cg=dict(link1=z3(elbow / 2), link2=z3((elbow + tip) / 2)),
        points=dict(elbow=z3(elbow), tip=z3(tip)),
        # CG markers: x along the link, identity rotated by the link angle
        orientation=dict(link1=rot_z(t1), link2=rot_z(t2)),
        # base revolute on link1: minus every other external force on the system
        base_force=-(np.array([0.0, -w1 - w2, 0.0]) + F),
        # elbow revolute (I on link2): minus (weight of link 2 + tip load)
        elbow_force=-(np.array([0.0, -w2, 0.0]) + F),
    )


# ---------------------------------------------------------------------------------------------
# 5. bushing_block
# ---------------------------------------------------------------------------------------------
BUSHING_PARAMS = dict(
    mass=5.0,
    cg0=(100.0, -200.0, 50.0),     # input CG (= bushing I and J origin), block axes = global
    kx=800.0, ky=1200.0, kz=1000.0,          # N/mm
    ktx=2.0e5, kty=2.0e5, ktz=1.0e5,         # N mm / rad
    preload_y=20.0,                          # N (other preloads zero)
    load=(30.0, -80.0, 0.0),                 # N, global, at CG + offset
    offset=(150.0, 0.0, 0.0),                # mm, load point relative to CG (body x axis)
)


def bushing_block(p=BUSHING_PARAMS):
    """Exact equilibrium: the load lies in the XY plane and acts at an offset along the body x axis,
    so the block translates in X, Y and rotates about Z only (AX = AY = 0, AZ = theta exactly).
    Forces on the block: -K D + preload + weight + load = 0 -> D per axis.
    Moment about the CG (= I marker, so the bushing force has no moment):
        -ktz theta + (R(theta) e) x P = 0,  with e = (e, 0, 0): -ktz theta + e (cos t Py - sin t Px) = 0.
    """
    w = weight(p["mass"])
    Px, Py, Pz = p["load"]
    e = p["offset"][0]
    dx = Px / p["kx"]
    dy = (p["preload_y"] - w + Py) / p["ky"]
    dz = Pz / p["kz"]

    def f(t):
        return -p["ktz"] * t + e * (math.cos(t) * Py - math.sin(t) * Px)

    bound = 1.01 * e * math.hypot(Px, Py) / p["ktz"]
    theta = optimize.brentq(f, -bound, bound, xtol=1e-15, rtol=1e-15)
    cg = np.array(p["cg0"]) + np.array([dx, dy, dz])
    return dict(theta=theta, displacement=np.array([dx, dy, dz]), cg=cg,
                orientation=rot_z(theta),
                load_point=cg + rot_z(theta) @ np.array(p["offset"]))


# ---------------------------------------------------------------------------------------------
# 6. hanging chain (discrete catenary)
# ---------------------------------------------------------------------------------------------
CHAIN_DEFAULTS = dict(link_length=100.0, mass=1.0, span_ratio=0.8)


def catenary_angles(n, a, m, span):
    """Closed-form discrete catenary: link k (1..n) from pin k-1 to pin k descends at angle theta_k
    below the horizontal, tan theta_k = w (n/2 - k + 1/2) / H, H from sum a cos theta_k = span.

    Derivation: the pin force transmitted across node k is (H, k w - n w/2) (pin 0 carries half the
    weight); moment balance of link k about its CG gives f_R - f_L parallel to the link.
    """
    w = weight(m)
    kk = np.arange(1, n + 1)
    c = w * (n / 2 - kk + 0.5)

    def closure(H):
        return float(np.sum(a / np.sqrt(1.0 + (c / H) ** 2))) - span

    if not 0 < span < n * a:
        raise ValueError("span must be in (0, n*a)")
    lo, hi = 1e-12 * w, w * n
    while closure(hi) < 0:
        hi *= 2
    while closure(lo) > 0:
        lo /= 2
    H = optimize.brentq(closure, lo, hi, xtol=1e-14 * w, rtol=1e-15, maxiter=500)
    theta = np.arctan(c / H)
    return theta, H


def catenary(n, a=CHAIN_DEFAULTS["link_length"], m=CHAIN_DEFAULTS["mass"], span=None):
    """Nodes, link CGs, link x-axes and end-pin reactions of the hanging chain.

    Pins at (0,0,0) and (span,0,0). Reaction of the left pin joint on link 1 (the joint's I body):
    (-H, n w/2, 0); of the right pin joint on link n: (+H, n w/2, 0).
    """
    if span is None:
        span = CHAIN_DEFAULTS["span_ratio"] * n * a
    theta, H = catenary_angles(n, a, m, span)
    steps = a * np.column_stack([np.cos(theta), -np.sin(theta), np.zeros(n)])
    nodes = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
    cg = 0.5 * (nodes[:-1] + nodes[1:])
    w = weight(m)
    return dict(theta=theta, H=H, nodes=nodes, cg=cg, xaxis=steps / a,
                left_force=np.array([-H, n * w / 2, 0.0]),
                right_force=np.array([H, n * w / 2, 0.0]),
                closure_error=float(np.linalg.norm(nodes[-1] - [span, 0.0, 0.0])))


def catenary_by_minimisation(n, a, m, span):
    """Independent check: minimise sum w y_cg over link angles phi_k (direction of link k measured
    counter-clockwise from +X) subject to the closure sum a (cos, sin) = (span, 0)."""
    w = weight(m)

    def nodes_y(phi):
        return np.concatenate([[0.0], np.cumsum(a * np.sin(phi))])

    def V(phi):
        y = nodes_y(phi)
        return w * float(np.sum(0.5 * (y[:-1] + y[1:])))

    def V_grad(phi):
        # y_cg,j = sum_{i<j} a sin phi_i + a/2 sin phi_j
        g = np.empty(n)
        for i in range(n):
            g[i] = w * a * math.cos(phi[i]) * ((n - 1 - i) + 0.5)
        return g

    cons = [dict(type="eq", fun=lambda phi: np.array([np.sum(a * np.cos(phi)) - span,
                                                      np.sum(a * np.sin(phi))]),
                 jac=lambda phi: np.vstack([-a * np.sin(phi), a * np.cos(phi)]))]
    # start: symmetric V shape that roughly closes
    x0 = np.where(np.arange(n) < n / 2, -0.5, 0.5)
    res = optimize.minimize(V, x0, jac=V_grad, constraints=cons, method="SLSQP",
                            options=dict(ftol=1e-15, maxiter=1000))
    return res


def chain_arc(n, a, span):
    """Input configuration of the generated chain decks: nodes on a circular arc (centre above the
    span) with n equal chords a between (0,0) and (span,0). Satisfies every joint exactly."""
    def f(alpha):
        return a * math.sin(n * alpha / 2) / math.sin(alpha / 2) - span
    alpha = optimize.brentq(f, 1e-12, 2 * math.pi / n * (1 - 1e-12), xtol=1e-16, rtol=1e-15)
    R = a / (2 * math.sin(alpha / 2))
    t = n * alpha / 2
    centre = np.array([R * math.sin(t), R * math.cos(t)])
    psi = -math.pi / 2 - t + alpha * np.arange(n + 1)
    xy = centre + R * np.column_stack([np.cos(psi), np.sin(psi)])
    xy[0] = (0.0, 0.0)
    xy[-1] = (span, 0.0)
    return np.column_stack([xy, np.zeros(n + 1)])
