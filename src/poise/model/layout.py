"""The compiled model built in one step: layout of the compile result, index maps, pattern.

:func:`build_model` takes the resolved bodies and markers and the element compilers'
:class:`~poise.elements.context.CompileResult` and computes everything the frozen
:class:`~poise.model.model.Model` declares: each family's global coordinate columns and local
pattern (a new family object, :func:`dataclasses.replace`), the coordinate and row index maps,
the reaction feed of forces reading reactions, the fixed sparsity pattern (one
:class:`~poise.model.assembly.Assembler`), the evaluation order, the time sources and energy
terms the element types declare. The model is then constructed once and sealed
(:func:`poise.core.readonly.seal`: every array reachable from it read-only).
"""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from poise.core.readonly import seal
from poise.elements.kernel import LocalPattern
from poise.elements.reaction_feed import ReactionFeed
from poise.elements.registry import energy_terms, kernel_types, time_sources
from poise.elements.rows import RowTable, Texts
from poise.model.assembly import Assembler
from poise.model.model import DENSE_MAX, Model
from poise.model.small_dense import small_dense


def lay_out(families, body_off, body_kind, marker_body, nb: int, nq_bodies: int) -> tuple:
    """The families with their global coordinate columns ``gcol`` (n, 6K + U) (-1 where a
    marker's body has none: ground, the rotation of a point body) and local ``pattern``."""
    out = []
    for f in families:
        cols = []
        for k in range(f.K):
            bi = marker_body[f.markers[:, k]]
            ground = bi >= nb
            bsafe = np.minimum(bi, max(nb - 1, 0))
            base = body_off[bsafe] if nb else np.zeros_like(bi)
            c = base[:, None] + np.arange(6)[None, :]
            c[ground] = -1
            if nb:
                point = (body_kind[bsafe] == 1) & ~ground
                c[point, 3:] = -1
            cols.append(c)
        if f.scols is not None and f.U:
            cols.append(np.where(f.scols >= 0, nq_bodies + f.scols, -1))
        f = replace(f, gcol=np.concatenate(cols, axis=1))
        out.append(replace(f, pattern=LocalPattern(f, marker_body)))
    return tuple(out)


def build_model(*, bodies: dict, markers: dict, result, nq_bodies: int, L: float, units: str,
                mass_factor: float, types, warnings=()) -> Model:
    """The frozen model (see the module docstring). ``bodies`` / ``markers``: the body and
    marker arrays of :mod:`poise.model.compile`; ``result``: the compile result; ``types``:
    the element types compiled (registry order)."""
    res = result
    nb = len(bodies["body_id"])
    kinds, off = bodies["body_kind"], bodies["body_off"]
    fams = lay_out(res.families, off, kinds, markers["marker_body"], nb, nq_bodies)
    ne = len(res.extra_names)
    nq, nc = nq_bodies + ne, len(res.rows)
    N = nq + nc
    rigid = kinds == 0
    f = dict(bodies, **markers)
    f["body_label"] = Texts(bodies["body_label"])   # one string: no object per body
    f["coord_info"] = bodies["coord_info"].with_extra(res.extra_names)
    rows = RowTable.of(res.rows)              # one entry per element, codes per row
    f.update(families=fams, nq=nq, nc=nc, row_info=rows, nb=nb, N=N, dense=N <= DENSE_MAX,
             angle_I=np.array([a[0] for a in res.angles], int),
             angle_J=np.array([a[1] for a in res.angles], int),
             angle_axis=np.array([a[2] for a in res.angles], int), L=L,
             active_effects=res.effects, outputs=res.outputs, units=units, n_extra=ne,
             extra0=np.array(res.extra0, float), extra_names=res.extra_names,
             mass_factor=float(mass_factor), spec_warnings=tuple(warnings),
             user_routines=res.user_routines, input_files=res.input_files)
    f["trans_idx"] = (off[:, None] + np.arange(3)).ravel()
    f["rot_body"] = np.nonzero(rigid)[0]
    f["rot_idx"] = (off[rigid][:, None] + 3 + np.arange(3)).ravel()
    f["extra_off"] = nq - ne
    f["extra_idx"] = np.arange(nq - ne, nq)
    kind = np.zeros(nq, int)                  # 0 force row, 1 moment row, 2 scalar unknown
    kind[f["rot_idx"]] = 1
    kind[f["extra_idx"]] = 2
    f["q_kind"] = kind
    # per-body length scale: largest marker lever of the body (>= 1e-3 L); used to weight
    # rotations against translations in least-squares problems and rank tests
    lever = np.linalg.norm(markers["marker_s0"], axis=1)
    ell = np.zeros(nb)
    mb = markers["marker_body"]
    on = mb < nb
    np.maximum.at(ell, mb[on], lever[on])
    f["body_scale"] = np.maximum(ell, 1e-3 * L)
    qs = np.ones(nq)
    qs[f["rot_idx"]] = np.repeat(f["body_scale"][rigid], 3)
    f["q_scale"] = qs                         # length per unit of each coordinate (rad -> length)
    f["row_kind"] = (rows.kind_is("rot").astype(int) if isinstance(rows, RowTable) else
                     np.array([1 if ri["kind"] == "rot" else 0 for ri in rows], int))
    # evaluation order: families reading reaction channels after every other (they read the
    # constraint reactions), then those declaring ``eval_last`` (gravity: the residual sums in
    # the order of earlier releases)
    rank = [2 if fam.eval_last else 1 if fam.reads_reactions else 0 for fam in fams]
    f["eval_order"] = tuple(sorted(range(len(fams)), key=rank.__getitem__))
    owners = kernel_types(types)              # family class -> its element type
    f["time_sources"] = tuple(time_sources(fams, owners))
    f["energy_terms"] = energy_terms(fams, owners)
    view = SimpleNamespace(**f)               # the model so far (feed, hooks)
    feed = None
    if res.reaction_channels is not None:
        feed = ReactionFeed(view, res.reaction_channels, res.element_markers)
    f["reaction_feed"] = feed
    f["frame_hooks"] = tuple(h.bind(view) if hasattr(h, "bind") else h for h in res.frame_hooks)
    f["assembler"] = Assembler(N, _blocks(view, feed), dense=f["dense"],
                               groups=_order_groups(view))
    f["small"] = small_dense(SimpleNamespace(**f))
    model = Model(**f)
    # the tables of text and numbers (one entry per row, coordinate, ...) hold no array: not
    # walked (tests/methods/test_model_frozen.py checks every array of the model is sealed)
    return seal(model, skip=(model.extra_names,
                             model.spec_warnings, model.user_routines, model.input_files,
                             model.active_effects, model.time_sources))


