"""Compliance matrix of an equilibrium (MotionSolve GTCMAT; ``Param_Static compliance_delta``).

For markers ``1..M`` block ``(i, j)`` of ``C`` (6M x 6M) is the displacement of marker ``i``
per unit force/torque at marker ``j`` of the *constrained* system, from the tangent stiffness
without the ``stability`` term: ``exact`` (default, one KKT factorisation; pseudo-inverse and
NaN along zero-stiffness directions when singular) or ``fd`` (finite-difference re-solves).
Written per frame with ``frames/compliance_flag``; the default marker selection is bounded
(:data:`AUTO_MAX_BODIES`, :data:`AUTO_MAX_ENTRIES`). Definitions, flags and selection:
docs/solvers.md, "Compliance".
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError, UsageError
from poise.core.wording import plural
from poise.model.evaluate import evaluate
from poise.model.frame_batch import batchable, chunk_size
from poise.model.model import log_so3
from poise.solvers.data import SolveData
from poise.solvers.history import History
from poise.solvers.linalg import Factor, SingularMatrix
from poise.solvers.newton import newton
from poise.solvers.record import ComplianceRecord

AUTO_MAX_BODIES = 100
AUTO_MAX_ENTRIES = 4_000_000   # auto: F x (6M)^2 above this (32 MB) is skipped with a note
REDUCED_MAX_NQ = 3000          # singular frames: dense reduced stiffness up to this size
UNITS = ("block rows (translation, rotation) x columns (force, torque): "
         "translation/force [length/force], translation/torque [1/force], "
         "rotation/force [rad/force], rotation/torque [rad/(force*length)]; global axes")
ZERO_REL = 1e-9            # singular values of the reduced stiffness below this x largest: zero
NULL_REL = 1e-10           # constraint-Jacobian singular values below this x largest: null space
MOVES_TOL = 1e-6           # |G N z| above this: the marker component moves in a free mode


def parse_markers(value) -> str:
    """Normalised ``compliance_markers``: ``auto``, ``all``, ``none`` or space-separated marker
    ids (accepts ``"10,20"``, ``"10 20"``, a sequence of ints). Raises ValueError."""
    if value is None:
        return "none"
    if isinstance(value, (list, tuple, np.ndarray)):
        items = [str(v) for v in value]
    else:
        s = str(value).strip()
        if s.lower() in ("auto", "all", "none"):
            return s.lower()
        items = s.replace(",", " ").split()
    if not items:
        raise ValueError("compliance_markers is empty; expected marker ids, 'all', 'auto' "
                         "or 'none'")
    ids = []
    for it in items:
        try:
            v = int(it)
        except ValueError:
            raise ValueError(f"compliance_markers: {it!r} is not a marker id; expected "
                             "integers, 'all', 'auto' or 'none'") from None
        if v < 0:
            raise ValueError(f"compliance_markers: marker id {v} is negative")
        ids.append(v)
    return " ".join(str(v) for v in ids)


def _cg_marker_rows(model) -> np.ndarray:
    """Marker row of each body's CG marker (the body's marker closest to its CG)."""
    nb = model.nb
    mb = model.marker_body
    d = np.linalg.norm(model.marker_s0, axis=1)
    rows = np.full(nb, -1, np.intp)
    order = np.lexsort((d, mb))                  # by body, then by distance from the CG
    bodies = mb[order]
    first = np.ones(order.size, bool)
    first[1:] = bodies[1:] != bodies[:-1]
    for k in order[first]:
        if mb[k] < nb:
            rows[mb[k]] = k
    return rows


def select(model, settings):
    """``(marker rows, note)``: the markers to report, or ``(None, note)`` when skipped."""
    spec = getattr(settings, "compliance_markers", "none")
    if spec == "none":
        return None, ("compliance matrix not requested: ask for it with --compliance-markers "
                      "all (or marker ids), Param_Static compliance_markers=\"all\" or "
                      "poise.solve(deck, compliance_markers=\"all\")")
    if spec in ("auto", "all"):
        if spec == "auto" and model.nb > AUTO_MAX_BODIES:
            return None, (f"compliance matrix skipped: {model.nb} bodies > {AUTO_MAX_BODIES}; "
                          "ask for it with --compliance-markers all (or marker ids), or "
                          "Param_Static compliance_markers=\"all\"")
        rows = _cg_marker_rows(model)
        return rows[rows >= 0], ""
    index = {int(m): k for k, m in enumerate(model.marker_id)}
    rows = []
    for m in spec.split():
        if int(m) not in index:
            raise UsageError(f"compliance_markers: marker id {m} is not a Reference_Marker of "
                             "the deck")
        rows.append(index[int(m)])
    return np.array(rows, np.intp), ""


def marker_map(model, state, rows) -> np.ndarray:
    """``G`` (6M, nq): tangent increment -> (translation, rotation) of each marker, global."""
    return marker_maps(model, [state], rows)[0]


def marker_maps(model, states, rows) -> np.ndarray:
    """:func:`marker_map` of many frames at once, (F, 6M, nq) (vectorised over frames and
    markers): rows ``[I, -[r]x]`` and ``[0, I]`` at the marker's body, zero for ground."""
    rows = np.asarray(rows, np.intp)
    F, M, nb = len(states), len(rows), model.nb
    G = np.zeros((F, 6 * M, model.nq))
    mb = model.marker_body[rows]
    mv = np.flatnonzero(mb < nb)                     # markers on moving bodies
    if not (F and mv.size):
        return G
    b = mb[mv]
    rot = np.stack([st.rot for st in states])[:, b]                     # (F, m, 3, 3)
    r = np.einsum("fmij,mj->fmi", rot, model.marker_s0[rows[mv]])       # lever from the CG
    o = model.body_off[b]
    eye = np.arange(3)
    tr = 6 * mv[:, None] + eye                                          # (m, 3) rows
    G[:, tr, o[:, None] + eye] = 1.0
    rig = model.body_kind[b] == 0
    if rig.any():
        zero = np.zeros(r.shape[:2])
        x, y, z = r[..., 0], r[..., 1], r[..., 2]
        S = np.stack([np.stack([zero, z, -y], -1), np.stack([-z, zero, x], -1),
                      np.stack([y, -x, zero], -1)], -2)                 # -[r]x  (F, m, 3, 3)
        k = np.flatnonzero(rig)
        ro = o[k][:, None] + 3 + eye                                    # (k, 3) rotation cols
        G[:, tr[k][:, :, None], ro[:, None, :]] = S[:, k]
        G[:, (tr[k] + 3)[:, :, None], ro[:, None, :]] = np.eye(3)
    return G


