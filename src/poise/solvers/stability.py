"""Stability classification of a converged equilibrium.

The tangent stiffness ``K`` (coordinate block of the Newton Jacobian, with the converged
multipliers, *without* the ``stability`` regularisation) is reduced to the constraint manifold:
``K_red = N^T K_s N`` where the columns of ``N`` span the null space of the active constraint
Jacobian. Coordinates are first scaled to lengths (rotations by each body's length scale) so
that the eigenvalues have units of force/length and the zero threshold is relative to the
stiffest direction. ``K_s`` is the symmetric part of the scaled K (for conservative models K is
symmetric at equilibrium; for non-conservative loads the symmetric part gives the energy
criterion — documented limitation).

The inertia of ``K_red`` (counts of negative, zero and positive eigenvalues) classifies the frame:
any negative eigenvalue -> ``unstable``; else any zero eigenvalue -> ``neutral``; else ``stable``.
Modes of negative and zero eigenvalues are described by the body with the largest participation.
``K_red`` is Jacobi-equilibrated before the eigen-decomposition (a congruence, so the inertia is
unchanged): the zero threshold is then relative to each direction's own stiffness, and a stiff/soft
mix (1e9 next to 1 N/m) is not mistaken for a neutral system.

Dense eigen-decomposition is used up to ``DENSE_LIMIT`` coordinates.

Large models (``nq > DENSE_LIMIT``, :func:`_classify_sparse`): ``K_red`` is never formed; the
inertia is counted by spectrum slicing with sparse ``L D L^T`` factorisations.

1. ``K_s`` and the active rows ``G`` (length-scaled as above; numerically empty rows dropped;
   ``K_s`` entries at round-off level of both rows they couple, ``NOISE_REL``, set to zero) are
   equilibrated by a symmetric Ruiz scaling ``S`` of the KKT matrix ``[[K_s, G^T], [G, 0]]``
   (every row's largest entry ~1): ``Kt = S_q K_s S_q``, ``Gt = S_l G S_q``. This diagonal
   congruence replaces the Jacobi equilibration: the counted eigenvalues are those of
   ``Zt^T Kt Zt`` (``Zt`` an orthonormal null-space basis of ``Gt``), i.e. of the pencil
   ``(Z^T K_s Z, Z^T S_q^-2 Z)`` in length coordinates, and ``|mu| <= eps`` with
   ``eps = ZERO_REL * max(rho(Kt), 1)`` (power-iteration estimate of the spectral radius) is
   zero. Exact zeros and eigenvalues well away from the threshold are classified as the dense
   path does; eigenvalues within a small factor of it may be judged differently (the metrics
   differ).
2. For ``Gt`` of full row rank ``m``, ``kkt(s) = [[Kt - s I, Gt^T], [Gt, 0]]`` has inertia
   ``In(Zt^T Kt Zt - s I) + (m, m, 0)``, so ``#(mu < s) = neg(kkt(s)) - m``. Adding
   ``rho Gt^T Gt`` to the (1,1) block is a congruence (``E = [[I, 0], [rho Gt / 2, I]]``), so
   the count is exact for any ``rho``; it makes the (1,1) block definite along the constraint
   directions, which a factorisation without pivoting needs. One factorisation at ``s = +eps``
   gives ``n_neg + n_zero``; when that is 0 the frame is ``stable`` (the common case costs one
   factorisation); otherwise one at ``s = -eps`` gives ``n_neg``.
3. :class:`SymmetricLDL`: SuperLU in symmetric mode with ``diag_pivot_thresh=0`` in a given
   order: bodies by minimum degree on the body quotient graph, every constraint row and every
   coordinate with a near-zero diagonal right after the last body it touches (then no pivot is
   structurally zero). With no off-diagonal pivot (``perm_r == perm_c``) ``U = D L^T`` and the
   pivot signs are the inertia (Sylvester). Without pivoting this is not backward stable in
   general, so a factorisation counts only when the estimate ``32 u ||(|L||U|) 1||`` is below
   ``BERR_MAX * eps`` and no pivot is below ``TINY_PIVOT * eps``; otherwise other
   augmentation weights ``rho`` are tried; a zero or tiny pivot also triggers the static
   driver's redundancy test on the active rows (rows that became dependent at this
   configuration are dropped, which leaves the null space unchanged), once. If nothing gives
   a trustworthy count the frame is ``unknown`` and ``modes`` says why — never a guessed class.
4. Modes: the ``x`` block of ``kkt(s)^-1 [v; 0]`` is ``Zt (Zt^T (Kt - s I) Zt)^-1 Zt^T v``, a
   symmetric operator whose range lies on the manifold, applied with the factorisation already
   made. Neutral modes are its dominant eigenvalues at ``s = -eps`` (block iteration and
   Rayleigh-Ritz; exactly degenerate clusters such as 10 000 free spins included). Unstable
   modes are its negative eigenvalues at ``s = -eps`` (Lanczos, ARPACK) when all are described
   (<= 6); otherwise a factorisation at a Gershgorin bound below the spectrum (inertia-checked)
   and then at 1.1 x the lowest Ritz value makes the most unstable ones dominant (block
   iteration: in a tight cluster, Ritz vectors are valid modes of their value). A stable
   frame's smallest eigenvalue is the lowest Ritz pair at ``s = +eps``. Every vector is checked
   (``Gt x ~ 0``, sign of its Rayleigh quotient) before it is described; ``min_eigenvalue`` is
   its Rayleigh quotient in length coordinates, as on the dense path (for many unstable modes,
   an upper-bound estimate).

Cost on the 10 000-link chain (60 000 coordinates, 110 000 KKT unknowns): one ``L D L^T``
~0.1 s (less than one COLAMD LU of the Newton matrix); the stable classification ~0.3 s; upside
down (9998 unstable modes) ~1 s; the spherical chain (10 000 neutral spins) ~0.9 s.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from poise.solvers.redundancy import redundant_rows

DENSE_LIMIT = 300       # coordinates; dense cost grows as nq^3 (3000: 30 s, sparse 0.05 s)
ZERO_REL = 1e-8
DIAG_FLOOR = 1e-24     # relative floor of the diagonal in the Jacobi equilibration
# sparse path (nq > DENSE_LIMIT)
N_MODES = 6            # modes described per class (as the dense path)
AUG_RHO = (1.0, 16.0, 1.0 / 16.0)   # augmented-Lagrangian weights tried in turn (inertia-neutral)
BERR_MAX = 1e-2        # LDL^T backward-error estimate allowed, as a fraction of the zero threshold
SMALL_OP = 64          # mode operators up to this size are decomposed densely
NOISE_REL = 1e-14      # stiffness entries below this fraction of both their rows' largest: round-off
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


def _info(model, klass, n_neg, n_zero, unstable, neutral, wmin) -> StabilityInfo:
    """StabilityInfo of a classified frame: ``unstable`` / ``neutral`` lists of ``(q, w)`` (mode
    in model coordinates, its Rayleigh quotient [force/length]), up to N_MODES described each;
    the text is built from the numeric modes."""
    modes, texts = [], []
    for label, found, count in (("unstable", unstable, n_neg), ("neutral", neutral, n_zero)):
        for q, w in found[:N_MODES]:
            mo = _describe(model, q, label, w)
            modes.append(mo)
            texts.append(f"{label}: {mo.text()}")
        extra = count - min(len(found), N_MODES)
        if extra > 0:
            texts.append(f"{label}: ... {extra} more")
    return StabilityInfo(klass, int(n_neg), int(n_zero), "; ".join(texts), float(wmin),
                         tuple(modes), tuple(np.asarray(q, float) for q, _ in unstable[:N_MODES]))


def classify(model, state, J=None, active=None) -> StabilityInfo:
    """Classify the equilibrium ``state`` of ``model``; ``active``: the solve's active
    constraint rows (None: all).

    ``J`` may be a KKT Jacobian already evaluated at ``state`` without regularisation (with
    any active rows: inactive rows are dropped here).
    """
    nq = model.nq
    if nq == 0:
        return StabilityInfo("stable", 0, 0, "", np.nan)
    if J is None:
        J = model.evaluate(state, need_jac=True, eps_mass=0.0, active=active).J
    if active is None:
        active = np.ones(model.nc, bool)
    if nq > DENSE_LIMIT:
        return _classify_sparse(model, J, active)
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    return classify_dense_frames(model, J[None], active)[0]


def classify_dense_frames(model, J, active, ok=None) -> list[StabilityInfo]:
    """Dense classification of ``F`` frames from their KKT Jacobians ``J`` (F, N, N) (dense).

    Per frame: the length-scaled symmetric stiffness reduced to the SVD null space of the
    ``active`` constraint rows, Jacobi-equilibrated, ``eigh`` with the ``ZERO_REL`` threshold
    (module docstring). Frames are processed with stacked SVDs and eigen-decompositions; frames
    of equal constraint rank share one call. Frames with ``ok[k]`` False are ``unknown``.
    """
    F = J.shape[0]
    nq = model.nq
    unknown = StabilityInfo("unknown", -1, -1, "", np.nan)
    ok = np.ones(F, bool) if ok is None else np.asarray(ok, bool)
    if nq == 0:
        return [StabilityInfo("stable", 0, 0, "", np.nan) if k else unknown for k in ok]
    out = [unknown] * F
    sel = np.nonzero(ok)[0]
    if not len(sel):
        return out
    d = model.q_scale                       # length per coordinate unit
    Ku = J[sel, :nq, :nq] / d[:, None] / d[None, :]
    Ku = 0.5 * (Ku + np.swapaxes(Ku, 1, 2))
    Pq = J[sel, nq:, :nq][:, active]
    Fo = len(sel)
    if Pq.shape[1]:
        _, s, vh = np.linalg.svd(Pq / d[None, None, :], full_matrices=True)
        tol = 1e-10 * (s.max(axis=1) if s.shape[1] else np.zeros(Fo))
        rank = np.sum(s > tol[:, None], axis=1)
    else:
        vh = np.broadcast_to(np.eye(nq), (Fo, nq, nq))
        rank = np.zeros(Fo, int)
    for rk in sorted(set(rank.tolist())):        # (np.unique imports numpy.ma: ~15 ms)
        grp = np.nonzero(rank == rk)[0]
        Nb = np.swapaxes(vh[grp, rk:, :], 1, 2)                      # (g, nq, k) null spaces
        if Nb.shape[2] == 0:
            for i in grp:
                out[sel[i]] = StabilityInfo("stable", 0, 0, "no degrees of freedom", np.inf)
            continue
        Kg = Ku[grp]
        Kr = np.matmul(np.swapaxes(Nb, 1, 2), np.matmul(Kg, Nb))
        Kr = 0.5 * (Kr + np.swapaxes(Kr, 1, 2))
        # Jacobi equilibration (a congruence: the inertia is unchanged, Sylvester): a stiff/soft
        # mix (a 1e9 N/m spring next to a 1 N/m one) is judged per direction, not against the
        # stiffest
        dg = np.abs(np.diagonal(Kr, axis1=1, axis2=2))
        ref = np.maximum(dg.max(axis=1), np.abs(np.diagonal(Kg, axis1=1, axis2=2)).max(axis=1))
        fl = np.where(ref > 1e-280, DIAG_FLOOR * ref, 1.0)          # all-zero: no scaling
        sj = 1.0 / np.sqrt(np.maximum(dg, fl[:, None]))
        w, V = np.linalg.eigh(Kr * sj[:, :, None] * sj[:, None, :])
        ztol = ZERO_REL * np.maximum(np.abs(w).max(axis=1), 1.0)
        neg = w < -ztol[:, None]
        zero = np.abs(w) <= ztol[:, None]
        X = np.matmul(Nb, sj[:, :, None] * V)        # eigenvectors in (length) coordinates
        X /= np.maximum(np.linalg.norm(X, axis=1), 1e-300)[:, None, :]
        kmin = np.argmin(w, axis=1)
        xk = X[np.arange(len(grp)), :, kmin]
        wmin = np.einsum("gi,gij,gj->g", xk, Kg, xk)                 # Rayleigh [force/length]
        for j, i in enumerate(grp):
            found = []
            for mask in (neg[j], zero[j]):
                ks = np.nonzero(mask)[0][:N_MODES]
                xs = X[j][:, ks]                                     # unit, length coordinates
                wk = np.einsum("ik,ij,jk->k", xs, Kg[j], xs)        # Rayleigh [force/length]
                found.append([(xs[:, c] / d, float(wk[c])) for c in range(len(ks))])
            klass = "unstable" if neg[j].any() else "neutral" if zero[j].any() else "stable"
            out[sel[i]] = _info(model, klass, int(neg[j].sum()), int(zero[j].sum()),
                                found[0], found[1], wmin[j])
    return out


def _describe(model, q, klass="", eigenvalue=np.nan) -> Mode:
    """Body with the largest participation in mode ``q`` and its dominant motion, as a
    :class:`Mode` (vectorised over the bodies: cheap for 10 000 bodies)."""
    q = np.asarray(q, float)
    nb = model.nb
    if nb == 0:
        k = int(np.argmax(np.abs(q)))
        name = model.coord_info[k] if k < len(model.coord_info) else f"coordinate {k}"
        return Mode(klass, -1, "coordinate", (np.nan,) * 3, float(eigenvalue), k, str(name))
    off = np.asarray(model.body_off)
    rigid = np.asarray(model.body_kind) == 0
    t = q[off[:, None] + np.arange(3)]
    r = np.zeros((nb, 3))
    r[rigid] = q[off[rigid][:, None] + 3 + np.arange(3)] * model.body_scale[rigid][:, None]
    part = np.linalg.norm(t, axis=1) ** 2 + np.linalg.norm(r, axis=1) ** 2
    b = int(np.argmax(part))
    t, r = t[b], r[b]
    bid = int(model.body_id[b])
    nr, nt = np.linalg.norm(r), np.linalg.norm(t)
    if nr >= (1.0 - 1e-9) * nt:       # a tie (hinge at the body's farthest marker): rotation
        kind, a = "rotation", r
    else:
        kind, a = "translation", t
    return Mode(klass, bid, kind, tuple(float(x) for x in sign_normalised(a)), float(eigenvalue))


def stability_datasets(infos: list[StabilityInfo]) -> dict:
    """Per-frame datasets (F frames): ``frames/stability``, ``frames/n_negative``,
    ``frames/n_zero``, ``frames/stability_modes`` (text), ``frames/min_stiffness_eigenvalue``,
    ``frames/n_modes``; and the described modes as numbers, flat in frame order (K = the sum of
    ``n_modes``; the frame of mode ``j`` is ``np.repeat(np.arange(F), n_modes)[j]``, so frames
    and runs concatenate along their axes): ``modes/class``, ``modes/kind`` (K,) strings,
    ``modes/body`` (K,) ids, ``modes/direction`` (K, 3) unit vectors, ``modes/eigenvalue``
    (K,). Frame ``f``'s modes are the :class:`Mode` records ``infos[f].mode_list``."""
    ml = [mo for info in infos for mo in info.mode_list]
    return {
        "frames/stability": np.array([i.klass for i in infos], dtype=str),
        "frames/n_negative": np.array([i.n_negative for i in infos], dtype=np.int64),
        "frames/n_zero": np.array([i.n_zero for i in infos], dtype=np.int64),
        "frames/stability_modes": np.array([i.modes for i in infos], dtype=str),
        "frames/min_stiffness_eigenvalue": np.array([i.min_eigenvalue for i in infos]),
        "frames/n_modes": np.array([len(i.mode_list) for i in infos], dtype=np.int64),
        "modes/class": np.array([mo.klass for mo in ml], dtype=str),
        "modes/kind": np.array([mo.kind for mo in ml], dtype=str),
        "modes/body": np.array([mo.body for mo in ml], dtype=np.int64),
        "modes/direction": np.array([mo.direction for mo in ml], float).reshape(len(ml), 3),
        "modes/eigenvalue": np.array([mo.eigenvalue for mo in ml], float),
    }


