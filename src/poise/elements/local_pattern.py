"""The static structure of one family's local tangent and constraint Jacobian:
:class:`LocalPattern`, built once per family when the model is laid out."""
from __future__ import annotations

import numpy as np

from poise.elements.slot_index import POINT, SlotIndex, as_slice, slot_rounds


class LocalPattern:
    """Static structure of one family's local tangent and constraint Jacobian.

    Built once per family (:func:`local_pattern`) from the slot layout and the family's optional
    structure declarations (:meth:`Family.g_blocks`, :meth:`Family.phi_y_mask`). ``kmask``
    (L, L) and ``pmask`` (m, L), L = 6K + U, mark the entries that can be non-zero; the model
    registers only those with the sparse assembler. ``kidx`` / ``pidx`` are their flat indices
    (C order), None when the mask is full. ``order`` is the order in which the model registers
    and fills the tangent entries: block-wise for ``compact`` patterns (declared ``G`` structure,
    no scalar columns; :func:`poise.elements.kernel.tangent_compact` fills them directly,
    entry-major: all instances of one entry after the other), else ``kidx`` (instance-major).
    ``slots``: the family's :class:`SlotIndex` (small families of a model, ``marker_body``
    given), else None. ``conn`` (S,): the slots with a connection term (not those the family
    declares at their body's reference point, :meth:`Family.zero_lever`).
    """

    #: families with at most this many slot instances (n * S) keep a :class:`SlotIndex`
    SLOT_INDEX_MAX = 4096

    def __init__(self, fam, marker_body=None):
        K, S, U, m = fam.K, len(fam.slot_ml), fam.U, fam.m
        gb = fam.g_blocks()
        self.declared = gb is not None
        self.slots = (SlotIndex(fam.markers, fam.slot_ml, fam.slot_kind, marker_body, m,
                                connection=not self.declared)
                      if marker_body is not None and fam.n * S <= self.SLOT_INDEX_MAX else None)
        ml = np.asarray(fam.slot_ml)
        L = 6 * K + U
        pt_any = (np.asarray(fam.slot_kind) == POINT).any(axis=0) if fam.n else np.zeros(S, bool)
        gb = np.ones((S, S), bool) if gb is None else np.asarray(gb, bool)
        km = np.zeros((L, L), bool)

        def tr(k):
            return slice(6 * k, 6 * k + 3)

        def rt(k):
            return slice(6 * k + 3, 6 * k + 6)

        zl = fam.zero_lever()
        # slots with a connection term (a slot at its body's reference point has none)
        conn = np.ones(S, bool) if zl is None else ~np.asarray(zl, bool)
        for s in np.flatnonzero(conn).tolist():                # connection term
            km[rt(ml[s]), rt(ml[s])] = True
        pairs = np.argwhere(gb)
        for s, t in pairs:
            k, l = ml[s], ml[t]
            km[rt(k), rt(l)] = True
            if pt_any[s]:
                km[tr(k), rt(l)] = True
            if pt_any[t]:
                km[rt(k), tr(l)] = True
            if pt_any[s] and pt_any[t]:
                km[tr(k), tr(l)] = True
        if U:
            km[:, 6 * K:] = True
            km[6 * K:, :] = True
        self.slot_rounds = slot_rounds(ml.tolist())
        self.s_idx = pairs[:, 0].copy()
        self.t_idx = pairs[:, 1].copy()
        self.pairs = [(int(a), int(b)) for a, b in pairs]
        self.pt_any = pt_any
        self.conn = conn
        self.pt_all = (np.asarray(fam.slot_kind) == POINT).all(axis=0) if fam.n else pt_any
        self.kmask = km
        self.kidx = None if km.all() else np.flatnonzero(km)
        # compact layout (declared families without scalar columns): the non-zero 3x3 blocks
        # of the (2K x 2K) block grid, row-major; the tangent is computed straight into
        # (nblocks, 3, 3, n) and registered with the assembler in that order (``order``)
        self.compact = self.declared and not U
        self.bpos = None
        self.nblocks = 0
        self.order = self.kidx
        self.conn_rounds = None
        if self.declared:
            bi, bj = np.nonzero(km[:6 * K:3, :6 * K:3])
            self.bpos = np.full((2 * K, 2 * K), -1, np.intp)
            self.bpos[bi, bj] = np.arange(bi.size)
            self.nblocks = int(bi.size)
            # the connection term's (rot k, rot k) blocks of each slot round (tangent_compact):
            # a slice when evenly spaced (views), else an index array
            rot = 2 * np.arange(K) + 1
            self.conn_rounds = [(as_slice(self.bpos[rot[ks], rot[ks]]), ss) for ks, ss in
                                slot_rounds(ml.tolist(), np.flatnonzero(conn).tolist())]
            if self.compact:
                r = 3 * bi[:, None, None] + np.arange(3)[None, :, None]
                c = 3 * bj[:, None, None] + np.arange(3)[None, None, :]
                self.order = (r * L + c).ravel()
        self.pmask = None
        self.pidx = None
        if m:
            pm = fam.phi_y_mask()
            pm = np.ones((m, 3 * S), bool) if pm is None else np.asarray(pm, bool)
            qm = np.zeros((m, L), bool)
            for s in range(S):
                k = ml[s]
                blk = pm[:, 3 * s:3 * s + 3]                  # (m, 3)
                if pt_any[s]:
                    qm[:, 6 * k:6 * k + 3] |= blk
                cnt = blk.sum(axis=1)
                # row p^T (-skew v) = (v x p)^T: component j is structurally zero only when p
                # has its single non-zero in component j
                rot = (cnt[:, None] >= 2) | ((cnt[:, None] == 1) & ~blk)
                qm[:, 6 * k + 3:6 * k + 6] |= rot
            if U:
                qm[:, 6 * K:] = True
            self.pmask = qm
            self.pidx = None if qm.all() else np.flatnonzero(qm)

    @property
    def nk(self) -> int:
        return int(self.kmask.sum())


def local_pattern(fam) -> LocalPattern:
    """The :class:`LocalPattern` of a family: the one of its model layout (``fam.pattern``), or
    built now for a family outside a model."""
    pat = fam.pattern
    return LocalPattern(fam) if pat is None else pat
