"""Frames tiled across one model: the families of ``F`` frames as one family each.

A quasi-static run writes per output frame the reactions, element loads, stability class and
(FIM_D's interpolated frames) the imbalance; one Python pass over every family per frame costs
far more than the numerical work on small models. The evaluation engine
(:func:`poise.model.evaluate.evaluate` with a list of states) therefore calls the families whose
element type declares them tileable (:func:`poise.elements.registry.tileable_kernels`) once for
all frames, on the tiled copies built here (:func:`tile_cache`), and any other once per frame.
The result equals ``F`` one-frame evaluations with all rows active (tests compare every deck's
frames); models whose forces read constraint reactions or with ``N > MAX_N`` unknowns are not
batched (:func:`batchable`).
"""
from __future__ import annotations

import copy

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


def tile_cache(model, F):
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