def unknown_info(why: str = "") -> StabilityInfo:
    """A frame that was not classified (not converged, or no trustworthy inertia)."""
    return StabilityInfo("unknown", -1, -1, why, np.nan)


# =============================================================================== sparse path
def _classify_sparse(model, J, active=None) -> StabilityInfo:
    """Inertia by spectrum slicing with sparse LDL^T factorisations of the equilibrated KKT
    matrix (module docstring, "Large models"). Active constraint rows that have become
    dependent at this configuration (a tiny pivot at a constraint row) are found by the
    redundancy test of the static driver and dropped (the null space is unchanged), once."""
    try:
        P = _SparsePencil(model, J, active=active)
        info = _classify_pencil(model, P)
        if info.klass == "unknown" and P.singular:
            red = redundant_rows(P.G_active, np.ones(model.nq))
            if len(red):
                info = _classify_pencil(model, _SparsePencil(model, J, drop=red, active=active))
        return info
    except (RuntimeError, ValueError, ArithmeticError, MemoryError,
            np.linalg.LinAlgError) as e:
        return _unknown(f"sparse classification failed ({type(e).__name__}: {e})")


def _classify_pencil(model, P) -> StabilityInfo:
    m, eps = P.m, P.eps
    up, why = P.factor(+eps)
    if up is None:
        return _unknown(why)
    below = up.n_negative - m                       # eigenvalues < +eps
    if below < 0:
        return _unknown("KKT inertia has fewer negative pivots than active constraint rows "
                        "(dependent constraint rows?)")
    if below == 0:
        if P.nq == m:                    # valid factorisation: Gt square and non-singular
            return StabilityInfo("stable", 0, 0, "no degrees of freedom", np.inf)
        low = _lowest_mode(P, up, +eps)
        return StabilityInfo("stable", 0, 0, "", low[0][1] if low else np.nan)
    dn, why = P.factor(-eps)
    if dn is None:
        return _unknown(why)
    n_neg = dn.n_negative - m                       # eigenvalues < -eps
    if not 0 <= n_neg <= below:
        return _unknown(f"inconsistent inertia at the two shifts ({below} eigenvalues below "
                        f"+{eps:.1e}, {n_neg} below -{eps:.1e})")
    n_zero = below - n_neg
    unstable = _negative_modes(P, dn, -eps, n_neg) if n_neg else []
    neutral = _zero_modes(P, dn, -eps, n_zero) if n_zero else []
    ws = [w for _, w in unstable + neutral]
    klass = "unstable" if n_neg else "neutral"
    return _info(model, klass, n_neg, n_zero, unstable, neutral, min(ws) if ws else np.nan)


