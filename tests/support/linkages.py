"""Driven linkages and loaded structures for the singular-configuration tests, with their
closed forms (independent of poise): a slider-crank whose slider is driven, a crank-rocker
four-bar driven at the rocker, a delta-like translational parallel robot (3-RUU, Tsai), a von
Mises truss (limit point), a column under a growing load (bifurcation) and a block following an
SHF-driven slider through soft springs (frame error at a motion reversal). Units N-kg-mm-s."""
from __future__ import annotations

import math

import numpy as np

from poise.gen.deck import Deck, rot_z

X_ALONG = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # marker z = global X
Y_ALONG = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])   # marker z = global Y


def quasistatic(d: Deck, end: float = 1.0, interval: float = 0.02) -> Deck:
    d.commands = [f'<Simulate analysis_type="Quasistatic" end_time="{end!r}" '
                  f'print_interval="{interval!r}"/>', "<Stop/>"]
    return d


def frame_z(z) -> np.ndarray:
    """Marker axes (columns) with the given z axis."""
    z = np.asarray(z, float) / np.linalg.norm(z)
    h = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = h - (h @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


# ------------------------------------------------------------------ slider-crank
SC_R, SC_L = 100.0, 300.0


def crank_angle(x, r=SC_R, l=SC_L):
    """Crank angle of the slider-crank with the slider at ``x`` on the upper branch:
    cos(theta) = (x^2 + r^2 - l^2) / (2 x r)."""
    x = np.asarray(x, float)
    return np.arccos((x * x + r * r - l * l) / (2.0 * x * r))


def slider_crank(expr: str, method: str = "FIM_S", interval: float = 0.02, x0: float = 300.0,
                 static: dict | None = None) -> Deck:
    """Crank (100 mm) pivoted at the origin, rod (300 mm), slider on global X whose position
    is driven: ``Motion_Joint`` on the slide, x(t) = ``expr`` (x0 at t = 0). Gravity -Y. Joints
    revolute, spherical, universal, translational: no redundant equation, 0 DOF."""
    d = Deck(units="mm", method=method, static=static)
    th = float(crank_angle(x0))
    A = np.array([SC_R * math.cos(th), SC_R * math.sin(th), 0.0])
    B = np.array([x0, 0.0, 0.0])
    d.ground(1, 100)
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, (0, 0, 0), X_ALONG)
    d.body(2, 200, A / 2, rot_z(th), mass=0.5, inertia=(6.25, 420.0, 420.0))
    d.marker(201, 2, (0, 0, 0))
    d.marker(202, 2, A)
    u = (B - A) / SC_L
    d.body(3, 300, (A + B) / 2, rot_z(math.atan2(u[1], u[0])), mass=1.0,
           inertia=(12.5, 7500.0, 7500.0))
    d.marker(301, 3, A)
    d.marker(302, 3, B, X_ALONG)
    d.body(4, 400, B, mass=2.0, inertia=(500.0, 500.0, 500.0))
    d.marker(401, 4, B)
    d.marker(402, 4, B, X_ALONG)
    for jid, label, typ, i, j in ((1, "Crank pivot", "REVOLUTE", 201, 101),
                                  (2, "Crank pin", "SPHERICAL", 301, 202),
                                  (3, "Wrist pin", "UNIVERSAL", 302, 401),
                                  (4, "Slide", "TRANSLATIONAL", 402, 102)):
        d.add("Constraint_Joint", id=jid, label=label, type=typ, i_marker_id=i, j_marker_id=j)
    d.add("Motion_Joint", id=1, label="Slider drive", joint_id=4, joint_type="T", val_type="D",
          type="EXPRESSION", expr=expr)
    return quasistatic(d, interval=interval)


# ------------------------------------------------------------------ four-bar
FB = dict(a=40.0, b=120.0, c=80.0, d=100.0)     # crank, coupler, rocker, ground


def fourbar_dead_time(rate_deg: float, p=FB) -> float:
    """The rocker, driven from 90 deg down at ``rate_deg`` deg/s, reaches the dead point where
    crank and coupler are collinear (|B| = a + b): cos(phi) = ((a+b)^2 - d^2 - c^2) / (2 d c)."""
    a, b, c, d = p["a"], p["b"], p["c"], p["d"]
    phi = math.degrees(math.acos(((a + b) ** 2 - d * d - c * c) / (2 * d * c)))
    return (90.0 - phi) / rate_deg


