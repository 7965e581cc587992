"""The output frames measured: one frame or all frames at once, as a typed record.

:func:`measure_frame` measures one frame from one residual + Jacobian evaluation: it certifies
the frame's outcome there, computes reactions (minimum-norm where constraints are redundant),
element loads, the stability class, and for FIM_D's interpolated frames the imbalance and
constraint error. :func:`measure_frames` does the same for a whole list of frames from
:func:`poise.model.evaluate.evaluate` (chunks of frames, one kernel call per tileable family
per chunk) and a batched stability classification, so the per-frame cost is array work; it
returns ``None`` where batching does not apply or a frame does not evaluate to finite values
(the caller then measures frame by frame, which names the failing element). Both give a
:class:`~poise.solvers.record.FrameSet` (:func:`frame_set`); :mod:`poise.results.layout`
lays it out in the file.
"""
from __future__ import annotations

import numpy as np

from poise.core import memory
from poise.core.lean import where
from poise.core.errors import EvaluationError
from poise.elements.rows import group_owner
from poise.model.evaluate import evaluate
from poise.model.frame_batch import batchable, chunk_size
from poise.solvers.certify import certify
from poise.solvers.newton import Scales
from poise.solvers.outputs import element_loads, loads_of
from poise.solvers.path import cached_info
from poise.solvers.record import FrameSet, GroupLoads
from poise.solvers import stability
from poise.solvers.redundancy import (column_scale, dependent_rows, left_null_basis,
                                      min_norm_multipliers)
from poise.solvers.stability import (
    DENSE_LIMIT,
    classify,
    classify_dense_frames,
    unknown_info,
)


def measure_frame(env, redundancy, state, outcomes) -> FrameSet:
    """The :class:`~poise.solvers.record.FrameSet` of one frame. The outcomes are certified
    on its output evaluation (:func:`~poise.solvers.certify.certify`: measured imbalance /
    error; demoted if the tolerances are not met): the set holds the certified ones and the
    frame's measures (None if it could not be evaluated)."""
    model = env.model
    # one evaluation (all rows active, slot data kept) serves the minimum-norm reactions,
    # the element loads and the stability classification
    saved = env.data.mask(model)
    J = columns = None
    dep = np.asarray(redundancy, int)
    outcomes = list(outcomes)
    measured = None
    done = env.data.classified
    known = (done[1] if done is not None and done[0] is state
             else cached_info(env.data, state))
    try:
        # in the solve's workspace: its buffers serve, no second set held by J till the end
        ev = model.evaluate(state, need_jac=True, keep=True, workspace=env.data.workspace)
        J = ev.J
        phi = where(saved, ev.phi, 0.0)
        for i, o in enumerate(outcomes):
            outcomes[i], measured = certify(model, env.settings, o, ev.r, phi)
        lam = state.lam
        if len(redundancy) and model.nc:
            Pfull = J[model.nq:, :model.nq]
            Y = left_null_basis(Pfull, saved, column_scale(model))   # one factorisation, both
            w = where(model.row_kind == 1, 1.0 / model.L ** 2, 1.0)
            lam = min_norm_multipliers(state.lam, saved, w, Y)
            dep = dependent_rows(saved, Y)
        loads = element_loads(model, state, lam=lam, ev=ev)
        ev = Pfull = Y = None     # the evaluation's kept slot data go before the classification
        if not model.assembler.dense:        # ... so do the assembly buffers (J keeps its data):
            if known is None:                # the model's column order (its pattern's)
                columns = _kkt_columns(model)
            if env.kind == "static":         # the static solve's workspace has served (all of it)
                env.data.workspace.clear()
            else:                            # the next frames reuse its scatters and order
                model.assembler.release(env.data.workspace, values=True)
        memory.release_stage(model.nq * 1000)  # ... and their pages (large)
    except EvaluationError:
        loads = {}
    if known is not None and (len(outcomes) == 1 or all(o.ok for o in outcomes)):
        # classified by the solve: also an equilibrium --require-stable refused (neutral),
        # or a path's located end
        infos = [known]
    elif all(o.ok for o in outcomes) and J is not None:
        jac, J = memory.hand_over(J), None    # the classification drops J once it is read
        infos = [classify(model, state, J=jac, active=saved, kkt_columns=columns)]
    else:   # the same records either way: frames of a sequence are concatenated
        infos = [unknown_info()] * len(outcomes)
    return frame_set(model, [state], {g: (F[None], T[None]) for g, (F, T) in loads.items()},
                     dep, outcomes, infos, [measured])


def _kkt_columns(model):
    """The column order of ``model``'s KKT matrix (made once per model at its first use; None
    for a dense assembler): the sparse classification's elimination order
    ranks the bodies as it does, without an ordering of its own."""
    if model.assembler.dense or model.nq <= stability.DENSE_LIMIT:    # (read at call time)
        return None
    return model.assembler.ordered()