def _unknown(why: str) -> StabilityInfo:
    return unknown_info(f"not classified: {why}")


class SymmetricLDL:
    """Sparse ``L D L^T`` of a symmetric matrix with 1x1 diagonal pivots only, and its inertia.

    SuperLU in symmetric mode with ``diag_pivot_thresh=0`` takes every diagonal pivot that is
    not exactly zero; when no off-diagonal pivot was taken (``perm_r == perm_c``) the factors
    of ``P^T A P`` satisfy ``U = D L^T`` and, by Sylvester's law of inertia, the signs of the
    pivots ``diag(U)`` are the signs of A's eigenvalues. ``order`` is a symmetric elimination
    order (``A[order][:, order]`` is factorised as given); None lets SuperLU choose (minimum
    degree on A + A^T).

    ``ok`` is False (with ``reason``) when a pivot was zero, non-finite or off the diagonal.
    Without pivoting the factorisation is not backward stable in general, so
    ``backward_error = 32 u ||(|L| |U|) 1||_inf`` estimates ``||L D L^T - A||``: the counted
    inertia is A's when this is below A's smallest |eigenvalue| (Weyl).
    """

    def __init__(self, A, order=None):
        import scipy.sparse as sp
        import scipy.sparse.linalg as spla
        A = sp.csc_matrix(A)
        self.n = n = A.shape[0]
        self.order = None if order is None else np.asarray(order)
        if self.order is not None:
            A = A[self.order][:, self.order].tocsc()
        self.ok = False
        self.reason = ""
        self.backward_error = np.inf
        self.n_negative = self.n_positive = -1
        try:
            lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A" if order is None else "NATURAL",
                           diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
        except RuntimeError as e:
            self.reason = f"the LDL^T factorisation failed ({e})"
            return
        if not np.array_equal(lu.perm_r, lu.perm_c):
            self.reason = "the LDL^T factorisation needed an off-diagonal pivot"
            return
        U = lu.U
        d = U.diagonal()
        if not np.all(np.isfinite(d)) or np.any(d == 0.0):
            self.reason = "the LDL^T factorisation has a zero or non-finite pivot"
            return
        g = abs(lu.L) @ (abs(U) @ np.ones(n))
        self.backward_error = 32 * np.finfo(float).eps * float(np.max(g, initial=0.0))
        self.pivots = d
        # original index of each pivot (pivot k eliminates column perm_c^-1[k] of A[order])
        self.index = np.empty(n, np.int64)
        self.index[lu.perm_c] = np.arange(n) if self.order is None else self.order
        self.n_negative = int(np.count_nonzero(d < 0))
        self.n_positive = n - self.n_negative
        self.lu = lu
        self.ok = True

    @property
    def inertia(self) -> tuple[int, int, int]:
        """(negative, zero, positive) pivot counts (no zero pivot in a valid factorisation)."""
        return self.n_negative, 0, self.n_positive

    def solve(self, b):
        b = np.asarray(b, float)
        if self.order is None:
            return self.lu.solve(b)
        y = self.lu.solve(np.ascontiguousarray(b[self.order]))
        x = np.empty_like(y)
        x[self.order] = y
        return x


