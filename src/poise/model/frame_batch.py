"""Evaluate many frames of one model at once (quasi-static outputs).

A quasi-static run writes per output frame the reactions, element loads, stability class and
(FIM_D's interpolated frames) the imbalance, each needing the residual and the KKT Jacobian at
the frame; one Python pass over every family per frame costs far more than the numerical work
on small models. Here all ``F`` frames are evaluated together: the families whose element type
declares them tileable (:func:`poise.elements.registry.tileable_kernels`) are tiled across frames
and called once, any other once per frame, and everything is scattered with one ``bincount``
(how: :func:`evaluate_frames`). The result equals ``F`` calls of ``Model.evaluate(state,
need_jac=True, keep=True)`` with all rows active (tests compare every deck's frames); models whose
forces read constraint reactions or with ``N > MAX_N`` unknowns are not batched
(:func:`batchable`).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from poise.elements.registry import tileable_kernels
from poise.core.errors import EvaluationError
from poise.elements.kernel import (SlotKinematics, constraint_jacobian_local, local_pattern,
                                   local_residual_tangent, slot_kinematics)
from poise.core import phases
from poise.model.model import EvalContext, _constraint_ext

MAX_N = 400                 # KKT size up to which frames are batched (dense (F, N, N) blocks)
CHUNK_ENTRIES = 4_000_000   # dense Jacobian entries per chunk of frames (32 MB)


def _tileable():
    """Kernels declared tileable by their element types (:mod:`poise.elements.registry`)."""
    return tileable_kernels()


#: per-instance index arrays of tileable families shifted per frame: attribute -> table
#: (``angle`` = the continuous-angle table ``State.angle``)
OFFSET_ARRAYS = {"angle_index": "angle"}


def batchable(model) -> bool:
    """True if :func:`evaluate_frames` applies to ``model``."""
    return model.reaction_feed is None and model.N <= MAX_N


def chunk_size(model) -> int:
    """Frames per call of :func:`evaluate_frames` (bounded dense Jacobian memory)."""
    return max(1, CHUNK_ENTRIES // max(1, model.N * model.N))


@dataclass
class FrameEvaluation:
    """Residuals and Jacobians of ``F`` frames (all constraint rows active).

    Attributes
    ----------
    r : (F, nq) generalised force imbalance per frame
    phi : (F, nc) constraint values per frame
    J : (F, N, N) dense KKT Jacobians (``None`` without ``need_jac``)
    items : list of ``(family, kin, rho, phi_y)`` over the stacked instances (frame-major:
        instance ``f * n + i``), the ``family`` a tiled copy whose ``owner`` / ``crow`` are
        shifted per frame (output group size / ``nc``) for :func:`poise.elements.loads.loads_of`
    """

    r: np.ndarray
    phi: np.ndarray
    J: np.ndarray | None
    items: list = field(default_factory=list)


def _tile_family(fam, F, model, exact: bool):
    """Shallow copy of ``fam`` covering ``F`` frames (instance ``f * n + i``)."""
    n = fam.n
    t = copy.copy(fam)
    fo = np.arange(F)
    nm = len(model.marker_id)
    t.markers = (fam.markers[None] + (nm * fo)[:, None, None]).reshape(F * n, -1)
    t.slot_kind = np.tile(fam.slot_kind, (F, 1))
    group = getattr(fam, "group", None)
    n_out = len(model.outputs[group]["ids"]) if group in model.outputs else 0
    t.owner = (fam.owner[None] + (n_out * fo)[:, None]).ravel()
    if fam.is_constraint:
        t.crow = (fam.crow[None] + (model.nc * fo)[:, None, None]).reshape(F * n, -1)
    if exact:
        skip = {"markers", "slot_kind", "owner", "crow", "gcol", "scols", "slot_ml"}
        na = len(model.angle_I)
        for k, v in vars(fam).items():
            if k in skip or not isinstance(v, np.ndarray) or v.ndim == 0 or v.shape[0] != n:
                continue
            rep = np.tile(v, (F,) + (1,) * (v.ndim - 1))
            if k in OFFSET_ARRAYS:
                off = (na * fo).reshape((F,) + (1,) * v.ndim)
                rep = np.where(v[None] >= 0, v[None] + off, v[None]).reshape(rep.shape)
            setattr(t, k, rep)
    return t


def _slice_kin(kin, a, b):
    return SlotKinematics(Y=kin.Y[a:b], V=kin.V[a:b], pt=kin.pt[a:b], slot_ml=kin.slot_ml,
                          K=kin.K)


def _stack_ext(outs, at):
    """Stack the optional ``ext`` dicts (item ``at``) of per-frame kernel outputs."""
    exts = [o[at] if len(o) > at else None for o in outs]
    if all(e is None for e in exts):
        return None
    keys = set().union(*[e.keys() for e in exts if e])
    res = {}
    for k in keys:
        vals = [None if e is None else e.get(k) for e in exts]
        res[k] = None if any(v is None for v in vals) else np.concatenate(vals)
    return res


def evaluate_frames(model, states, need_jac: bool = True) -> FrameEvaluation:
    """Evaluate ``states`` (all constraint rows active). See the module docstring.

    Raises
    ------
    EvaluationError
        A kernel produced NaN/Inf in some frame (callers fall back to frame-by-frame outputs,
        which name the element).

    All ``F`` frames are evaluated together:

    * marker kinematics for all frames in one array operation, ``(F, nm, 3)`` and ``(F, nm, 3, 3)``;
    * the joint primitives and marker-pair force laws (:func:`_tileable`: no
      time, marker-table or scalar-unknown reads) are *tiled*: a shallow copy whose per-instance
      arrays are repeated ``F`` times (marker indices shifted by ``nm`` per frame, continuous-angle
      indices by ``na``), so one kernel call covers every frame;
    * any other family (motions and expression forces read the analysis time, curves the scalar
      unknowns, ...) is called once per frame with that frame's context — exactly what
      :meth:`Model.evaluate` does — and its outputs are stacked in the same frame-major order;
    * local residuals and tangents of the stacked instances go through the same slot kernel
      (:func:`local_residual_tangent`) with the family's :class:`LocalPattern`; the residual
      ``(F, nq)``, constraints ``(F, nc)`` and dense per-frame KKT Jacobians ``(F, N, N)`` are
      scattered with one ``bincount`` each.
    """
    t_start = phases.now()
    try:
        return _evaluate_frames(model, states, need_jac)
    finally:
        phases.add("evaluate", phases.now() - t_start)


def _evaluate_frames(model, states, need_jac):

    F = len(states)
    nb, nq, nc, N = model.nb, model.nq, model.nc, model.N
    nm = len(model.marker_id)
    mb = model.marker_body
    posx = np.zeros((F, nb + 1, 3))
    rotx = np.zeros((F, nb + 1, 3, 3))
    posx[:, :nb] = np.stack([s.pos for s in states])
    rotx[:, :nb] = np.stack([s.rot for s in states])
    rotx[:, nb] = np.eye(3)
    P = posx[:, mb] + np.einsum("fnij,nj->fni", rotx[:, mb], model.marker_s0)
    A = np.matmul(rotx[:, mb], model.marker_A0)
    Pf = P.reshape(F * nm, 3)
    Af = A.reshape(F * nm, 3, 3)
    posf = posx.reshape(F * (nb + 1), 3)
    mbf = (mb[None] + ((nb + 1) * np.arange(F))[:, None]).ravel()
    lam = np.stack([s.lam for s in states]) if nc else np.zeros((F, 0))
    lamf = lam.ravel()
    angf = np.concatenate([s.angle for s in states]) if len(model.angle_I) else np.zeros(0)
    extf = np.concatenate([s.extra for s in states]) if model.n_extra else None
    # tiled families see every frame at once: one time per frame, stacked marker tables
    ctx_t = EvalContext(t=np.array([s.t for s in states], float), angle=angf, P=Pf, A=Af,
                        extra=extf)
    ctxs = None
    tiles = _tile_cache(model, F)
    fo = np.arange(F)
    r = np.zeros(F * nq)
    phi = np.zeros(F * nc)
    items = []
    ridx, rval, jidx, jval = [], [], [], []
    for fi in model.eval_order:
        fam = model.families[fi]
        t, exact = tiles[fi]
        n = fam.n
        kin = slot_kinematics(t.markers, fam.slot_ml, t.slot_kind, Pf, Af, mbf, posf)
        U = fam.U
        lt = lamf[t.crow] if fam.is_constraint else None
        if exact:
            if fam.is_constraint:
                out = t.constraints(kin, lt, ctx_t)
            else:
                out = t.forces(kin, ctx_t, need_jac)
        else:
            if ctxs is None:
                ctxs = [EvalContext(t=s.t, angle=s.angle, P=P[f], A=A[f], extra=s.extra)
                        for f, s in enumerate(states)]
            outs = []
            for f in range(F):
                kf = _slice_kin(kin, f * n, (f + 1) * n)
                if fam.is_constraint:
                    outs.append(fam.constraints(kf, lam[f][fam.crow], ctxs[f]))
                else:
                    outs.append(fam.forces(kf, ctxs[f], need_jac))
            k = 3 if fam.is_constraint else 2
            out = [None if outs[0][j] is None else np.concatenate([o[j] for o in outs])
                   for j in range(k)]
            ext = _stack_ext(outs, k)
            if ext is not None:
                out.append(ext)
        if fam.is_constraint:
            ph, phy, G = out[:3]
            ext = out[3] if len(out) > 3 else None
            rho = np.einsum("nmy,nm->ny", phy, lt)
            if U:
                ext = _constraint_ext(ext, lt, F * n, fam.m, U)
            phi[t.crow.ravel()] = ph.ravel()
        else:
            rho, G = out[:2]
            ext = out[2] if len(out) > 2 else None
            phy = None
        items.append((t, kin, rho, phy))
        pat = local_pattern(fam)
        rl, Kl = local_residual_tangent(kin, rho, G, fam.slot_ml, fam.K, need_jac, ext, U, pat)
        if not np.isfinite(rl).all():
            raise EvaluationError(f"element family {fam.name} produced a non-finite value")
        g = fam.gcol                                                  # (n, L)
        gv = g >= 0
        ridx.append(((g + nq * fo[:, None, None]) * gv - (~gv)).reshape(F * n, -1))
        rval.append(rl)
        if need_jac:
            L = g.shape[1]
            li, lj = np.nonzero(pat.kmask)
            _add_block(jidx, jval, g[:, li], g[:, lj], Kl.reshape(F * n, L * L)[:, li * L + lj],
                       F, N)
            if fam.is_constraint:
                Pq = constraint_jacobian_local(kin, phy, fam.K)
                if U:
                    Pq = np.concatenate([Pq, ext["phi_s"]], axis=2)
                pr, pc = np.nonzero(pat.pmask)
                rows = nq + fam.crow
                vals = Pq[:, pr, pc]
                _add_block(jidx, jval, rows[:, pr], g[:, pc], vals, F, N)
                _add_block(jidx, jval, g[:, pc], rows[:, pr], vals, F, N)
    if ridx:
        idx = np.concatenate([i.ravel() for i in ridx])
        val = np.concatenate([v.ravel() for v in rval])
        ok = idx >= 0
        r = np.bincount(idx[ok], weights=val[ok], minlength=F * nq)
    r = r.reshape(F, nq)
    phi = phi.reshape(F, nc)
    if model.gravity_on:
        mg = model.body_mass[:, None]
        for f, s in enumerate(states):
            g = model.gravity if model.gravity_fn is None else model.gravity_fn(s.t)
            r[f, model.trans_idx] -= (mg * g[None, :]).ravel()
    if not (np.isfinite(r).all() and np.isfinite(phi).all()):
        raise EvaluationError("non-finite residual in a batched frame evaluation")
    J = None
    if need_jac:
        idx = np.concatenate(jidx) if jidx else np.zeros(0, np.int64)
        val = np.concatenate(jval) if jval else np.zeros(0)
        J = np.bincount(idx, weights=val, minlength=F * N * N).reshape(F, N, N)
    return FrameEvaluation(r=r, phi=phi, J=J, items=items)


def _add_block(jidx, jval, rows, cols, vals, F, N):
    """Register dense-Jacobian entries ``(rows, cols)`` (n, E) of every frame: flat index
    ``f N^2 + row N + col``; entries with a negative row or column are dropped."""
    ok = (rows >= 0) & (cols >= 0)                                  # (n, E)
    base = (rows * N + cols)[ok]                                    # (k,)
    flat = (base[None, :] + (N * N * np.arange(F))[:, None]).ravel()
    v = vals.reshape(F, *rows.shape)[:, ok].ravel()
    jidx.append(flat.astype(np.int64))
    jval.append(v)


def _tile_cache(model, F):
    """Tiled families for ``F`` frames, cached on the model (same F reused across chunks)."""
    cache = getattr(model, "_frame_tiles", None)
    if cache is None or cache[0] != F:
        exact_types = _tileable()
        tiles = []
        for fam in model.families:
            hook = getattr(fam, "tile_frames", None)          # None: not tileable
            exact = type(fam) in exact_types or hook is not None   # readers: not batchable()
            t = _tile_family(fam, F, model, exact)
            if exact and hook is not None:
                hook(t, F, model)
            tiles.append((t, exact))
        cache = (F, tiles)
        model._frame_tiles = cache
    return cache[1]
