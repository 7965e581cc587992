"""Singular configurations of a quasi-static path: measures, diagnosis, naming.

The equilibrium path ``F(q(t), lam(t), t) = 0`` is singular where ``F``'s Jacobian loses rank:
either the constraint Jacobian beyond the redundant rows (*kinematic*: a dead point, a toggle,
a motion driven beyond the linkage's reach; a self-stress ``u`` with ``u^T Phi_q = 0`` names the
constraints that lock) or the stiffness reduced to the constraint manifold (*limit point* or
bifurcation under load). Where the path ends (no continuation beyond a time) the end is located
by bisection (:mod:`poise.solvers.quasistatic`) and :func:`diagnose` compares both measures at
the last point reached with their values on the path before: a measure that fell to ``DROP`` of
it is the cause. Sign changes of the reduced stiffness along a path that goes on are found from
the frames' classification (:mod:`poise.solvers.path`). Method: docs/quasistatic.md.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, replace

import numpy as np

from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.limits import LIMITS
from poise.solvers.newton import FrameOutcome
from poise.solvers.stability import DENSE_LIMIT, classify, describe_mode
from poise.solvers.status import Status

DROP = 0.05          # a measure this fraction of its value on the path before: singular there
NEAR = 0.3           # ... this fraction: approaching a singularity (worth locating)
NEAR_HISTORY = 6     # accepted states whose measure the current one is compared with
SHARE_MIN = 0.05     # constraints with this share of the largest share of the self-stress named
KINDS = {"dead_point": "at a dead point (the constraint equations lose rank: a toggle, a dead "
                       "centre or a motion beyond the linkage's reach)",
         "limit_point": "at a limit point (the reduced stiffness reaches zero: the load cannot "
                        "increase further on this branch, snap-through or buckling)",
         "bifurcation": "at a bifurcation (the reduced stiffness changes sign: the equilibrium "
                        "branches)"}


@dataclass(frozen=True)
class SingularInfo:
    """Where and why a path is singular: ``time``, ``kind`` (a :data:`KINDS` key),
    ``elements`` (dicts ``tag``, ``id``, ``label``, ``line``, ``share`` of the constraints in
    the self-stress, kinematic kinds; the joint the linkage folds at first, with ``fold``
    true), ``mode`` (the motion at the singular point, e.g. ``body 2 rotation about z``)."""
    time: float
    kind: str
    elements: tuple = ()
    mode: str = ""

    def message(self) -> str:
        names = [element_name(e) for e in self.elements]
        who = names[0] + " " if names else ""
        also = f"; the constraints that lock: {', '.join(names)}" if len(names) > 1 else ""
        where = f"; moving: {self.mode}" if self.mode else ""
        return (f"singular configuration at t = {self.time:.6g}: {who}{KINDS[self.kind]}"
                f"{also}{where}")

    def attrs(self) -> dict:
        """Analysis attributes ``singular_time``, ``singular_kind``, ``singular_elements``
        (JSON), ``singular_mode``."""
        return {"singular_time": float(self.time), "singular_kind": self.kind,
                "singular_elements": json.dumps([dict(e) for e in self.elements]),
                "singular_mode": self.mode}


@dataclass
class SingularOutcome(FrameOutcome):
    """A frame outcome at a located singular configuration (status ``singular_configuration``
    or, with ``--require-stable``, ``unstable``)."""
    where: SingularInfo | None = None


def singular_outcome(info: SingularInfo, iterations: int, status=Status.SINGULAR_CONFIGURATION,
                     message: str | None = None, counts=None) -> SingularOutcome:
    return SingularOutcome(status, int(iterations), np.nan, np.nan,
                           info.message() if message is None else message,
                           dict(counts or {}), "plain", where=info)


def element_name(e: dict) -> str:
    """``Joint 2 (Crank pin)``: the deck tag without ``Constraint_`` (``Motion_Joint`` ->
    ``Motion``), the id and the label."""
    tag = str(e["tag"])
    short = "Motion" if tag == "Motion_Joint" else tag.replace("Constraint_", "")
    return f"{short} {e['id']}" + (f" ({e['label']})" if e.get("label") else "")


# ---------------------------------------------------------------------- measures
@dataclass(frozen=True)
class Measures:
    """Both singularity measures of one state: ``sigma`` the smallest singular value of the
    scaled active constraint Jacobian (inf without constraint rows) with its left singular
    vector ``u`` over ``model.nc`` rows (inactive rows 0: the self-stress that appears where
    the constraints lose rank), ``stiffness`` |smallest eigenvalue| of the reduced stiffness
    (NaN when not classified or when the frame has neutral directions, whose zero eigenvalues
    hide the one that matters) and the classification ``info``."""
    sigma: float
    u: np.ndarray
    stiffness: float
    info: object
    v: np.ndarray = None     # the motion the constraints allow there (model coordinates)


def scaled_constraints(model, J, active):
    """The active rows of the constraint Jacobian in ``J`` (a KKT Jacobian), dimensionless:
    columns per length (``q_scale``), rotational rows times L. ``(A, rows)``; ``A`` dense, or
    CSR for a sparse ``J``."""
    nq = model.nq
    rows = np.nonzero(active)[0]
    w = np.where(model.row_kind[rows] == 1, model.L, 1.0)
    if hasattr(J, "tocsr"):
        import scipy.sparse as sp  # lazy: large models only
        return sp.diags(w) @ J.tocsr()[nq:, :nq][rows] @ sp.diags(1.0 / model.q_scale), rows
    return np.asarray(J)[nq:, :nq][rows] * w[:, None] / model.q_scale[None, :], rows


def measure(model, data, state) -> Measures:
    """:class:`Measures` of ``state`` from one (counted) Jacobian evaluation."""
    active = data.mask(model)
    J = data.evaluate(model, state, "jacobian").J
    info = classify(model, state, J=J, active=active)
    k = np.nan if info.klass == "unknown" or info.n_zero != 0 else abs(float(info.min_eigenvalue))
    u = np.zeros(model.nc)
    if model.nc == 0 or not np.any(active):
        return Measures(np.inf, u, k, info)
    A, rows = scaled_constraints(model, J, active)
    if hasattr(A, "tocsr") and model.nq > DENSE_LIMIT:
        s, w = _smallest_sparse(A)
        x = np.asarray(A.T @ w).ravel()
    else:
        A = A.toarray() if hasattr(A, "toarray") else A
        U, sv, vh = np.linalg.svd(A, full_matrices=True)
        m, n = A.shape
        s = float(sv[m - 1]) if m <= n else 0.0
        w = U[:, m - 1] if m <= n else U[:, -1]
        x = vh[m - 1] if m <= n else vh[-1]
    u[rows] = w
    return Measures(s, u, k, info, x / model.q_scale)


class Orientation:
    """Which assembly branch a state is on, relative to a reference state (the last accepted
    one): the sign of ``det([A(x); N^T])`` with ``A`` the scaled active constraint Jacobian and
    ``N`` the null space of ``A`` at the reference. The sign is continuous along a branch and
    flips where the path crosses a configuration in which the constraints lose rank an odd
    number of times, so two states on mirrored branches (a crank above and below a toggle)
    differ. It also keeps the constraints' smallest singular value of the recent references:
    :meth:`near` says the reference approaches a singular configuration, where branches may
    meet without a sign change (three legs of a parallel robot reaching their toggle together).
    Dense models only (``nq <= DENSE_LIMIT``); otherwise every state agrees."""

    def __init__(self, model, data):
        self.model, self.data = model, data
        self.on = model.nc > 0 and model.nq <= DENSE_LIMIT
        self.ref = None              # (state, N, sign, sigma)
        self.sigmas = []             # sigma of the recent references, oldest first

    def matrix(self, state):
        if not self.on:
            return None
        model = self.model
        J = self.data.evaluate(model, state, "jacobian").J
        A, _ = scaled_constraints(model, J, self.data.mask(model))
        return A.toarray() if hasattr(A, "toarray") else A

    def reference(self, state, A=None):
        """Make ``state`` (with its matrix ``A`` if known) the reference."""
        if not self.on:
            return
        A = self.matrix(state) if A is None else A
        m, n = A.shape
        if m > n:
            self.ref = None
            return
        _, sv, vh = np.linalg.svd(A, full_matrices=True)
        N = vh[m:]
        sigma = float(sv[m - 1]) if m else np.inf
        self.ref = (state, N, self._sign(A, N), sigma)
        self.sigmas = (self.sigmas + [sigma])[-NEAR_HISTORY:]

    @staticmethod
    def _sign(A, N):
        sign, _ = np.linalg.slogdet(np.vstack([A, N]))
        return float(sign)

    def same(self, ref_state, state, A=None) -> tuple[bool, object]:
        """``(state on ref_state's branch, its matrix)``; the reference is set from
        ``ref_state`` first when it is not the current one."""
        if not self.on:
            return True, None
        if self.ref is None or self.ref[0] is not ref_state:
            self.reference(ref_state)
        if self.ref is None:
            return True, None
        A = self.matrix(state) if A is None else A
        s = self._sign(A, self.ref[1])
        return s != 0.0 and s == self.ref[2], A

    def near(self) -> bool:
        """The reference's constraints' smallest singular value is at most ``NEAR`` of the
        largest of the references before it."""
        s = self.sigmas
        return len(s) > 1 and np.isfinite(s[-1]) and s[-1] <= NEAR * max(s[:-1])


def _smallest_sparse(A):
    """``(sigma_min, left vector)`` of a sparse ``A`` (m <= n rows) by inverse iteration on
    ``A A^T`` (one sparse LU; :class:`InverseIteration`, ``Limits.inverse_steps`` steps)."""
    import scipy.sparse.linalg as spla  # lazy: large models only
    M = (A @ A.T).tocsc()
    x = np.random.default_rng(0).standard_normal(M.shape[0])
    x /= np.linalg.norm(x)
    try:
        lu = spla.splu(M)
    except RuntimeError:                    # exactly singular
        return 0.0, x
    return iterate(InverseIteration(M, lu), LIMITS.inverse_steps, [], x)


@dataclass(frozen=True)
class _Inverse:
    x: np.ndarray
    zero: bool = False          # the iterate vanished or overflowed: sigma_min 0


class InverseIteration(Solver[_Inverse]):
    """Inverse iteration on ``M = A A^T`` (factorised ``lu``) for its smallest eigenvalue: a
    fixed number of steps (the budget; converged to the few digits a diagnosis needs), unless
    the iterate stops being finite (``M`` numerically singular: ``sigma_min`` 0)."""

    out_of_budget = Status.CONVERGED

    def __init__(self, M, lu):
        self.M, self.lu = M, lu

    def init(self, x):
        return _Inverse(x)

    def terminate(self, s):
        return (True, Status.CONVERGED) if s.zero else (False, None)

    def step(self, s, left):
        y = self.lu.solve(s.x)
        n = float(np.linalg.norm(y))
        if not np.isfinite(n) or n == 0.0:
            return Next(replace(s, zero=True))
        return Next(_Inverse(y / n))

    def postprocess(self, s, status, used):
        if s.zero:
            return 0.0, s.x
        return float(np.sqrt(max(float(s.x @ (self.M @ s.x)), 0.0))), s.x


def self_stress_elements(model, u) -> tuple:
    """The constraints taking part in the self-stress ``u``, largest share first (ties in deck
    order): dicts ``tag``, ``id``, ``label``, ``line``, ``share`` (fraction of ``|u|^2``)."""
    share: dict = {}
    first: dict = {}
    for r, ur in enumerate(u):
        ri = model.row_info[r]
        key = (ri["tag"], ri["id"])
        share[key] = share.get(key, 0.0) + float(ur) ** 2
        first.setdefault(key, r)
    tot = sum(share.values()) or 1.0
    top = max(share.values(), default=0.0)
    keys = sorted((k for k in share if share[k] >= SHARE_MIN * top and share[k] > 0),
                  key=lambda k: (-round(share[k] / tot, 6), first[k]))
    return tuple({"tag": k[0], "id": int(k[1]),
                  "label": str(model.row_info[first[k]].get("label", "") or ""),
                  "line": int(model.row_info[first[k]]["line"]),
                  "share": round(share[k] / tot, 6)} for k in keys)


def fold_joint(model, v, elements) -> tuple:
    """``elements`` with the one the linkage folds at first (``fold`` true): of the
    constraints between two bodies, the one whose bodies turn most against each other in the
    singular motion ``v`` (at a dead centre, the joint between the two collinear links)."""
    if v is None or not elements or not len(model.rot_body):
        return elements
    w = np.zeros((model.nb + 1, 3))
    w[model.rot_body] = v[model.rot_idx].reshape(-1, 3)
    rel: dict = {}
    for fam in model.families:
        if not fam.is_constraint or fam.crow is None:
            continue
        b = np.asarray(model.marker_body)[fam.markers]
        b0, b1 = b.min(axis=1), b.max(axis=1)
        two = np.all((b == b0[:, None]) | (b == b1[:, None]), axis=1) & (b0 != b1)
        turn = np.linalg.norm(w[b0] - w[b1], axis=1)
        for i in np.nonzero(two)[0]:
            ri = model.row_info[int(fam.crow[i][0])]
            key = (ri["tag"], int(ri["id"]))
            rel[key] = max(rel.get(key, 0.0), float(turn[i]))
    cand = [e for e in elements if (e["tag"], e["id"]) in rel]
    if not cand:
        return elements
    top = max(rel[(e["tag"], e["id"])] for e in cand)
    first = next(e for e in cand if rel[(e["tag"], e["id"])] >= (1.0 - 1e-6) * top)
    return (dict(first, fold=True),) + tuple(e for e in elements if e is not first)


def path_mode(model, a, b) -> str:
    """The motion from state ``a`` to ``b`` named by the body that moves most (next to a
    singular point the path's direction is its critical mode)."""
    if model.nb == 0 or a is None:
        return ""
    q = model.local_difference(a, b)
    if not np.any(q):
        return ""
    return describe_mode(model, q, "singular").text(short=True)


def diagnose(model, data, near, before, refs, t, threshold=DROP) -> SingularInfo | None:
    """Is ``near`` (the last state reached on the branch, at time ``t``) at a singular
    configuration? Each measure at ``near`` against its largest value over ``refs`` (states
    earlier on the path, or their :class:`Measures`): kinematic if the constraint Jacobian's
    smallest singular value fell to ``threshold`` of it, else a limit point if the reduced
    stiffness' smallest eigenvalue did; None otherwise. ``before``: the state reached before
    ``near`` (the path's direction names the moving body)."""
    mn = measure(model, data, near)
    mr = [r if isinstance(r, Measures) else measure(model, data, r) for r in refs]
    s_ref = max([r.sigma for r in mr if np.isfinite(r.sigma)], default=np.nan)
    if np.isfinite(mn.sigma) and s_ref > 0 and mn.sigma <= threshold * s_ref:
        mode = describe_mode(model, mn.v, "singular").text(short=True) \
            if mn.v is not None and model.nb else ""
        return SingularInfo(t, "dead_point",
                            fold_joint(model, mn.v, self_stress_elements(model, mn.u)), mode)
    k_ref = max([r.stiffness for r in mr if np.isfinite(r.stiffness)], default=np.nan)
    if np.isfinite(mn.stiffness) and k_ref > 0 and mn.stiffness <= threshold * k_ref:
        return SingularInfo(t, "limit_point", (), path_mode(model, before, near))
    return None


def fold_time(model, data, kind, a, b, t_max) -> float:
    """The time of a fold (a singular point where the path turns back in time) from two
    states next to it, ``a`` before ``b`` (``b`` the last reached): there the vanishing measure
    (the constraints' smallest singular value, or the reduced stiffness' smallest eigenvalue)
    goes as the square root of the time left, so its square extrapolates linearly to zero.
    Newton's own factorisation calls the Jacobian singular a little before the fold (about
    1e-7 of the time scale for a slider-crank): the extrapolation covers that gap. Clamped to
    ``[b.t, t_max]``; ``b.t`` when the two do not fit that shape."""
    ma, mb = measure(model, data, a), measure(model, data, b)
    ya, yb = ((ma.sigma, mb.sigma) if kind == "dead_point" else (ma.stiffness, mb.stiffness))
    ya, yb = ya * ya, yb * yb
    if not (np.isfinite(ya) and np.isfinite(yb) and ya > yb > 0 and b.t > a.t):
        return float(b.t)
    return float(min(max(b.t + yb * (b.t - a.t) / (ya - yb), b.t), t_max))


def located_attrs(outcomes) -> dict:
    """Analysis attributes of a run that ended at a located singular configuration (the last
    outcome's :class:`SingularInfo`), else ``{}``."""
    where = getattr(outcomes[-1], "where", None) if outcomes else None
    return where.attrs() if where is not None else {}