class _SparsePencil:
    """The reduced-stiffness eigenproblem of a large model, never formed: the length-scaled
    symmetric stiffness ``Kt`` and active constraint Jacobian ``Gt`` after a symmetric
    equilibration of the KKT matrix, the KKT elimination order, and factorisations at shifts."""

    def __init__(self, model, J, drop=(), active=None):
        import scipy.sparse as sp
        nq = model.nq
        J = sp.csr_matrix(J)
        d = np.asarray(model.q_scale, float)
        Di = sp.diags(1.0 / d)
        Ku = Di @ J[:nq, :nq] @ Di
        Ks = _prune_noise(((Ku + Ku.T) * 0.5).tocsr())
        rows = np.arange(model.nc) if active is None else np.nonzero(active)[0]
        G = (J[nq:, :nq][rows] @ Di).tocsr()
        self.G_active = G                 # active rows, length-scaled (dependent-row check)
        self.rows = rows                  # constraint rows of Gt (model indices)
        if G.shape[0]:
            # a numerically empty row does not constrain anything (the dense SVD's rcond);
            # ``drop``: active rows found dependent at this configuration
            rn = np.sqrt(np.asarray(G.multiply(G).sum(axis=1)).ravel())
            keep = rn > 1e-10 * rn.max()
            keep[np.asarray(drop, np.int64)] = False
            G = G[keep]
            self.rows = self.rows[keep]
        dq, dl = _equilibrate(Ks, G)
        self.Kt = (sp.diags(dq) @ Ks @ sp.diags(dq)).tocsr()
        self.Gt = (sp.diags(dl) @ G @ sp.diags(dq)).tocsr()
        self.GtG = (self.Gt.T @ self.Gt).tocsr()
        self.Ks, self.d, self.dq, self.dl = Ks, d, dq, dl
        self.nq, self.m = nq, self.Gt.shape[0]
        self.order = _kkt_order(model, self.Kt, self.Gt, self.GtG)
        # zero threshold: ZERO_REL of the spectral radius of Kt (an upper bound of the reduced
        # matrix's), at least ZERO_REL (Kt has a unit-scale diagonal block after equilibration)
        self.eps = ZERO_REL * max(_spectral_radius(self.Kt), 1.0)
        self.singular = False             # a tiny pivot at a constraint row was met

    def kkt(self, s, rho):
        """``[[Kt - s I + rho Gt^T Gt, Gt^T], [Gt, 0]]`` (congruent to the rho = 0 matrix)."""
        import scipy.sparse as sp
        A = self.Kt + rho * self.GtG - s * sp.identity(self.nq, format="csr")
        if self.m == 0:
            return A.tocsc()
        return sp.bmat([[A, self.Gt.T], [self.Gt, None]], format="csc")

    def factor(self, s):
        """A valid LDL^T of ``kkt(s, rho)`` for the first ``rho`` of AUG_RHO whose backward
        error is below ``BERR_MAX * eps`` and whose pivots are all above ``TINY_PIVOT * eps``
        (a pivot at round-off level has no reliable sign: the matrix is numerically singular,
        typically dependent constraint rows at this configuration); else ``(None, reason)``."""
        why = []
        for rho in AUG_RHO:
            F = SymmetricLDL(self.kkt(s, rho), self.order)
            if not F.ok:                  # a zero pivot (exactly dependent rows?)
                self.singular = True
                why.append(F.reason)
                continue
            if F.backward_error > BERR_MAX * self.eps:
                why.append(f"LDL^T backward error {F.backward_error:.1e} above "
                           f"{BERR_MAX:g} x the zero threshold {self.eps:.1e}")
                continue
            tiny = np.abs(F.pivots) < TINY_PIVOT * self.eps
            if tiny.any():
                at_row = bool(np.any(F.index[tiny] >= self.nq))
                self.singular |= at_row
                why.append(f"pivot {np.abs(F.pivots).min():.1e} below {TINY_PIVOT:g} x the zero "
                           f"threshold: numerically singular"
                           + (" (dependent constraint rows?)" if at_row else ""))
                continue
            return F, ""
        return None, (f"sparse inertia of the {self.nq + self.m}-unknown KKT matrix at shift "
                      f"{s:+.1e} not reliable ({why[0]}; {len(why) - 1} other augmentation "
                      "weights failed too)")

    def op(self, F):
        """``v -> x`` with ``kkt(s) [x; y] = [v; 0]``: ``Z (Z^T (Kt - s I) Z)^-1 Z^T v`` for an
        orthonormal null-space basis Z of Gt (symmetric; its range satisfies Gt x = 0)."""
        from scipy.sparse.linalg import LinearOperator
        nq, m = self.nq, self.m

        def mv(v):
            v = np.asarray(v, float)
            b = np.zeros((nq + m,) + v.shape[1:])
            b[:nq] = v
            return F.solve(b)[:nq]
        return LinearOperator((nq, nq), matvec=mv, matmat=mv, dtype=float)

    def modes(self, X):
        """Check the columns of X (scaled coordinates) and return [(q, w, mu)]: ``q`` in model
        coordinates, ``w`` the Rayleigh quotient in length coordinates [force/length] (as the
        dense path), ``mu`` the scaled Rayleigh quotient (compared with ``eps``)."""
        X = np.asarray(X, float).reshape(self.nq, -1)
        nx = np.linalg.norm(X, axis=0)
        ok = np.isfinite(nx) & (nx > 0.0)
        X = X[:, ok] / nx[ok]
        if self.m:                                    # on the manifold (Gt x = 0)?
            X = X[:, np.linalg.norm(self.Gt @ X, axis=0) <= 1e-6]
        mu = np.einsum("ij,ij->j", X, self.Kt @ X)
        XL = self.dq[:, None] * X
        XL /= np.linalg.norm(XL, axis=0)
        w = np.einsum("ij,ij->j", XL, self.Ks @ XL)
        return [(XL[:, j] / self.d, float(w[j]), float(mu[j])) for j in range(X.shape[1])]