def frame_set(model, frames, loads, dep, outcomes, stability, measures) -> FrameSet:
    """The :class:`~poise.solvers.record.FrameSet` of ``frames`` (one or many): times, body
    poses, per output group the element loads and (joints, jprims) reaction uniqueness, the
    ``outcomes``, their ``stability`` and ``measures`` (per frame ``(imbalance, constraint
    error, worst equation)`` of its output evaluation, or None).

    ``loads``: ``{group: (F, T)}`` with arrays (n_frames, n_group, 3); groups missing are
    zero. ``dep``: constraint rows taking part in a dependency (not unique).
    """
    nf = len(frames)
    rot = _stacked([s.rot for s in frames])
    groups = {}
    owners = None
    for g, o in model.outputs.items():
        n_out = len(o["ids"])
        zero = np.zeros((nf, n_out, 3))
        F, T = loads.get(g, (zero, zero))
        uniq = None
        if g in ("joints", "jprims"):
            uniq = np.ones(n_out, bool)
            if owners is None:
                owners = group_owner(model.row_info, dep)
            grp, own = owners
            uniq[own[grp == g]] = False
        groups[g] = GroupLoads(ids=np.asarray(o["ids"]), force=F, torque=T, unique=uniq,
                               tag=np.asarray(o["tag"], dtype=str) if g == "forces" else None)
    if all(s.rotvec is not None for s in frames):       # every frame at once
        rv = model.rotation_from_input(None, rot, _stacked([s.rotvec for s in frames]))
    else:
        rv = np.stack([model.rotation_from_input(s) for s in frames])
    return FrameSet(states=tuple(frames), time=np.array([s.t for s in frames]),
                    body_id=model.body_id,
                    position=_stacked([s.pos for s in frames]), orientation=rot,
                    rotation_from_input=rv, groups=groups, outcomes=tuple(outcomes),
                    stability=tuple(stability), measures=tuple(measures))


def _stacked(arrays):
    """``np.stack(arrays)`` (a static solve's one frame: its copy with a leading axis)."""
    return arrays[0][None].copy() if len(arrays) == 1 else np.stack(arrays)


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


def measure_frames(env, redundancy, frames, outcomes) -> FrameSet | None:
    """The :class:`~poise.solvers.record.FrameSet` of all ``frames``, as the frame-by-frame
    path (:func:`measure_frame` per frame, concatenated) makes it.

    Parameters
    ----------
    env : Env
        Provides the model, the settings and the active rows (:class:`~poise.solvers.context.Env`).
    redundancy : array of int
        The redundant rows.
    frames : list of State
    outcomes : list of FrameOutcome (one per frame)

    Every outcome is certified on its frame's evaluation (inactive, redundant rows excluded) by
    :func:`poise.solvers.certify.certify`: the set holds the certified outcomes and the
    measures.
    """
    model = env.model
    outcomes = list(outcomes)
    if not frames or not batchable(model):
        return None
    sc = Scales(model, env.settings)
    F = len(frames)
    nq, nc = model.nq, model.nc
    saved = env.data.mask(model)
    red = np.asarray(redundancy, int)
    dep = red
    w = where(model.row_kind == 1, 1.0 / model.L ** 2, 1.0)
    cs = column_scale(model)
    loads = {}
    infos, measured = [], []
    C = chunk_size(model)
    try:
        for a in range(0, F, C):
            chunk = frames[a:a + C]
            ev = evaluate(model, chunk, "jacobian")
            for j in range(len(chunk)):
                outcomes[a + j], ms = certify(model, env.settings, outcomes[a + j], ev.r[j],
                                              np.where(saved, ev.phi[j], 0.0), sc)
                measured.append(ms)
            lam = np.stack([s.lam for s in chunk]) if nc else np.zeros((len(chunk), 0))
            if len(red) and nc:
                lam = lam.copy()
                for j in range(len(chunk)):
                    Pf = ev.J[j, nq:, :nq]
                    Y = left_null_basis(Pf, saved, cs)
                    lam[j] = min_norm_multipliers(lam[j], saved, w, Y)
                    if a + j == 0:
                        dep = dependent_rows(saved, Y)
            for g, (Fg, Tg) in loads_of(model, ev.items, lam.ravel(), frames=len(chunk)).items():
                n_out = len(model.outputs[g]["ids"])
                loads.setdefault(g, []).append((Fg.reshape(-1, n_out, 3),
                                                Tg.reshape(-1, n_out, 3)))
            ok = np.array([o.ok for o in outcomes[a:a + C]])
            got = [cached_info(env.data, st) for st in chunk]    # classified by the solve (also
            if all(g is not None for g, k in zip(got, ok) if k):   # a path's located end)
                infos += [g if g is not None else unknown_info() for g in got]
            elif model.nq <= DENSE_LIMIT:
                infos += classify_dense_frames(model, ev.J, saved, ok)
            else:                                     # sparse inertia, frame by frame
                columns = _kkt_columns(model)
                infos += [classify(model, None, J=ev.J[j], active=saved, kkt_columns=columns)
                          if ok[j] else unknown_info()
                          for j in range(len(chunk))]
    except EvaluationError:
        return None
    return frame_set(model, frames, {g: (np.concatenate([x[0] for x in parts]),
                                         np.concatenate([x[1] for x in parts]))
                                     for g, parts in loads.items()}, dep, outcomes, infos,
                     measured)