def _exact(model, state, active, G, singular_hint=False):
    """``(C, flag)`` from the KKT Jacobian at ``state`` (one factorisation, all columns)."""
    nq = model.nq
    J = model.evaluate(state, need_jac=True, eps_mass=0.0, active=active).J
    if not singular_hint:
        rhs = np.zeros((model.N, G.shape[0]))
        rhs[:nq] = G.T
        try:
            X = Factor(J).solve(rhs)
            if np.all(np.isfinite(X)):
                return G @ X[:nq], "ok"
        except SingularMatrix:
            pass
    return _reduced(model, J, active, G)


def _reduced(model, J, active, G):
    """Dense pseudo-inverse of the reduced stiffness; NaN where a free direction enters."""
    nq = model.nq
    if nq > REDUCED_MAX_NQ:                 # too large for a dense null space: say so
        return np.full((G.shape[0], G.shape[0]), np.nan), "singular"
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    d = model.q_scale
    Gs = G / d[None, :]
    K = J[:nq, :nq] / d[:, None] / d[None, :]
    Pq = J[nq:, :nq][np.asarray(active, bool)] / d[None, :]
    if Pq.shape[0]:
        _, s, vh = np.linalg.svd(Pq, full_matrices=True)
        rk = int(np.sum(s > NULL_REL * s.max())) if s.size and s.max() > 0 else 0
        N = vh[rk:].T
    else:
        N = np.eye(nq)
    GN = Gs @ N
    if N.shape[1] == 0:
        return np.zeros((G.shape[0], G.shape[0])), "ok"
    Kr = N.T @ K @ N
    U, s, Vt = np.linalg.svd(Kr)
    smax = s.max() if s.size else 0.0
    nz = s > ZERO_REL * smax if smax > 0 else np.zeros(s.size, bool)
    C = (GN @ Vt[nz].T) @ ((U[:, nz].T @ GN.T) / s[nz][:, None])
    if nz.all():
        return C, "ok"
    moves = np.abs(GN @ Vt[~nz].T).max(axis=1) > MOVES_TOL      # rows: displaced freely
    loads = np.abs(GN @ U[:, ~nz]).max(axis=1) > MOVES_TOL      # columns: load a free mode
    C[moves, :] = np.nan
    C[:, loads] = np.nan
    return C, "singular"