def _blocks(m, feed):
    """The fixed sparsity pattern: ``(rows, cols)`` blocks in assembly order, generated one at
    a time (the assembler keys each as it comes: a large model's index blocks are never all
    alive at once)."""
    for fam in m.families:
        # only the entries that can be non-zero (family slot structure, see LocalPattern)
        g = fam.gcol
        pat = fam.pattern
        L = g.shape[1]
        li, lj = ((pat.order // L, pat.order % L) if pat.order is not None
                  else np.nonzero(pat.kmask))
        if pat.compact:            # entry-major, as tangent_compact fills them
            yield g[:, li].T, g[:, lj].T
        else:
            yield g[:, li], g[:, lj]
        if fam.is_constraint:
            rows = m.nq + fam.crow
            pr, pc = np.nonzero(pat.pmask)
            yield rows[:, pr], g[:, pc]
            yield g[:, pc], rows[:, pr]
    # mass blocks (regularisation): translational diagonal, rotational 3x3
    rigid = m.body_kind == 0
    tb = m.body_off[:, None] + np.arange(3)
    yield tb, tb
    rb = m.body_off[rigid][:, None] + 3 + np.arange(3)
    yield np.repeat(rb[:, :, None], 3, 2), np.repeat(rb[:, None, :], 3, 1)
    # diagonal of the multiplier block (removed / redundant rows)
    lr = m.nq + np.arange(m.nc)
    yield lr, lr
    # forces reading constraint reactions: d r / d lambda (ReactionFeed, after all others)
    if feed is not None:
        yield from feed.blocks


def _order_groups(m) -> np.ndarray:
    """Group of each KKT unknown for the fill-reducing ordering: one group per body's
    coordinates, per scalar unknown and per element instance's constraint rows."""
    grp = np.arange(m.N, dtype=np.int64)          # default: every unknown on its own
    size = np.where(m.body_kind == 0, 6, 3)
    bid = np.repeat(np.arange(len(size)), size)
    start = np.repeat(m.body_off, size)
    within = np.arange(bid.size) - np.repeat(np.cumsum(size) - size, size)
    grp[start + within] = bid
    for fam in m.families:
        if fam.is_constraint and fam.n:
            grp[m.nq + fam.crow] = (m.N + fam.crow[:, :1])
    _, grp = np.unique(grp, return_inverse=True)
    return grp.ravel()
