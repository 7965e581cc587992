"""Per-frame output datasets of a quasi-static run, all frames at once.

:meth:`poise.solvers.static.StaticAnalysis.frame_datasets` computes one frame's outputs from
one residual + Jacobian evaluation: reactions (minimum-norm where constraints are redundant),
element loads, the stability class, and for FIM_D's interpolated frames the imbalance and
constraint error. :func:`frames_datasets` produces the same datasets for a whole list of frames
from :func:`poise.model.frame_batch.evaluate_frames` (chunks of frames, one kernel call per
tileable family per chunk) and a batched stability classification (stacked SVD null spaces and
symmetric eigen-decompositions, grouped by constraint rank:
:func:`poise.solvers.stability.classify_dense_frames`), so the per-frame cost is array work,
not a Python pass over the model. It returns ``None`` where batching does not apply (see
:func:`poise.model.frame_batch.batchable`) or a frame does not evaluate to finite values; the
caller then uses the frame-by-frame path, which names the failing element.
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError


def frames_datasets(sa, frames, outcomes, measure=None) -> dict | None:
    """Datasets of all ``frames`` (concatenated along the frame axis), as the frame-by-frame
    path writes them.

    Parameters
    ----------
    sa : StaticAnalysis
        Provides the model and the redundant rows.
    frames : list of State
    outcomes : list of FrameOutcome (one per frame)
    measure : callable or None
        ``measure(k, imbalance, constraint_error, worst_equation)`` for every frame ``k``, as
        measured on its evaluation (inactive, redundant rows excluded) by
        :func:`poise.solvers.certify.certify`, which also certifies every outcome.
    """
    from poise.model.frame_batch import batchable, chunk_size, evaluate_frames
    from poise.solvers.outputs import loads_of
    from poise.solvers.redundancy import dependent_rows, left_null_basis, min_norm_multipliers
    from poise.solvers.stability import (DENSE_LIMIT, classify, classify_dense_frames,
                                         unknown_info)

    model = sa.model
    if not frames or not batchable(model):
        return None
    from poise.solvers.certify import certify
    from poise.solvers.newton import Scales
    sc = Scales(model, sa.settings)
    F = len(frames)
    nq, nc = model.nq, model.nc
    saved = model.row_active.copy()
    red = np.asarray(sa.redundancy, int)
    dep = red
    w = np.where(model.row_kind == 1, 1.0 / model.L ** 2, 1.0)
    loads = {}
    infos = []
    C = chunk_size(model)
    model.row_active[:] = True
    try:
        for a in range(0, F, C):
            chunk = frames[a:a + C]
            ev = evaluate_frames(model, chunk, need_jac=True)
            for j in range(len(chunk)):
                got = certify(model, sa.settings, outcomes[a + j], ev.r[j],
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
            model.row_active[:] = saved
            if model.nq <= DENSE_LIMIT:
                infos += classify_dense_frames(model, ev.J, saved, ok)
            else:                                     # sparse inertia, frame by frame
                infos += [classify(model, None, J=ev.J[j]) if ok[j] else
                          unknown_info()
                          for j in range(len(chunk))]
            model.row_active[:] = True
    except EvaluationError:
        return None
    finally:
        model.row_active[:] = saved
    from poise.solvers.static import output_datasets
    d = output_datasets(model, frames, {g: (np.concatenate([x[0] for x in parts]),
                                            np.concatenate([x[1] for x in parts]))
                                        for g, parts in loads.items()}, dep, outcomes)
    from poise.solvers.stability import stability_datasets
    d.update(stability_datasets(infos))
    return d