def fourbar(rate_deg: float = 60.0, method: str = "FIM_S", interval: float = 0.02,
            p=FB) -> Deck:
    """Crank-rocker four-bar (all revolute: 3 redundant equations), rocker pivot driven from
    90 deg at -rate deg/s; gravity -Y."""
    a, b, c, dd = p["a"], p["b"], p["c"], p["d"]
    B = np.array([dd, c, 0.0])
    # crank pin A on the crank circle at distance b from B (upper solution)
    base = math.atan2(B[1], B[0])
    al = base + math.acos((a * a + B @ B - b * b) / (2 * a * math.hypot(B[0], B[1])))
    A = np.array([a * math.cos(al), a * math.sin(al), 0.0])
    O4 = np.array([dd, 0.0, 0.0])
    d = Deck(units="mm", method=method)
    d.ground(1, 100)
    d.marker(101, 1, (0, 0, 0))
    d.marker(102, 1, O4)
    d.body(2, 200, A / 2, rot_z(al), mass=0.2, inertia=(10.0, 30.0, 30.0))
    d.marker(201, 2, (0, 0, 0))
    d.marker(202, 2, A)
    u = B - A
    d.body(3, 300, (A + B) / 2, rot_z(math.atan2(u[1], u[0])), mass=0.5,
           inertia=(10.0, 600.0, 600.0))
    d.marker(301, 3, A)
    d.marker(302, 3, B)
    d.body(4, 400, (O4 + B) / 2, rot_z(math.pi / 2), mass=0.3, inertia=(10.0, 160.0, 160.0))
    d.marker(401, 4, B)
    d.marker(402, 4, O4)
    for jid, label, i, j in ((1, "Crank pivot", 201, 101), (2, "Crank pin", 301, 202),
                             (3, "Rocker pin", 302, 401), (4, "Rocker pivot", 402, 102)):
        d.add("Constraint_Joint", id=jid, label=label, type="REVOLUTE", i_marker_id=i,
              j_marker_id=j)
    d.add("Motion_Joint", id=1, label="Rocker drive", joint_id=4, joint_type="R", val_type="D",
          type="EXPRESSION", expr=f"-{rate_deg!r}D*TIME")
    return quasistatic(d, interval=interval)


# ------------------------------------------------------------------ delta-like robot
DELTA = dict(rb=50.0, rp=20.0, a=40.0, l=60.0)   # base radius, platform radius, arm, forearm


def delta_height(theta, p=DELTA):
    """Platform height of the 3-RUU robot with every arm at ``theta`` [rad] below the
    horizontal (lower assembly): z = -a sin(theta) - sqrt(l^2 - (rb - rp + a cos(theta))^2)."""
    theta = np.asarray(theta, float)
    R = p["rb"] - p["rp"] + p["a"] * np.cos(theta)
    return -p["a"] * np.sin(theta) - np.sqrt(p["l"] ** 2 - R * R)


def delta_boundary_angle(p=DELTA) -> float:
    """Arm angle [deg] where the forearms reach the horizontal (the workspace boundary)."""
    return math.degrees(math.acos((p["l"] - p["rb"] + p["rp"]) / p["a"]))


