"""Stability results: the classes, the mode description and the datasets they are written to.

:class:`StabilityInfo` (class, inertia counts, described :class:`Mode` s) is what both
classification paths (:mod:`poise.solvers.stability` dense, :mod:`poise.solvers.stability_sparse`)
return; :func:`describe_mode` names a mode by the body that moves most. Kept apart from the
eigen-solves so the results side needs neither. Method: docs/stability.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DENSE_LIMIT = 300       # coordinates; dense cost grows as nq^3 (3000: 30 s, sparse 0.05 s)
ZERO_REL = 1e-8
NOISE_REL = 1e-14      # round-off level of a stiffness entry, relative to its matrix or rows
# relative floor of the diagonal in the equilibrations (x ||K_s||): round-off (NOISE_REL x
# ||K_s||) is never magnified beyond a tenth of the zero threshold, so an exactly zero direction
# (a free spin) is zero whatever the sign of its rounding errors
DIAG_FLOOR = 10.0 * NOISE_REL / ZERO_REL
# sparse path (nq > DENSE_LIMIT)
N_MODES = 6            # modes described per class (as the dense path)
AUG_RHO = (1.0, 16.0, 1.0 / 16.0)   # augmented-Lagrangian weights tried in turn (inertia-neutral)
BERR_MAX = 1e-2        # LDL^T backward-error estimate allowed, as a fraction of the zero threshold
SMALL_OP = 64          # mode operators up to this size are decomposed densely
LOW_BLOCK = 1          # vectors per step of a stable frame's lowest-mode Krylov iteration
LOW_ANGLE = 1e-5       # ... its Ritz vector's angle bound at which the mode is taken
LOW_MAX = 12           # ... and its steps (solves) at most
WEAK_DIAG = 1e-3       # scaled augmented diagonal below this: eliminated after its neighbours
TINY_PIVOT = 1e-3      # pivots below this fraction of the zero threshold: sign not reliable


#: direction components within this of the largest magnitude count as tied for the sign rule
SIGN_TIE = 1e-6


@dataclass(frozen=True)
class Mode:
    """One described unstable or neutral mode, as numbers (``modes/*`` datasets).

    ``body`` is the id of the body with the largest participation (-1 for a model without
    bodies, where ``coordinate`` is the index of the dominant scalar unknown); ``kind`` is
    ``rotation`` (about ``direction``), ``translation`` (along ``direction``) or
    ``coordinate``; ``direction`` a unit vector in global axes, sign-normalised by
    :func:`sign_normalised` (NaN for ``coordinate``); ``eigenvalue`` the mode's Rayleigh
    quotient of the stiffness in length coordinates [force/length] (negative for unstable,
    ~0 for neutral). The sign of an eigenvector is arbitrary (it depends on the LAPACK/BLAS
    kernel), hence the normalisation.
    """
    klass: str                 # unstable | neutral
    body: int
    kind: str                  # rotation | translation | coordinate
    direction: tuple           # (3,) floats
    eigenvalue: float
    coordinate: int = -1
    label: str = ""            # coordinate name (kind coordinate)

    def text(self, short: bool = False) -> str:
        """``body 3 rotation about (0.00,0.00,1.00)``, built from the numbers (rounded to two
        decimals, no negative zero). ``short``: a direction within 1e-3 of a global axis is
        named by it (``body 3 rotation about z``)."""
        if self.kind == "coordinate":
            return self.label or f"coordinate {self.coordinate}"
        a = np.asarray(self.direction, float)
        prep = "about" if self.kind == "rotation" else "along"
        axis = next((n for n, e in zip("xyz", np.eye(3)) if abs(a @ e) > 1.0 - 1e-3), None)
        if short and axis is not None:
            return f"body {self.body} {self.kind} {prep} {axis}"
        r = np.round(a, 2) + 0.0
        return f"body {self.body} {self.kind} {prep} ({r[0]:.2f},{r[1]:.2f},{r[2]:.2f})"


@dataclass
class StabilityInfo:
    klass: str                 # stable | neutral | unstable | unknown
    n_negative: int
    n_zero: int
    modes: str                 # human-readable description of negative and zero modes
    min_eigenvalue: float      # smallest eigenvalue of the reduced stiffness [force/length]
    mode_list: tuple = ()      # the described modes as numbers (Mode), unstable first
    # the described unstable modes as vectors in model tangent coordinates (solvers/stable.py
    # leaves an unstable equilibrium along them); not part of the outputs
    vectors: tuple = field(default=(), compare=False, repr=False)


def sign_normalised(a) -> np.ndarray:
    """Unit vector ``a / |a|`` with the sign fixed: its largest-magnitude component is positive
    (components within SIGN_TIE of the largest are tied: the first of them, in x, y, z order),
    and no component is a negative zero."""
    a = np.asarray(a, float)
    n = float(np.linalg.norm(a))
    if not np.isfinite(n) or n == 0.0:
        return np.full(a.shape, np.nan)
    a = a / n
    m = np.abs(a)
    i = int(np.argmax(m >= m.max() - SIGN_TIE))
    if a[i] < 0.0:
        a = -a
    return a + 0.0


def classified_info(model, klass, n_neg, n_zero, unstable, neutral, wmin) -> StabilityInfo:
    """StabilityInfo of a classified frame: ``unstable`` / ``neutral`` lists of ``(q, w)`` (mode
    in model coordinates, its Rayleigh quotient [force/length]), up to N_MODES described each;
    the text is built from the numeric modes."""
    modes, texts = [], []
    for label, found, count in (("unstable", unstable, n_neg), ("neutral", neutral, n_zero)):
        for q, w in found[:N_MODES]:
            mo = describe_mode(model, q, label, w)
            modes.append(mo)
            texts.append(f"{label}: {mo.text()}")
        extra = count - min(len(found), N_MODES)
        if extra > 0:
            texts.append(f"{label}: ... {extra} more")
    return StabilityInfo(klass, int(n_neg), int(n_zero), "; ".join(texts), float(wmin),
                         tuple(modes), tuple(np.asarray(q, float) for q, _ in unstable[:N_MODES]))


def canonical_basis(B):
    """A basis of the span of ``B``'s columns (nq, k) that does not depend on which basis
    ``B`` is: ``C = B B[p]^-1`` (``C[p] = I``) for the coordinates ``p`` a column-pivoted
    Gram-Schmidt picks on ``B^T`` (largest remaining row first), ordered by coordinate, unit
    columns. For an exactly degenerate cluster (neutral modes: every zero eigenvalue is one)
    ``eigh`` returns any rotation of the eigenspace, mixed by round-off; when that space is
    spanned by modes of separate bodies (free spins of 10 links), the columns of ``C`` are
    those modes, listed by body, whichever basis came in."""
    k = B.shape[1]
    A = np.array(B.T)                            # (k, nq): coordinates are columns
    piv = []
    for _ in range(k):
        p = int(np.argmax(np.einsum("ij,ij->j", A, A)))
        piv.append(p)
        q = A[:, p] / np.linalg.norm(A[:, p])
        A -= np.outer(q, q @ A)
    piv = np.sort(np.asarray(piv))
    C = np.linalg.solve(B[piv].T, B.T).T         # B B[piv]^-1
    return C / np.linalg.norm(C, axis=0)


def describe_mode(model, q, klass="", eigenvalue=np.nan) -> Mode:
    """Body with the largest participation in mode ``q`` and its dominant motion, as a
    :class:`Mode` (vectorised over the bodies: cheap for 10 000 bodies); the scalar unknown
    that moves most (``coordinate``) when no body moves, or without bodies."""
    q = np.asarray(q, float)
    nb = model.nb
    if nb:
        t, r = _body_motion(model, q)
        part = np.linalg.norm(t, axis=1) ** 2 + np.linalg.norm(r, axis=1) ** 2
    nbq = model.nq - model.n_extra                  # body coordinates come first
    k = nbq + int(np.argmax(np.abs(q[nbq:]))) if model.n_extra else -1
    if nb == 0 or (k >= 0 and part.max() <= 1e-24 * q[k] ** 2):     # no body moves
        k = int(np.argmax(np.abs(q))) if nb == 0 else k
        name = model.coord_info[k] if k < len(model.coord_info) else f"coordinate {k}"
        return Mode(klass, -1, "coordinate", (np.nan,) * 3, float(eigenvalue), k, str(name))
    b = int(np.argmax(part))
    t, r = t[b], r[b]
    bid = int(model.body_id[b])
    nr, nt = np.linalg.norm(r), np.linalg.norm(t)
    if nr >= (1.0 - 1e-9) * nt:       # a tie (hinge at the body's farthest marker): rotation
        kind, a = "rotation", r
    else:
        kind, a = "translation", t
    return Mode(klass, bid, kind, tuple(float(x) for x in sign_normalised(a)), float(eigenvalue))


def _body_motion(model, q):
    """(nb, 3) translations and (nb, 3) rotations x body scale of every body in mode ``q``."""
    off = np.asarray(model.body_off)
    rigid = np.asarray(model.body_kind) == 0
    t = q[off[:, None] + np.arange(3)]
    r = np.zeros((model.nb, 3))
    r[rigid] = q[off[rigid][:, None] + 3 + np.arange(3)] * model.body_scale[rigid][:, None]
    return t, r


def unknown_info(why: str = "") -> StabilityInfo:
    """A frame that was not classified (not converged, or no trustworthy inertia)."""
    return StabilityInfo("unknown", -1, -1, why, np.nan)



def not_classified(why: str) -> StabilityInfo:
    return unknown_info(f"not classified: {why}")

