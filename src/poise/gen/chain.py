"""Generate a hanging-chain deck: N identical rigid links pinned to ground at both ends.

    python decks/gen_chain.py N --joint revolute|spherical [--span S] [--link-length A]
                             [--mass M] [--start arc|v] [-o FILE]

Units N-kg-mm-s, gravity -9810 mm/s^2 along global -Y. Pins at (0,0,0) and (S,0,0); default span
S = 0.8 * N * A. The input configuration puts the N+1 pin points on a circular arc with N equal
chords A (centre above the span): every joint equation holds exactly in the input configuration
(to printing precision, 17 significant digits), so no assembly is needed. It is *not* the
equilibrium (the discrete catenary), so the solver has work to do. ``--start v`` puts the pins on
a V instead (two straight legs of N//2 and N - N//2 links): Newton from there tends to an
unstable equilibrium (kinked links), the test case of ``--require-stable`` and MKEAM.

Each link k (1..N) is body k+1 (ground is body 1), a uniform bar of mass M with its CG at
mid-length. Its markers (CG 10k+1, start pin 10k+2, end pin 10k+3) all have x along the link
(start -> end), z = global Z. Joint j (1..N+1) sits at pin j-1: joint 1 I = link 1 start, J =
ground marker 2; joint j I = link j start, J = link j-1 end; joint N+1 I = link N end, J = ground
marker 3.

* ``--joint revolute``: a planar closed loop built from 3-D revolutes: 5(N+1) equations for 6N
  coordinates, N-2 degrees of freedom, exactly 3 redundant equations (out-of-plane).
* ``--joint spherical``: 3(N+1) equations, not redundant, but every link can spin freely about its
  own axis (N neutral directions); the deck sets ``Param_Static stability="1.0E-4"`` so FIM's
  Newton matrix stays non-singular (stability never changes the converged answer).

Only the standard library is used, so the script runs anywhere. ``decks/gen_chain.py`` is the
command-line front end (its output is byte-identical); ``benchmarks.chain`` generates its chains here.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

LINK_RADIUS = 5.0  # mm, only for the (irrelevant in statics) inertia of a thin bar


def _f(x: float) -> str:
    x = float(x)
    if x == 0.0:
        return "0."
    return repr(x)


def _bisect(f, lo, hi, tol=0.0, maxiter=400):
    flo = f(lo)
    for _ in range(maxiter):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        fm = f(mid)
        if (fm > 0) == (flo > 0):
            lo, flo = mid, fm
        else:
            hi = mid
    return 0.5 * (lo + hi)


def arc_nodes(n: int, a: float, span: float) -> list[tuple[float, float]]:
    """N+1 points on a circular arc, consecutive points a apart, from (0,0) to (span,0), sagging
    below the span. Chord angle alpha solves a sin(n alpha/2)/sin(alpha/2) = span."""
    if not 0.0 < span < n * a:
        raise ValueError(f"span must be in (0, N*link_length) = (0, {n * a})")
    # g(alpha) decreases from n*a (alpha -> 0) to 0 (alpha = 2 pi / n)
    alpha = _bisect(lambda al: a * math.sin(n * al / 2) / math.sin(al / 2) - span,
                    1e-15, 2 * math.pi / n)
    R = a / (2 * math.sin(alpha / 2))
    t = n * alpha / 2
    cx, cy = R * math.sin(t), R * math.cos(t)
    pts = []
    for k in range(n + 1):
        psi = -math.pi / 2 - t + alpha * k
        pts.append((cx + R * math.cos(psi), cy + R * math.sin(psi)))
    pts[0] = (0.0, 0.0)
    pts[-1] = (float(span), 0.0)
    return pts


def v_nodes(n: int, a: float, span: float) -> list[tuple[float, float]]:
    """N+1 points forming a V: two straight legs of N//2 and N - N//2 links (each a long) from
    (0,0) and (span,0) meeting at a vertex below the span. Every joint holds exactly; the
    straight legs are kinked-link (unstable) equilibria of the legs, so Newton from here tends
    to an unstable equilibrium of the chain."""
    if not 0.0 < span < n * a:
        raise ValueError(f"span must be in (0, N*link_length) = (0, {n * a})")
    n1 = n // 2
    n2 = n - n1
    l1, l2 = n1 * a, n2 * a
    # vertex: |P| = l1, |P - (span,0)| = l2, below the span
    x = (l1 * l1 - l2 * l2 + span * span) / (2 * span)
    y = -math.sqrt(max(l1 * l1 - x * x, 0.0))
    pts = [(x * k / n1, y * k / n1) for k in range(n1 + 1)]
    pts += [(x + (span - x) * k / n2, y - y * k / n2) for k in range(1, n2 + 1)]
    pts[-1] = (float(span), 0.0)
    return pts


def _marker(mid, body, pos, x_axis, label):
    ux, uy = x_axis
    # columns: x = (ux, uy, 0), y = z cross x = (-uy, ux, 0), z = (0, 0, 1)
    return (f'    <Reference_Marker id="{mid}" label="{label}" body_id="{body}" body_type="RIGIDBODY"\n'
            f'        pos_x="{_f(pos[0])}" pos_y="{_f(pos[1])}" pos_z="0."\n'
            f'        a00="{_f(ux)}" a10="{_f(uy)}" a20="0." a01="{_f(-uy)}" a11="{_f(ux)}" a21="0."'
            f' a02="0." a12="0." a22="1."/>\n')


def build_chain_deck(n: int, joint: str = "revolute", span: float | None = None,
                     link_length: float = 100.0, mass: float = 1.0, start: str = "arc") -> str:
    """Return the XML text of the chain deck (``start``: ``arc`` or ``v``, the input shape)."""
    joint = joint.lower()
    if joint not in ("revolute", "spherical"):
        raise ValueError("joint must be 'revolute' or 'spherical'")
    if n < 2:
        raise ValueError("need at least 2 links")
    a = float(link_length)
    if span is None:
        span = 0.8 * n * a
    span = float(span)
    if start not in ("arc", "v"):
        raise ValueError("start must be 'arc' or 'v'")
    pts = arc_nodes(n, a, span) if start == "arc" else v_nodes(n, a, span)
    stab = ' stability="1.0E-4"' if joint == "spherical" else ""
    ixx = 0.5 * mass * LINK_RADIUS ** 2
    iyy = mass * a * a / 12.0 + 0.25 * mass * LINK_RADIUS ** 2
    jt = joint.upper()
    out = []
    out.append('<?xml version="1.0" encoding="UTF-8"?>\n')
    out.append(f"<!-- Hanging chain: {n} rigid links ({a:g} mm, {mass:g} kg each), {jt} joints,\n"
               f"     pinned to ground at (0,0,0) and ({span:g},0,0). Input configuration: "
               f"{'circular arc' if start == 'arc' else 'V (two straight legs)'}\n"
               f"     satisfying every joint exactly. Generated by decks/gen_chain.py with\n"
               f"     N={n} joint={joint} span={span!r} link_length={a!r} mass={mass!r}"
               + (" start=v" if start == "v" else "") + "\n")
    if joint == "revolute":
        out.append("     3-D revolutes in a planar loop: 3 redundant (out-of-plane) equations. -->\n")
    else:
        out.append("     Each link spins freely about its own axis (neutral): stability=1e-4. -->\n")
    out.append("<MotionSolve>\n  <Model>\n")
    out.append('    <Param_Unit force_unit="NEWTON" mass_unit="KILOGRAM" length_unit="MILLIMETER" time_unit="SECOND"/>\n')
    out.append('    <Force_Gravity grav_x="0." grav_y="-9810." grav_z="0."/>\n')
    out.append(f'    <Param_Static method="FIM_S" max_num_iter="100" max_imbalance="1.0E-8" max_error="1.0E-8"{stab}/>\n')
    out.append('    <Body_Rigid id="1" label="Ground" isground="TRUE" cg_id="1" lprf_id="1"/>\n')
    out.append(_marker(1, 1, (0.0, 0.0), (1.0, 0.0), "Ground origin"))
    out.append(_marker(2, 1, pts[0], (1.0, 0.0), "Left pin J"))
    out.append(_marker(3, 1, pts[-1], (1.0, 0.0), "Right pin J"))
    for k in range(1, n + 1):
        (x0, y0), (x1, y1) = pts[k - 1], pts[k]
        dx, dy = x1 - x0, y1 - y0
        L = math.hypot(dx, dy)
        u = (dx / L, dy / L)
        body = k + 1
        out.append(f'    <Body_Rigid id="{body}" label="Link {k}" cg_id="{10 * k + 1}" lprf_id="{10 * k + 1}" mass="{_f(mass)}"\n'
                   f'        inertia_xx="{_f(ixx)}" inertia_yy="{_f(iyy)}" inertia_zz="{_f(iyy)}"'
                   f' inertia_xy="0." inertia_yz="0." inertia_xz="0."/>\n')
        out.append(_marker(10 * k + 1, body, ((x0 + x1) / 2, (y0 + y1) / 2), u, f"Link {k} CG"))
        out.append(_marker(10 * k + 2, body, (x0, y0), u, f"Link {k} start pin"))
        out.append(_marker(10 * k + 3, body, (x1, y1), u, f"Link {k} end pin"))
    for j in range(1, n + 2):
        if j == 1:
            i_m, j_m = 12, 2
        elif j == n + 1:
            i_m, j_m = 10 * n + 3, 3
        else:
            i_m, j_m = 10 * j + 2, 10 * (j - 1) + 3
        out.append(f'    <Constraint_Joint id="{j}" label="Pin {j - 1}" type="{jt}"'
                   f' i_marker_id="{i_m}" j_marker_id="{j_m}"/>\n')
    out.append("  </Model>\n  <Command>\n    <Simulate analysis_type=\"Static\"/>\n    <Stop/>\n"
               "  </Command>\n</MotionSolve>\n")
    return "".join(out)


def main(argv=None, prog: str | None = None) -> int:
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("n", type=int, help="number of links")
    ap.add_argument("--joint", choices=("revolute", "spherical"), default="revolute")
    ap.add_argument("--span", type=float, default=None, help="pin distance, mm (default 0.8*N*A)")
    ap.add_argument("--link-length", type=float, default=100.0, help="link length A, mm")
    ap.add_argument("--mass", type=float, default=1.0, help="link mass, kg")
    ap.add_argument("--start", choices=("arc", "v"), default="arc",
                    help="input shape: circular arc (default) or V (two straight legs)")
    ap.add_argument("-o", "--output", default=None,
                    help="output file (default chain_N.xml / chain_N_spherical.xml; '-' = stdout)")
    args = ap.parse_args(argv)
    try:
        text = build_chain_deck(args.n, args.joint, args.span, args.link_length, args.mass,
                                args.start)
    except ValueError as exc:
        ap.error(str(exc))
    out = args.output
    if out is None:
        out = f"chain_{args.n}.xml" if args.joint == "revolute" else f"chain_{args.n}_spherical.xml"
    if out == "-":
        sys.stdout.write(text)
    else:
        Path(out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
