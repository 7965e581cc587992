"""Frames tiled across one model: the families of ``F`` frames as one family each.

A quasi-static run writes per output frame the reactions, element loads, stability class and
(FIM_D's interpolated frames) the imbalance; one Python pass over every family per frame costs
far more than the numerical work on small models. The evaluation engine
(:func:`poise.model.evaluate.evaluate` with a list of states) therefore calls the families whose
element type declares them tileable (:func:`poise.elements.registry.tileable_kernels`) once for
all frames, on the tiled copies built here (:func:`tiles`, kept in the solve's workspace), and
any other once per frame.
The result equals ``F`` one-frame evaluations with all rows active (tests compare every deck's
frames); models whose forces read constraint reactions or with ``N > MAX_N`` unknowns are not
batched (:func:`batchable`).
"""
from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from poise.elements.registry import tileable_kernels

MAX_N = 400                 # KKT size up to which frames are batched (dense (F, N, N) blocks)
CHUNK_ENTRIES = 4_000_000   # dense Jacobian entries per chunk of frames (32 MB)


def _tileable():
    """Kernels declared tileable by their element types (:mod:`poise.elements.registry`)."""
    return tileable_kernels()


#: per-instance index arrays of tileable families shifted per frame: attribute -> table
#: (``angle`` = the continuous-angle table ``State.angle``)
OFFSET_ARRAYS = {"angle_index": "angle"}


def batchable(model) -> bool:
    """True if the frames of ``model`` may be evaluated together."""
    return model.reaction_feed is None and model.N <= MAX_N


def chunk_size(model) -> int:
    """Frames per batched evaluation (bounded dense Jacobian memory)."""
    return max(1, CHUNK_ENTRIES // max(1, model.N * model.N))


def _tile_family(fam, F, model, exact: bool):
    """Copy of ``fam`` covering ``F`` frames (instance ``f * n + i``)."""
    n = fam.n
    fo = np.arange(F)
    nm = len(model.marker_id)
    ch = {}
    ch["markers"] = (fam.markers[None] + (nm * fo)[:, None, None]).reshape(F * n, -1)
    ch["slot_kind"] = np.tile(fam.slot_kind, (F, 1))
    group = fam.group
    n_out = len(model.outputs[group]["ids"]) if group in model.outputs else 0
    ch["owner"] = (fam.owner[None] + (n_out * fo)[:, None]).ravel()
    if fam.is_constraint:
        ch["crow"] = (fam.crow[None] + (model.nc * fo)[:, None, None]).reshape(F * n, -1)
    if exact:
        skip = {"markers", "slot_kind", "owner", "crow", "gcol", "scols", "slot_ml"}
        na = len(model.angle_I)
        for fd in fields(fam):
            k, v = fd.name, getattr(fam, fd.name)
            if k in skip or not isinstance(v, np.ndarray) or v.ndim == 0 or v.shape[0] != n:
                continue
            rep = np.tile(v, (F,) + (1,) * (v.ndim - 1))
            if k in OFFSET_ARRAYS:
                off = (na * fo).reshape((F,) + (1,) * v.ndim)
                rep = np.where(v[None] >= 0, v[None] + off, v[None]).reshape(rep.shape)
            ch[k] = rep
        ch.update(fam.tile_fields(F, model))
    return replace(fam, **ch)


class _Tiles:
    """The tiled families of the last frame count ``F`` (one entry: same F reused across
    chunks; a model's scratch in the solve's workspace)."""

    __slots__ = ("F", "tiles")

    def __init__(self):
        self.F, self.tiles = None, None


def tiles(model, F, workspace):
    """``[(family for F frames, tileable), ...]`` of ``model`` (kept in ``workspace``)."""
    cache = workspace.scratch(model, _Tiles)
    if cache.F != F:
        exact_types = _tileable()
        cache.tiles = [(_tile_family(fam, F, model, type(fam) in exact_types), type(fam) in
                        exact_types) for fam in model.families]
        cache.F = F
    return cache.tiles


def set_tiles(model, F, workspace, tiled) -> None:
    """Use ``tiled`` (``[(family for F frames, tileable), ...]`` as :func:`tiles` gives) for
    the next ``F``-frame evaluations of ``model`` in ``workspace``: families whose per-instance
    parameters differ per frame (a sweep's cases solved together, :mod:`poise.solvers.batched`)."""
    cache = workspace.scratch(model, _Tiles)
    cache.F, cache.tiles = F, list(tiled)


def stack_ext(outs, at):
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


def add_block(jidx, jval, rows, cols, vals, F, N):
    """Register dense-Jacobian entries ``(rows, cols)`` (n, E) of every frame: flat index
    ``f N^2 + row N + col``; entries with a negative row or column are dropped."""
    ok = (rows >= 0) & (cols >= 0)                                  # (n, E)
    base = (rows * N + cols)[ok]                                    # (k,)
    flat = (base[None, :] + (N * N * np.arange(F))[:, None]).ravel()
    v = vals.reshape(F, *rows.shape)[:, ok].ravel()
    jidx.append(flat.astype(np.int64))
    jval.append(v)