def delta(expr: str, method: str = "FIM_S", interval: float = 0.05, p=DELTA) -> Deck:
    """Delta-like translational parallel robot (Tsai's 3-RUU): three arms on revolute
    shoulders at 120 deg, each driven (``Motion_Joint``, AZ = ``expr``, from 90 deg: arms
    straight down), forearms with a universal joint at each end (axes parallel to the
    shoulder's and perpendicular to the forearm), a platform that can only translate; gravity
    -Z. 0 DOF, no redundant equation; about 0.1 m across."""
    rb, rp, a, l = p["rb"], p["rp"], p["a"], p["l"]
    th = math.pi / 2
    z0 = float(delta_height(th, p))
    P0 = np.array([0.0, 0.0, z0])
    d = Deck(units="mm", grav=(0.0, 0.0, -9810.0), method=method)
    d.ground(1, 100)
    d.body(10, 1000, P0, mass=0.3, inertia=(50.0, 50.0, 80.0))
    for i in range(3):
        ph = math.radians(120.0 * i)
        e = np.array([math.cos(ph), math.sin(ph), 0.0])
        ax = np.array([-math.sin(ph), math.cos(ph), 0.0])
        B = rb * e
        E = B + a * (math.cos(th) * e - math.sin(th) * np.array([0.0, 0.0, 1.0]))
        P = P0 + rp * e
        w = np.cross(ax, (P - E) / l)
        arm, fore = 20 + i, 30 + i
        d.body(arm, 100 * arm, (B + E) / 2, frame_z(E - B), mass=0.1, inertia=(1.0, 15.0, 15.0))
        d.body(fore, 100 * fore, (E + P) / 2, frame_z(P - E), mass=0.05,
               inertia=(0.5, 15.0, 15.0))
        d.marker(100 * arm + 1, arm, B, frame_z(ax))
        d.marker(110 + i, 1, B, frame_z(ax))
        d.marker(100 * arm + 2, arm, E, frame_z(ax))
        d.marker(100 * fore + 1, fore, E, frame_z(w))
        d.marker(100 * fore + 2, fore, P, frame_z(w))
        d.marker(1010 + i, 10, P, frame_z(ax))
        for jid, label, typ, I, J in ((1 + 3 * i, f"Shoulder {i + 1}", "REVOLUTE", 100 * arm + 1,
                                       110 + i),
                                      (2 + 3 * i, f"Elbow {i + 1}", "UNIVERSAL", 100 * fore + 1,
                                       100 * arm + 2),
                                      (3 + 3 * i, f"Wrist {i + 1}", "UNIVERSAL", 100 * fore + 2,
                                       1010 + i)):
            d.add("Constraint_Joint", id=jid, label=label, type=typ, i_marker_id=I, j_marker_id=J)
        d.add("Motion_Joint", id=1 + i, label=f"Arm drive {i + 1}", joint_id=1 + 3 * i,
              joint_type="R", val_type="D", type="EXPRESSION", expr=expr)
    return quasistatic(d, interval=interval)


# ------------------------------------------------------------------ limit point, bifurcation
VM = dict(a=100.0, h=50.0, k=10.0, c=40.0)   # half span, rise, spring N/mm, load rate N/s


def vonmises_limit_time(p=VM) -> float:
    """Von Mises truss (slider on a vertical guide, spring to (a, 0) of free length
    sqrt(a^2+h^2)) under a load c t down: P(y) = k y (L0 / sqrt(a^2 + y^2) - 1) peaks where
    sqrt(a^2 + y^2)^3 = L0 a^2; the limit point is at P_max / c."""
    a, h, k = p["a"], p["h"], p["k"]
    L0 = math.hypot(a, h)
    L = (L0 * a * a) ** (1.0 / 3.0)
    y = math.sqrt(L * L - a * a)
    return k * y * (L0 / L - 1.0) / p["c"]


def vonmises(method: str = "FIM_S", interval: float = 0.1, p=VM) -> Deck:
    a, h = p["a"], p["h"]
    d = Deck(units="mm", grav=None, method=method)
    d.ground(1, 100)
    d.marker(101, 1, (0, 0, 0), Y_ALONG)
    d.marker(102, 1, (a, 0, 0))
    d.body(2, 200, (0, h, 0), mass=1.0, inertia=(100.0, 100.0, 100.0))
    d.marker(201, 2, (0, h, 0), Y_ALONG)
    d.add("Constraint_Joint", id=1, label="Guide", type="TRANSLATIONAL", i_marker_id=201,
          j_marker_id=101)
    d.spring(1, 200, 102, p["k"], math.hypot(a, h))
    d.add("Force_Vector_OneBody", id=2, type="FORCEONLY", marker_id=200, ref_marker_id=0,
          fx_expression="0", fy_expression=f"-{p['c']!r}*TIME", fz_expression="0")
    return quasistatic(d, interval=interval)


COLUMN = dict(l=500.0, k=1e5, c=400.0)   # length, base spring N mm/rad, load rate N/s


def column_critical_time(p=COLUMN) -> float:
    """Rigid column on a hinge with a rotational spring k, axial load c t at the top: the
    upright equilibrium loses stability where k = P l (P = k / l)."""
    return p["k"] / p["l"] / p["c"]


