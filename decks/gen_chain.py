#!/usr/bin/env python3
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

Only the standard library is used, so the script runs anywhere. The generator itself lives in
``poise.gen.chain`` (found through ``../src`` when poise is not installed); this file is its
command line, and its output is byte-identical.
"""
from __future__ import annotations

import sys
from pathlib import Path

try:
    from poise.gen import chain as _chain
except ImportError:  # a checkout without the package installed
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "src"))
    from poise.gen import chain as _chain

LINK_RADIUS = _chain.LINK_RADIUS
arc_nodes = _chain.arc_nodes
build_chain_deck = _chain.build_chain_deck


def main(argv=None) -> int:
    return _chain.main(argv)


if __name__ == "__main__":
    raise SystemExit(main())
