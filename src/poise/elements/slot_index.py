"""What a small family's slots derive from its markers alone: :class:`SlotIndex`.

A family of few slot instances (n·S <= ``LocalPattern.SLOT_INDEX_MAX``) keeps, from compile
time on, the gathers of its slot kinematics (slot markers, point masks, bodies, axis columns)
and the targets of its slot sums onto the markers' rows (local residual ``B^T rho``,
constraint Jacobian ``phi_y B``, the connection term of a tangent formed with ``B``, and ``B``
itself), so that an evaluation of a small model does array work without per-slot loops. The
sums are one ``np.bincount`` each: bincount adds its inputs in order onto zeros, so every row
receives its slots' terms in slot order, bit for bit the loop's sums.
"""
from __future__ import annotations

import numpy as np

POINT, AX_X, AX_Y, AX_Z = 0, 1, 2, 3    # slot kinds: the marker origin, its x, y, z axis


def slot_rounds(ml, slots=None) -> list:
    """The slots (markers ``ml``; only ``slots`` when given) in rounds of distinct markers,
    each marker's slots in order round after round, as ``(marker slice, slot slice)`` pairs (a
    round whose markers or slots are not evenly spaced goes slot by slot): a loop's additions
    over the slots onto their markers' rows, in its order, a few slots at a time."""
    seen: dict = {}
    rounds: list = []
    for s in (range(len(ml)) if slots is None else slots):
        k = ml[s]
        r = seen[k] = seen.get(k, -1) + 1
        if r == len(rounds):
            rounds.append([])
        rounds[r].append((k, s))
    out = []
    for rnd in rounds:
        rnd.sort()
        ks, ss = [k for k, _ in rnd], [s for _, s in rnd]
        dk = ks[1] - ks[0] if len(ks) > 1 else 1
        ds = ss[1] - ss[0] if len(ss) > 1 else 1
        if dk > 0 and ds > 0 and ks == list(range(ks[0], ks[-1] + 1, dk)) \
                and ss == list(range(ss[0], ss[-1] + 1, ds)):
            out.append((slice(ks[0], ks[-1] + 1, dk), slice(ss[0], ss[-1] + 1, ds)))
        else:
            out += [(slice(k, k + 1), slice(s, s + 1)) for k, s in rnd]
    return out


def as_slice(idx):
    """``idx`` (1-d, distinct) as an equivalent slice when evenly increasing, else as is."""
    idx = np.asarray(idx)
    step = int(idx[1] - idx[0]) if idx.size > 1 else 1
    if step > 0 and np.array_equal(idx, np.arange(idx[0], idx[0] + step * idx.size, step)):
        return slice(int(idx[0]), int(idx[-1]) + 1, step)
    return idx


