"""Per-frame output datasets, one frame or all frames at once.

:func:`frame_datasets` computes one frame's outputs from one residual + Jacobian evaluation:
reactions (minimum-norm where constraints are redundant), element loads, the stability class,
and for FIM_D's interpolated frames the imbalance and constraint error; it certifies the
frame's outcome on that evaluation. :func:`frames_datasets` produces the same datasets for a
whole list of frames from :func:`poise.model.evaluate.evaluate` (chunks of frames,
one kernel call per tileable family per chunk) and a batched stability classification, so the
per-frame cost is array work; it returns ``None`` where batching does not apply or a frame does
not evaluate to finite values (the caller then uses the frame-by-frame path, which names the
failing element). :func:`output_datasets` holds the datasets common to every analysis.
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError
from poise.model.evaluate import evaluate
from poise.model.frame_batch import batchable, chunk_size
from poise.elements.rotation import euler_313, euler_parameters
from poise.solvers.certify import certify
from poise.solvers.history import STRATEGIES
from poise.solvers.newton import Scales
from poise.solvers.outputs import element_loads, loads_of
from poise.solvers.redundancy import dependent_rows, left_null_basis, min_norm_multipliers
from poise.solvers.stability import (
    DENSE_LIMIT,
    classify,
    classify_dense_frames,
    stability_datasets,
    unknown_info,
)


def frame_datasets(ctx, state, outcomes, on_eval=None):
    """Datasets of one frame. ``on_eval(ev, active)``, if given, is called with the output
    evaluation (all rows active) and the analysis' active-row mask before the outcomes are
    read (FIM_D records its interpolated frames' measures from it: no second evaluation).
    The outcomes are certified on that evaluation (:func:`~poise.solvers.certify.certify`:
    measured imbalance / error; demoted if the tolerances are not met)."""
    model = ctx.model
    # one evaluation (all rows active, slot data kept) serves the minimum-norm reactions,
    # the element loads and the stability classification
    saved = ctx.data.mask(model)
    J = None
    dep = np.asarray(ctx.redundancy, int)
    try:
        ev = model.evaluate(state, need_jac=True, keep=True)
        J = ev.J
        if on_eval is not None:
            on_eval(ev, saved)
        for o in outcomes:
            certify(model, ctx.settings, o, ev.r, np.where(saved, ev.phi, 0.0))
        lam = state.lam
        if len(ctx.redundancy) and model.nc:
            Pfull = J[model.nq:, :model.nq]
            Y = left_null_basis(Pfull, saved)       # one factorisation serves both
            w = np.where(model.row_kind == 1, 1.0 / model.L ** 2, 1.0)
            lam = min_norm_multipliers(Pfull, state.lam, saved, w, Y=Y)
            dep = dependent_rows(Pfull, saved, Y=Y)
        loads = element_loads(model, state, lam=lam, ev=ev)
    except EvaluationError:
        loads = {}
    d = output_datasets(model, [state], {g: (F[None], T[None]) for g, (F, T) in loads.items()},
                        dep, outcomes)
    done = ctx.data.classified
    if done is not None and done[0] is state and len(outcomes) == 1:
        # classified by the solve: also an equilibrium --require-stable refused (neutral)
        d.update(stability_datasets([done[1]]))
    elif all(o.ok for o in outcomes) and J is not None:
        d.update(stability_datasets([classify(model, state, J=J, active=saved)]))
    else:   # the same datasets either way: frames of a sequence are concatenated by key
        d.update(stability_datasets([unknown_info()] * len(outcomes)))
    return d


def redundancy_datasets(model, redundancy) -> dict:
    """``redundant/*``: the deck element and equation of every redundant constraint row."""
    rows = [model.row_info[r] for r in redundancy]
    return {
        "redundant/tag": np.array([r["tag"] for r in rows], dtype=str),
        "redundant/id": np.array([r["id"] for r in rows], dtype=np.int64),
        "redundant/equation": np.array([r["equation"] for r in rows], dtype=str),
        "redundant/line": np.array([r["line"] for r in rows], dtype=np.int64),
    }


def output_datasets(model, frames, loads, dep, outcomes) -> dict:
    """Datasets of ``frames`` (one or many) common to every analysis: ``time``, ``bodies/*``,
    per output group the ids, tags, element loads and (joints, jprims) reaction-uniqueness
    flags, and ``frames/*`` of the ``outcomes``.

    ``loads``: ``{group: (F, T)}`` with arrays (n_frames, n_group, 3); groups missing are
    zero. ``dep``: constraint rows taking part in a dependency (not unique).
    """
    nf = len(frames)
    d = {"time": np.array([s.t for s in frames])}
    d["bodies/id"] = model.body_id
    d["bodies/position"] = np.stack([s.pos for s in frames])
    d["bodies/orientation"] = np.stack([s.rot for s in frames])
    d.update(orientation_datasets(model, frames, d["bodies/orientation"]))
    for g, o in model.outputs.items():
        n_out = len(o["ids"])
        zero = np.zeros((nf, n_out, 3))
        F, T = loads.get(g, (zero, zero))
        d[f"{g}/id"] = np.asarray(o["ids"])
        if g == "forces":
            d["forces/tag"] = np.asarray(o["tag"], dtype=str)
        d[f"{g}/force"] = F
        d[f"{g}/torque"] = T
        if g in ("joints", "jprims"):
            uniq = np.ones(n_out, bool)
            for r in dep:
                ri = model.row_info[r]
                if ri["group"] == g:
                    uniq[ri["owner"]] = False
            d[f"{g}/unique"] = uniq
    d["frames/converged"] = np.array([o.ok for o in outcomes])
    d["frames/iterations"] = np.array([o.iterations for o in outcomes], dtype=np.int64)
    d["frames/imbalance"] = np.array([o.imbalance for o in outcomes])
    d["frames/error"] = np.array([o.error for o in outcomes])
    d["frames/status"] = np.array([o.status.value for o in outcomes], dtype=str)
    d.update(strategy_datasets(outcomes))
    return d


def orientation_datasets(model, frames, rot) -> dict:
    """``bodies/euler_parameters`` (F,B,4), ``bodies/euler_313`` (F,B,3) of the orientations
    ``rot`` (F,B,3,3) and ``bodies/rotation_from_input`` (F,B,3): each state's continuous
    rotation vector (turns counted by State.rotvec; principal, |v| <= pi, for a state without
    it). docs/results-format.md defines them."""
    if all(s.rotvec is not None for s in frames):       # every frame at once
        rv = model.rotation_from_input(None, rot, np.stack([s.rotvec for s in frames]))
    else:
        rv = np.stack([model.rotation_from_input(s) for s in frames])
    return {"bodies/euler_parameters": euler_parameters(rot), "bodies/euler_313": euler_313(rot),
            "bodies/rotation_from_input": rv}


def strategy_datasets(outcomes) -> dict:
    """``frames/strategy`` (the recovery stage that produced each frame, ``plain`` without
    recovery) and ``frames/strategy_iterations`` (F, len(STRATEGIES)): each frame's iterations
    split by stage (columns in :data:`~poise.solvers.history.STRATEGIES` order; they sum to
    ``frames/iterations``)."""
    it = np.zeros((len(outcomes), len(STRATEGIES)), np.int64)
    for k, o in enumerate(outcomes):
        c = o.counts or {"plain": o.iterations}
        for j, name in enumerate(STRATEGIES):
            it[k, j] = int(c.get(name, 0))
        it[k, 0] += int(o.iterations) - int(it[k].sum())   # work not split: plain
    return {"frames/strategy": np.array([o.strategy for o in outcomes], dtype=str),
            "frames/strategy_iterations": it}


def strategy_attrs(datasets) -> dict:
    """Analysis attributes ``iterations_<strategy>``: totals over the frames, and
    ``iterations_total``."""
    it = np.asarray(datasets.get("frames/strategy_iterations", np.zeros((0, len(STRATEGIES)))))
    tot = it.sum(axis=0) if it.size else np.zeros(len(STRATEGIES), np.int64)
    out = {f"iterations_{n}": int(v) for n, v in zip(STRATEGIES, tot)}
    out["iterations_total"] = int(tot.sum())
    return out


def frame_outputs(model, state) -> dict:
    """Per-frame datasets from the model's output hooks (requests, contact points, ...).

    Each hook in ``model.frame_hooks`` is ``hook(model, state) -> {path: array}`` for ONE frame;
    callers stack frames along a new leading axis (see :func:`stack_frames`).
    """
    out = {}
    for hook in getattr(model, "frame_hooks", []):
        out.update(hook(model, state))
    return out


def stack_frames(per_frame: list[dict]) -> dict:
    """Stack a list of per-frame dicts along axis 0 (keys ending in ``/id`` are not stacked)."""
    if not per_frame:
        return {}
    out = {}
    for k in per_frame[0]:
        if k.endswith("/id") or k.endswith("/tag") or k.endswith("/label"):
            out[k] = np.asarray(per_frame[0][k])
        else:
            out[k] = np.stack([np.asarray(f[k]) for f in per_frame])
    return out


def frames_datasets(ctx, frames, outcomes, measure=None) -> dict | None:
    """Datasets of all ``frames`` (concatenated along the frame axis), as the frame-by-frame
    path writes them.

    Parameters
    ----------
    ctx : Context
        Provides the model, the settings, the active and the redundant rows.
    frames : list of State
    outcomes : list of FrameOutcome (one per frame)
    measure : callable or None
        ``measure(k, imbalance, constraint_error, worst_equation)`` for every frame ``k``, as
        measured on its evaluation (inactive, redundant rows excluded) by
        :func:`poise.solvers.certify.certify`, which also certifies every outcome.
    """
    model = ctx.model
    if not frames or not batchable(model):
        return None
    sc = Scales(model, ctx.settings)
    F = len(frames)
    nq, nc = model.nq, model.nc
    saved = ctx.data.mask(model)
    red = np.asarray(ctx.redundancy, int)
    dep = red
    w = np.where(model.row_kind == 1, 1.0 / model.L ** 2, 1.0)
    loads = {}
    infos = []
    C = chunk_size(model)
    try:
        for a in range(0, F, C):
            chunk = frames[a:a + C]
            ev = evaluate(model, chunk, "jacobian")
            for j in range(len(chunk)):
                got = certify(model, ctx.settings, outcomes[a + j], ev.r[j],
                              np.where(saved, ev.phi[j], 0.0), sc)
                if measure is not None:
                    measure(a + j, *got)
            lam = np.stack([s.lam for s in chunk]) if nc else np.zeros((len(chunk), 0))
            if len(red) and nc:
                lam = lam.copy()
                for j in range(len(chunk)):
                    Pf = ev.J[j, nq:, :nq]
                    Y = left_null_basis(Pf, saved)
                    lam[j] = min_norm_multipliers(Pf, lam[j], saved, w, Y=Y)
                    if a + j == 0:
                        dep = dependent_rows(Pf, saved, Y=Y)
            for g, (Fg, Tg) in loads_of(model, ev.items, lam.ravel(), frames=len(chunk)).items():
                n_out = len(model.outputs[g]["ids"])
                loads.setdefault(g, []).append((Fg.reshape(-1, n_out, 3),
                                                Tg.reshape(-1, n_out, 3)))
            ok = np.array([o.ok for o in outcomes[a:a + C]])
            if model.nq <= DENSE_LIMIT:
                infos += classify_dense_frames(model, ev.J, saved, ok)
            else:                                     # sparse inertia, frame by frame
                infos += [classify(model, None, J=ev.J[j], active=saved) if ok[j] else
                          unknown_info()
                          for j in range(len(chunk))]
    except EvaluationError:
        return None
    d = output_datasets(model, frames, {g: (np.concatenate([x[0] for x in parts]),
                                            np.concatenate([x[1] for x in parts]))
                                        for g, parts in loads.items()}, dep, outcomes)
    d.update(stability_datasets(infos))
    return d