class _Loaded(SolveData):
    """Solve data whose evaluations add a constant generalised force ``f`` to the applied
    loads (the Newton re-solves of the ``fd`` method evaluate through it)."""

    def __init__(self, active, f):
        super().__init__(active)
        self._f = f

    def evaluate(self, model, states, what="jacobian", **kw):
        ev = super().evaluate(model, states, what, **kw)
        if what != "phi":
            ev.r = ev.r - self._f
        return ev


def _fd(model, state, active, G, rows, settings):
    """``(C, flag)`` by re-solving the equilibrium under a load ``delta`` per column."""
    from dataclasses import replace

    delta = float(settings.compliance_delta)
    ncol = G.shape[0]
    C = np.full((ncol, ncol), np.nan)
    P0, A0, _ = model.marker_kinematics(state)
    P0, A0 = P0[rows], A0[rows]
    tight = replace(settings, max_imbalance=min(settings.max_imbalance, 1e-6 * delta),
                    max_error=min(settings.max_error, 1e-9))
    failed = False
    for c in range(ncol):
        h = delta if c % 6 < 3 else delta * model.L
        st = None
        for s in (tight, settings):
            st, out = newton(model, state.copy(), s, History(), 0, _Loaded(active, G[c] * h),
                             max_iter=50)
            if out.ok:
                break
        if not out.ok:
            failed = True
            continue
        P1, A1, _ = model.marker_kinematics(st)
        u = np.empty((len(rows), 6))
        u[:, :3] = P1[rows] - P0
        u[:, 3:] = log_so3(np.matmul(A1[rows], np.swapaxes(A0, 1, 2)))
        C[:, c] = u.ravel() / h
    return C, ("fd_failed" if failed else "ok")


def frame_compliance(model, state, active, rows, settings, stability=""):
    """``(C (6M, 6M), flag)`` of one converged frame."""
    G = marker_map(model, state, rows)
    if model.nq == 0:
        return np.zeros((G.shape[0], G.shape[0])), "ok"
    try:
        if getattr(settings, "compliance_method", "exact") == "fd":
            C, flag = _fd(model, state, active, G, rows, settings)
        else:
            C, flag = _exact(model, state, active, G, singular_hint=(stability == "neutral"))
    except EvaluationError:
        return np.full((G.shape[0], G.shape[0]), np.nan), "not_converged"
    if flag == "ok" and stability == "unstable":
        flag = "unstable"
    return C, flag


def _exact_frames(model, frames, active, rows, classes):
    """``exact`` compliance of many converged frames at once (batched evaluation and stacked
    dense solves), or None where batching does not apply. Frames whose stacked solve is not
    trustworthy (neutral, or a large residual) go through :func:`_exact` one by one."""
    if len(frames) < 2 or not batchable(model):
        return None
    nq = model.nq
    off = nq + np.flatnonzero(~np.asarray(active, bool))
    out = []
    Cn = chunk_size(model)
    for a in range(0, len(frames), Cn):
        chunk = frames[a:a + Cn]
        J = np.array(evaluate(model, chunk, "jacobian").J)     # all rows active
        J[:, off, :] = 0.0                                 # redundant rows: dl = 0, as the
        J[:, :, off] = 0.0                                 # analysis' own Jacobian has them
        J[:, off, off] = 1.0
        G = marker_maps(model, chunk, rows)                              # (f, 6M, nq)
        rhs = np.zeros((len(chunk), model.N, G.shape[1]))
        rhs[:, :nq] = np.swapaxes(G, 1, 2)
        with np.errstate(all="ignore"):
            try:
                X = np.linalg.solve(J, rhs)
            except np.linalg.LinAlgError:
                X = np.full_like(rhs, np.nan)
            res = np.linalg.norm(np.matmul(J, X) - rhs, axis=(1, 2))
        for j in range(len(chunk)):
            cls = classes[a + j]
            if cls == "neutral" or not (res[j] <= 1e-8 * np.linalg.norm(rhs[j])) \
                    or not np.all(np.isfinite(X[j])):
                C, flag = _reduced(model, J[j], active, G[j])
            else:
                C, flag = G[j] @ X[j, :nq], "ok"
            if flag == "ok" and cls == "unstable":
                flag = "unstable"
            out.append((C, flag))
    return out