def _prune_noise(Ks):
    """Drop the entries of Ks at round-off level of both rows they couple (``|K_ij| <=
    NOISE_REL max(max_k |K_ik|, max_k |K_jk|)``): a perturbation of the size of the rounding in
    those rows, but equilibration would otherwise scale a 1e-19-relative coupling next to a
    zero diagonal (a box's yaw on a plane) up to unit size and count a negative eigenvalue."""
    a = np.abs(Ks.data)
    cnt = np.diff(Ks.indptr)
    nz = cnt > 0
    if not a.size:
        return Ks
    rmax = np.zeros(Ks.shape[0])
    rmax[nz] = np.maximum.reduceat(a, Ks.indptr[:-1][nz])
    rows = np.repeat(np.arange(Ks.shape[0]), cnt)
    keep = a > NOISE_REL * np.maximum(rmax[rows], rmax[Ks.indices])
    if keep.all():
        return Ks
    Ks = Ks.copy()
    Ks.data[~keep] = 0.0
    Ks.eliminate_zeros()
    return Ks


def _equilibrate(Ks, G, iters=12, tol=0.1):
    """Symmetric Ruiz scaling ``D`` of the KKT matrix ``[[Ks, G^T], [G, 0]]``: every row of
    ``D |KKT| D`` has a largest entry in ``[1 - tol, 1 + tol]`` (a diagonal congruence: the
    inertia is unchanged), except that a coordinate is never scaled up beyond
    ``1 / sqrt(DIAG_FLOOR max|Ks|)`` (the dense path's floor). Returns the coordinate and row
    factors."""
    import scipy.sparse as sp
    nq = Ks.shape[0]
    kmax = float(np.max(np.abs(Ks.data), initial=0.0))
    cap = 1.0 / np.sqrt(DIAG_FLOOR * kmax) if kmax > 0.0 else np.inf
    B = sp.bmat([[Ks, G.T], [G, None]], format="csr") if G.shape[0] else Ks.tocsr()
    n = B.shape[0]
    a = np.abs(B.data)
    cnt = np.diff(B.indptr)
    rows = np.repeat(np.arange(n), cnt)
    nz = cnt > 0
    starts = B.indptr[:-1][nz]
    D = np.ones(n)
    for _ in range(iters):
        r = np.ones(n)
        if a.size:
            r[nz] = np.maximum.reduceat(a * D[rows] * D[B.indices], starts)
        r[r <= 0.0] = 1.0                              # an all-zero row keeps its scale
        if np.all(np.abs(r - 1.0) <= tol):
            break
        D /= np.sqrt(r)
        np.minimum(D[:nq], cap, out=D[:nq])
    return D[:nq], D[nq:]