class SlotIndex:
    """What :func:`poise.elements.kernel.slot_kinematics` derives from a family's markers and
    slot kinds alone (the slots' markers, point masks, bodies, axis columns): a small family's
    pattern keeps one (:class:`~poise.elements.local_pattern.LocalPattern`), so that its
    evaluations only gather the marker kinematics. With rounds, the targets of its slot sums
    (:meth:`slot_sums`: residual, ``m`` constraint rows; ``connection``: the tangent's
    connection blocks, :meth:`add_connection`, and ``B``) are made here, once: a solve adds
    nothing to the model."""

    __slots__ = ("mk", "pt", "masks", "case", "body", "ax", "is_pt", "slot_ml", "rounds",
                 "p_slots", "_sums", "b_at")

    def __init__(self, markers, slot_ml, slot_kind, marker_body, m: int = 0,
                 connection: bool = False):
        self.slot_ml = np.asarray(slot_ml)
        self.mk = markers[:, self.slot_ml]                       # (n, S)
        self.pt = pt = slot_kind == POINT
        self.masks = (pt.all(axis=0), pt.any(axis=0))
        self.case = POINT if pt.all() else AX_X if not pt.any() else None
        self.body = np.maximum(marker_body[self.mk], 0)
        self.ax = slot_kind - 1 if self.case == AX_X else np.clip(slot_kind - 1, 0, 2)
        self.is_pt = pt[..., None]
        # the slots' sums on their markers' rows in rounds (:func:`_slot_rounds`): every slot
        # on the rotation rows, the point slots on the translation rows (None: a slot that is
        # a point in some instances only, summed slot by slot)
        p_all, p_any = self.masks
        ml = self.slot_ml.tolist()
        self.rounds = (None if (p_any & ~p_all).any() else
                       (slot_rounds(ml), slot_rounds(ml, np.flatnonzero(p_all).tolist())))
        self.p_slots = np.flatnonzero(p_all)
        self._sums: dict = {}
        n, K = markers.shape
        if self.rounds is not None:
            for N in {n, n * m} - {0}:
                self._sums[(N, K)] = _sum_index(N, K, self.slot_ml, self.p_slots)
            if connection:
                self._sums[("connection", n, K)] = _connection_index(n, K, self.slot_ml)
        # where :meth:`b_matrix` puts -skew(v) and the point slots' I (families whose tangent
        # is formed with B: no declared G structure)
        self.b_at = _b_index(n, K, self.slot_ml, self.p_slots) if (
            connection and self.rounds is not None) else None

    def b_matrix(self, msk, K: int) -> np.ndarray:
        """:attr:`SlotKinematics.B` (n, 3S, 6K) from ``-skew(V)`` (n, S, 3, 3): the same
        entries placed by index (no slot loop)."""
        n, S = msk.shape[:2]
        rot_at, pt_at = self.b_at
        B = np.zeros(n * 3 * S * 6 * K)
        B[rot_at] = msk.reshape(-1)
        B[pt_at] = 1.0
        return B.reshape(n, 3 * S, 6 * K)

    def slot_sums(self, rot, trans, K: int) -> np.ndarray:
        """The sums of the slot rounds (``rounds`` not None) as one ``np.bincount``: ``rot``
        (..., S, 3) onto each marker's rotation rows, ``trans`` of the point slots onto its
        translation rows; (N, 6K) for the N leading instances. bincount adds its inputs in
        order onto zeros, every slot of a marker in slot order: the same sums, bit for bit."""
        S = len(self.slot_ml)
        N = rot.size // (3 * S)
        got = self._sums.get((N, K))
        if got is None:
            got = _sum_index(N, K, self.slot_ml, self.p_slots)
        w = np.concatenate([rot.reshape(-1), trans[..., self.p_slots, :].reshape(-1)])
        return np.bincount(got, weights=w, minlength=N * 6 * K).reshape(N, 6 * K)

    def add_connection(self, Kl, blk, K: int) -> np.ndarray:
        """``Kl`` (n, 6K, 6K) plus each slot's connection block ``blk`` (n, S, 3, 3) on its
        marker's (rot, rot) block, as one bincount of Kl's entries then the blocks in slot
        order: the same sums as adding them slot by slot onto Kl (a zero may lose its sign)."""
        n = blk.shape[0]
        idx = self._sums.get(("connection", n, K))
        if idx is None:
            idx = _connection_index(n, K, self.slot_ml)
        w = np.concatenate([Kl.reshape(-1), blk.reshape(-1)])
        return np.bincount(idx, weights=w, minlength=Kl.size).reshape(Kl.shape)


def _sum_index(N: int, K: int, ml, p_slots) -> np.ndarray:
    """:meth:`SlotIndex.slot_sums`' target of each value: ``(N, S, 3)`` rotation rows of the
    slots' markers, then ``(N, P, 3)`` translation rows of the point slots' markers, in the
    (N, 2K, 3) layout of a local residual."""
    i = np.arange(N)[:, None, None] * (2 * K)
    c = np.arange(3)[None, None, :]
    rot = (i + 2 * np.asarray(ml)[None, :, None] + 1) * 3 + c
    trans = (i + 2 * np.asarray(ml)[p_slots][None, :, None]) * 3 + c
    return np.concatenate([rot.ravel(), trans.ravel()]).astype(np.intp)


def _b_index(n: int, K: int, ml, p_slots) -> tuple:
    """:meth:`SlotIndex.b_matrix`' positions: ``-skew(v_s)`` (n, S, 3, 3) on rows ``3s..3s+3``,
    the rotation columns of the slot's marker; 1 on the diagonal of each point slot's
    translation columns."""
    ml = np.asarray(ml)
    S, W = len(ml), 6 * K
    a = np.arange(3)
    row = np.arange(n)[:, None, None, None] * 3 * S + 3 * np.arange(S)[None, :, None, None] \
        + a[:, None]
    rot_at = row * W + 6 * ml[None, :, None, None] + 3 + a[None, :]
    prow = np.arange(n)[:, None, None] * 3 * S + 3 * np.asarray(p_slots)[None, :, None] + a
    pt_at = prow * W + 6 * ml[p_slots][None, :, None] + a
    return rot_at.ravel().astype(np.intp), pt_at.ravel().astype(np.intp)


def _connection_index(n: int, K: int, ml) -> np.ndarray:
    """:meth:`SlotIndex.add_connection`'s target of each value: Kl's own entries, then each
    slot's 3x3 block on its marker's (rot, rot) block."""
    L = 6 * K
    r = 6 * np.asarray(ml)[None, :, None, None] + 3 + np.arange(3)[:, None]
    c = 6 * np.asarray(ml)[None, :, None, None] + 3 + np.arange(3)[None, :]
    at = (np.arange(n)[:, None, None, None] * L + r) * L + c              # (n, S, 3, 3)
    return np.concatenate([np.arange(n * L * L), at.ravel()]).astype(np.intp)