def compliance_step(model, frame_set, redundancy, settings) -> tuple:
    """The driver's compliance step after the frames are measured: ``(ComplianceRecord or
    None, analysis attributes)`` of the frames of ``frame_set`` (its certified outcomes and
    stability classes decide what is computed)."""
    frames, outcomes = list(frame_set.states), frame_set.outcomes
    attrs = {}
    rows, note = select(model, settings)
    n = 6 * (len(rows) if rows is not None else 0)
    if rows is not None and getattr(settings, "compliance_markers", "auto") == "auto" \
            and len(frames) * n * n > AUTO_MAX_ENTRIES:
        rows, note = None, (f"compliance matrix skipped: {len(frames)} frames x ({n} x {n}) "
                            f"entries > {AUTO_MAX_ENTRIES}; ask for it with "
                            "--compliance-markers all (or marker ids), or Param_Static "
                            "compliance_markers=\"all\"")
    if rows is None:
        attrs["compliance_note"] = note
        return None, attrs
    method = getattr(settings, "compliance_method", "exact")
    active = np.ones(model.nc, bool)
    active[np.asarray(redundancy, int)] = False
    stab = frame_set.stability
    Cs, flags = [], []
    cache = {}
    t_dep = model.depends_on_time()
    classes = [str(stab[k].klass) if k < len(stab) else "" for k in range(len(frames))]
    if method == "exact" and model.nq and len(frames) > 1:
        ok = [k for k, o in enumerate(outcomes) if o.ok]
        try:
            got = _exact_frames(model, [frames[k] for k in ok], active, rows,
                                [classes[k] for k in ok])
        except EvaluationError:
            got = None
        if got is not None:
            byk = dict(zip(ok, got))
            Cs = [byk[k][0] if k in byk else np.full((n, n), np.nan) for k in range(len(frames))]
            flags = [byk[k][1] if k in byk else "not_converged" for k in range(len(frames))]
            frames = []                                   # done: skip the loop below
    for k, (st, o) in enumerate(zip(frames, outcomes)):
        if not o.ok:
            Cs.append(np.full((n, n), np.nan))
            flags.append("not_converged")
            continue
        key = (st.pos.tobytes(), st.rot.tobytes(), st.lam.tobytes(),
               None if st.extra is None else st.extra.tobytes(), st.t if t_dep else None)
        if key not in cache:
            cache[key] = frame_compliance(model, st, active, rows, settings, classes[k])
        C, flag = cache[key]
        Cs.append(C)
        flags.append(flag)
    rec = ComplianceRecord(matrices=np.stack(Cs) if Cs else np.zeros((0, n, n)),
                           flags=tuple(flags), method=method,
                           marker_id=np.asarray(model.marker_id)[rows].astype(np.int64))
    attrs["compliance_method"] = method
    attrs["compliance_units"] = UNITS
    if method == "fd":
        attrs["compliance_delta"] = float(settings.compliance_delta)
    said = {"singular": "free mechanism direction: NaN where it enters",
            "unstable": "unstable equilibrium: written as the KKT solve gives it",
            "fd_failed": "fd re-solve did not converge: NaN columns",
            "not_converged": "frame not converged: NaN"}
    parts = [f"{plural(sum(f == k for f in flags), 'frame')} {k} ({v})" for k, v in said.items()
             if k in flags]
    if note or parts:
        attrs["compliance_note"] = "; ".join([note] * bool(note) + parts)
    return rec, attrs