def _coordinate_groups(model) -> np.ndarray:
    """Group of each coordinate: one per body, one per scalar unknown."""
    nq, nb = model.nq, model.nb
    grp = np.full(nq, -1, np.int64)
    if nb:
        size = np.where(np.asarray(model.body_kind) == 0, 6, 3)
        within = np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
        grp[np.repeat(np.asarray(model.body_off), size) + within] = np.repeat(np.arange(nb), size)
    free = grp < 0
    grp[free] = nb + np.arange(int(free.sum()))
    return grp


def _kkt_order(model, K, G, GtG) -> np.ndarray:
    """Symmetric elimination order of the KKT matrix for 1x1 pivots. Bodies (and scalar
    unknowns) are ordered by minimum degree on the quotient graph (one node per body) of
    ``|K| + |G|^T |G|``; every constraint row comes right after the last of the bodies it acts
    on (its pivot is then ``-g A^-1 g^T``, not its zero diagonal), and so does every *weak*
    coordinate (augmented diagonal ``|K_ii + (G^T G)_ii|`` below ``WEAK_DIAG``, e.g. a scalar
    unknown with no stiffness of its own): eliminated first, its near-zero pivot would blow up
    the rest of the factor."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    nq = model.nq
    grp = _coordinate_groups(model)
    ng = int(grp.max()) + 1
    E = sp.csr_matrix((np.ones(nq), (np.arange(nq), grp)), shape=(nq, ng))
    S = (abs(K) + abs(GtG)).tocsr()
    S.sum_duplicates()
    if ng > 1:
        Q = (E.T @ S @ E).tocsc()
        Q.data[:] = 1.0
        Q = (Q + sp.identity(ng, format="csc") * (ng + 1.0)).tocsc()   # diagonally dominant
        rank = spla.splu(Q, permc_spec="MMD_AT_PLUS_A").perm_c       # position of each group
    else:
        rank = np.zeros(1, np.int64)
    key = 3 * rank[grp]
    nzr = np.diff(S.indptr) > 0
    weak = (np.abs((K + GtG).diagonal()) < WEAK_DIAG) & nzr
    if weak.any():
        last = np.zeros(nq, np.int64)
        last[nzr] = np.maximum.reduceat(rank[grp[S.indices]], S.indptr[:-1][nzr])
        key[weak] = 3 * last[weak] + 2
    keys = [key]
    if G.shape[0]:
        Ga = abs(G).tocsr()
        last = np.maximum.reduceat(rank[grp[Ga.indices]], Ga.indptr[:-1])
        keys.append(3 * last + 1)
    return np.argsort(np.concatenate(keys), kind="stable")


def _spectral_radius(A, iters=20) -> float:
    """Power-iteration estimate (a lower bound) of the spectral radius of symmetric A."""
    x = np.random.default_rng(20240611).standard_normal(A.shape[0])
    r = 0.0
    for _ in range(iters):
        nx = np.linalg.norm(x)
        if nx == 0.0:
            break
        x = A @ (x / nx)
        r = float(np.linalg.norm(x))
    return r


def _eig_extreme(op, n, k, which, tol, maxiter=20):
    """``k`` eigenpairs of the symmetric operator ``op`` at the end ``which`` ('LA' or 'SA'):
    dense for small operators, else implicitly restarted Lanczos (ARPACK; on non-convergence
    the pairs that did converge)."""
    if n <= SMALL_OP:
        A = op.matmat(np.eye(n))
        w, V = np.linalg.eigh(0.5 * (A + A.T))
        idx = np.argsort(w if which == "SA" else -w)[:k]
        return w[idx], V[:, idx]
    from scipy.sparse.linalg import ArpackError, ArpackNoConvergence, eigsh
    v0 = op.matvec(np.random.default_rng(7).standard_normal(n))     # in the range of op
    try:
        return eigsh(op, k=k, which=which, tol=tol, v0=v0, maxiter=maxiter)
    except ArpackNoConvergence as e:
        return e.eigenvalues, e.eigenvectors
    except ArpackError:
        return np.zeros(0), np.zeros((n, 0))


def _subspace(P, op, b, iters, seed, X=None):
    """Block subspace iteration on ``op`` (block size ``b``, one multi-right-hand-side solve per
    step) followed by a Rayleigh-Ritz step on Kt: the Ritz pairs ``(mu, X)`` (mu ascending) of
    the dominant invariant subspace of ``op``. Ritz values are Rayleigh quotients, so a Ritz
    vector of a tight cluster is a valid mode with that value even before it has converged."""
    b = max(1, min(b, P.nq))
    if X is None:
        X = np.random.default_rng(seed).standard_normal((P.nq, b))
    X = op.matmat(X)
    for it in range(iters + 1):
        U = _orthonormalize(_orthonormalize(X))
        if it < iters:
            X = op.matmat(U)
    H = U.T @ (P.Kt @ U)
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    return w, U @ V


def _orthonormalize(X, rtol=1e-7):
    """Orthonormal basis of the columns of tall X from its Gram matrix (one pass loses the
    directions below ``rtol`` of the largest: harmless here, they are the ones the iteration
    discards; call twice for orthogonality to round-off). Cheaper than QR for n x 10."""
    Gm = X.T @ X
    w, V = np.linalg.eigh(0.5 * (Gm + Gm.T))
    keep = w > (rtol ** 2) * max(float(w[-1]), 0.0) if w.size else w > 0
    keep &= w > 0
    return (X @ V[:, keep]) / np.sqrt(w[keep])


def _lowest_mode(P, F, s):
    """Stable model (``kkt(s)`` has no reduced eigenvalue below ``s``): the smallest ones are
    the dominant eigenvalues 1/(mu - s) > 0 of ``op(F)``; the lowest Ritz pair of a short block
    iteration (a block, not Lanczos on one vector, so that clusters cost nothing extra)."""
    _, X = _subspace(P, P.op(F), 4, 4, seed=5)
    found = sorted(P.modes(X), key=lambda mo: mo[2])
    return [mo[:2] for mo in found[:1]]


def _negative_modes(P, F, s, n_neg):
    """Up to N_MODES unstable modes, most negative first.

    ``F`` factorises ``kkt(s)``, ``s = -eps``: the negative eigenvalues ``1/(mu - s)`` of
    ``op(F)`` are exactly the n_neg unstable modes, well apart from the positive ones when the
    instability is weak. When all of them are wanted (n_neg <= N_MODES) Lanczos takes them from
    there. Otherwise (or if Lanczos does not deliver them all) a further factorisation at a
    Gershgorin lower bound ``s_lo`` of the spectrum of Kt (no reduced eigenvalue below it,
    checked by its inertia) makes the most unstable modes the dominant ones of a positive
    operator, and a block iteration gives them (Ritz pairs: inside a tight cluster, valid
    modes of that value). Its lowest Ritz value ``r`` then gives a closer shift ``1.1 r``,
    used (after the same inertia check) for a few more steps: convergence goes with
    ``(mu_1 - s) / (mu_j - s)``."""
    k = min(n_neg, N_MODES)
    found = []
    if n_neg <= N_MODES:
        th, X = _eig_extreme(P.op(F), P.nq, k, "SA", 1e-8)
        found = [mo for mo in P.modes(X[:, th < 0]) if mo[2] < -P.eps]
    if len(found) < k:
        X = None
        s_lo = -1.01 * float(abs(P.Kt).sum(axis=1).max()) - P.eps
        for _ in range(2):
            lo, _why = P.factor(s_lo)
            if lo is None or lo.n_negative != P.m:
                break
            w, X = _subspace(P, P.op(lo), k + 6, 3, seed=3, X=X)
            more = [mo for mo in P.modes(X) if mo[2] < -P.eps]
            if len(more) >= len(found):
                found = more
            if not w.size or w[0] >= -P.eps:
                break
            s_lo = 1.1 * float(w[0])
    found.sort(key=lambda mo: mo[2])
    return [mo[:2] for mo in found[:k]]


def _zero_modes(P, F, s, n_zero):
    """Up to N_MODES neutral modes. With ``F`` factorising ``kkt(s)``, ``s = -eps``, the reduced
    eigenvalues in [-eps, eps] are the dominant ones of ``op(F)`` (>= 1/(2 eps)), exactly
    degenerate clusters included: a short block iteration and Rayleigh-Ritz give them."""
    k = min(n_zero, N_MODES)
    w, X = _subspace(P, P.op(F), k + 4, 4, seed=11)
    X = X[:, np.argsort(np.abs(w), kind="stable")]
    found = [mo for mo in P.modes(X) if abs(mo[2]) <= 2 * P.eps]
    return [mo[:2] for mo in found[:k]]