def column(method: str = "FIM_S", interval: float = 0.1, p=COLUMN) -> Deck:
    d = Deck(units="mm", grav=None, method=method)
    d.ground(1, 100)
    d.marker(101, 1, (0, 0, 0))
    d.body(2, 200, (0, p["l"] / 2, 0), mass=1.0, inertia=(1e4, 1e2, 1e4))
    d.marker(201, 2, (0, 0, 0))
    d.marker(202, 2, (0, p["l"], 0))
    d.add("Constraint_Joint", id=1, label="Base hinge", type="REVOLUTE", i_marker_id=201,
          j_marker_id=101)
    d.spring(1, 201, 101, p["k"], 0.0, rotational=True)
    d.add("Force_Vector_OneBody", id=2, type="FORCEONLY", marker_id=202, ref_marker_id=0,
          fx_expression="0", fy_expression=f"-{p['c']!r}*TIME", fz_expression="0")
    return quasistatic(d, interval=interval)


# ------------------------------------------------------------------ frame error at a reversal
SHF = dict(force=0.05, k=1e-3)   # load amplitude N, spring N/mm


def shf_block(t, p=SHF):
    """Block position under the load F = force sin(2 pi t) against the spring k (free length
    100 from the anchor at the origin): x = 100 + F / k."""
    return 100.0 + p["force"] * np.sin(2.0 * np.pi * np.asarray(t, float)) / p["k"]


def shf_reversal(method: str = "FIM_S", interval: float = 0.05, p=SHF,
                 static: dict | None = None) -> Deck:
    """A block on a guide along X held by a soft spring to the origin and pushed by an ``SHF``
    load: its motion reverses at t = 0.25 and 0.75. The deck's ``Param_Static`` gives only the
    method (default tolerances) unless ``static`` is given: the equilibrium is soft (1e-3
    N/mm), so a residual within ``max_imbalance`` can be 0.1 mm from it."""
    d = Deck(units=None)
    d.add("Param_Unit", force_unit="NEWTON", mass_unit="KILOGRAM", length_unit="MILLIMETER",
          time_unit="SECOND")
    d.add("Param_Static", method=method, **(static or {}))
    d.ground(1, 100)
    d.marker(101, 1, (0, 0, 0), X_ALONG)
    d.marker(102, 1, (200, 0, 0))
    d.body(2, 200, (100, 0, 0), mass=1.0, inertia=(100.0, 100.0, 100.0))
    d.marker(201, 2, (100, 0, 0), X_ALONG)
    d.add("Constraint_Joint", id=1, label="Guide", type="TRANSLATIONAL", i_marker_id=201,
          j_marker_id=101)
    d.spring(1, 200, 100, p["k"], 100.0)
    d.add("Force_Vector_OneBody", id=2, label="Load", type="FORCEONLY", marker_id=200,
          ref_marker_id=0, fx_expression=f"SHF(TIME, 0, {p['force']!r}, 360D, 0, 0)",
          fy_expression="0", fz_expression="0")
    return quasistatic(d, interval=interval)


def loaded_slide(fx: str, method: str = "FIM_S", interval: float = 0.1) -> Deck:
    """A 2 kg block on a guide along X at the origin, load ``fx`` (an expression of TIME and
    DX(200, 100)): x = 0 is an equilibrium of every frame when the load vanishes there."""
    d = Deck(units=None)
    d.add("Param_Unit", force_unit="NEWTON", mass_unit="KILOGRAM", length_unit="METER",
          time_unit="SECOND")
    d.add("Param_Static", method=method, max_imbalance=1e-8, max_error=1e-8)
    d.ground(1, 100)
    d.marker(101, 1, (0, 0, 0), X_ALONG)
    d.body(2, 200, (0, 0, 0), mass=2.0, inertia=(1.0, 1.0, 1.0))
    d.marker(201, 2, (0, 0, 0), X_ALONG)
    d.add("Constraint_Joint", id=1, type="TRANSLATIONAL", i_marker_id=201, j_marker_id=101)
    d.add("Force_Vector_OneBody", id=2, type="FORCEONLY", marker_id=200, ref_marker_id=0,
          fx_expression=fx, fy_expression="0", fz_expression="0")
    return quasistatic(d, interval=interval)
