"""The generic marker-slot kernel: slot vectors -> local body coordinates, residual, tangent.

Slots (:mod:`poise.elements.base`) are mapped to the 6 local coordinates of each marker's body:
a translation ``dr`` and a spatial rotation increment ``dtheta`` (``R <- expm(skew(dtheta)) R``).
For a point slot with lever ``v = P - r_body``: ``dP = dr - v x dtheta``; for an axis ``a``:
``da = -a x dtheta``. The local residual is ``B^T rho`` and the local tangent ``B^T G B + C``,
``C`` the connection term from rotating levers/axes, ``C_thth += v rho_s^T - (v . rho_s) I``
per slot. This gives the complete Newton Jacobian (including the geometric stiffness of
constraint reactions, d(Phi_q^T lam)/dq) for every family from first principles.
"""
from __future__ import annotations

import numpy as np

from poise.core import per_object
from poise.elements.rotation import skew
from poise.elements.slot_index import AX_X, AX_Y, AX_Z, POINT, SlotIndex  # noqa: F401 (API)
from poise.elements.local_pattern import LocalPattern, local_pattern  # noqa: F401 (API)
from poise.elements.major import MAJOR_MIN, local_residual_major

_I3 = np.eye(3)
_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])   # component i: i+1, i+2
_GATHER_MAX = 1 << 14      # entries up to which cross products gather components by index
_SKEW_ROWS = np.array([6, 5, 1, 2, 6, 3, 4, 0, 6])   # skew's entries from (v, -v, 0), row-major
_DIAG9 = np.array([0, 4, 8])                           # a 3x3 block's diagonal, flat


class SlotKinematics:
    """Slot vectors and their maps to local body coordinates for n instances.

    Attributes
    ----------
    Y : (n, S, 3) slot vectors (global)
    V : (n, S, 3) lever (point slots) or axis (axis slots) used by the connection term
    pt : (n, S) bool, point slots
    B : (n, 3S, 6K) d y / d local coordinates. Built on first access only: each slot's block is
        ``[I | -skew(v)]`` (point) or ``[0 | -skew(a)]`` (axis) within its marker's 6 columns, and
        the kernels below use that structure instead of the dense matrix.
    """

    __slots__ = ("Y", "V", "pt", "slot_ml", "K", "_B", "_Sk", "_masks", "rounds", "index")

    def __init__(self, Y, V, pt=None, slot_ml=None, K=None, B=None, masks=None, rounds=None,
                 index=None):
        self.Y = Y
        self.V = V
        self.pt = pt
        self.slot_ml = slot_ml
        self.K = K
        self._B = B
        self._Sk = None
        self._masks = masks
        self.rounds = rounds      # a SlotIndex's (rotation, translation) slot rounds, or None
        self.index = index        # that SlotIndex (its sums onto the markers' rows)

    @property
    def masks(self):
        """``(pt.all(axis=0), pt.any(axis=0))``: which slots are points in every / some
        instance (kept by a :class:`SlotIndex`)."""
        if self._masks is None:
            self._masks = (self.pt.all(axis=0), self.pt.any(axis=0))
        return self._masks

    @property
    def Sk(self) -> np.ndarray:
        """``skew(V)`` (n, S, 3, 3); ``B_s = [pt_s I | -Sk_s]``."""
        if self._Sk is None:
            self._Sk = skew(self.V)
        return self._Sk

    @property
    def B(self) -> np.ndarray:
        if self._B is None and self.index is not None and self.index.b_at is not None:
            self._B = self.index.b_matrix(-self.Sk, self.K)
        if self._B is None:
            n, S = self.pt.shape
            B = np.zeros((n, 3 * S, 6 * self.K))
            sk = -self.Sk
            for s0, s1, k in _runs(self.slot_ml):        # a marker's consecutive slots at once
                B[:, 3 * s0:3 * s1, 6 * k + 3:6 * k + 6] = sk[:, s0:s1].reshape(n, 3 * (s1 - s0), 3)
            p_all, p_any = self.masks
            for s in np.flatnonzero(p_any).tolist():
                k = int(self.slot_ml[s])
                if p_all[s]:
                    B[:, 3 * s:3 * s + 3, 6 * k:6 * k + 3] = _I3
                else:
                    B[self.pt[:, s], 3 * s:3 * s + 3, 6 * k:6 * k + 3] = _I3
            self._B = B
        return self._B


def _runs(slot_ml) -> list:
    """``(first, end, marker)`` of each run of consecutive slots reading one marker."""
    out = []
    for s, k in enumerate(np.asarray(slot_ml).tolist()):
        if out and out[-1][2] == k and out[-1][1] == s:
            out[-1][1] = s + 1
        else:
            out.append([s, s + 1, k])
    return out


class PairBlocks:
    """A compact ``G`` (n, 3S, 3S) whose only non-zero 3x3 slot-pair blocks are multiples of
    the identity: block ``(s, t)`` is ``coef[(s, t)] * I`` (``coef`` values (n,)). This is the
    multiplier-weighted Hessian of the bilinear constraint rows (``Perpendicular``,
    ``InPlane``): a residual evaluation makes it for the price of the multipliers' view, and
    only a Jacobian expands its blocks (:meth:`block`; :func:`dense_g` for the generic
    consumers), never an (n, 3S, 3S) array per trial."""

    __slots__ = ("n", "S", "coef")

    def __init__(self, n: int, S: int, coef: dict):
        self.n, self.S, self.coef = n, S, coef

    def any(self) -> bool:
        """Whether any coefficient is non-zero (as ``ndarray.any`` of the dense ``G``)."""
        return any(c.any() for c in self.coef.values())

    def block(self, s: int, t: int) -> np.ndarray:
        """Block ``(s, t)`` component-major (3, 3, n) (zeros when it has no coefficient)."""
        c = self.coef.get((s, t))
        if c is None:
            return np.zeros((3, 3, self.n))
        return _I3[:, :, None] * c[None, None, :]

    def skew_times(self, s: int, t: int, v) -> np.ndarray:
        """``skew(v) @ block(s, t)`` component-major (3, 3, n) for ``v`` (3, n): the block is
        ``c I``, so the product is ``skew(c v)`` (the entries of the product, made from ``c v``
        without the block: its zeros may differ in sign only)."""
        c = self.coef.get((s, t))
        if c is None:
            return np.zeros((3, 3, self.n))
        w = v * c
        e = np.concatenate([w, -w, np.zeros((1, self.n))])
        return e.take(_SKEW_ROWS, 0).reshape(3, 3, self.n)

    def dense(self, rows=None) -> np.ndarray:
        """The (n, 3S, 3S) array (only the instances ``rows`` when given)."""
        n = self.n if rows is None else len(rows)
        G = np.zeros((n, 3 * self.S, 3 * self.S))
        for (s, t), c in self.coef.items():
            c = c if rows is None else c[rows]
            G[:, 3 * s:3 * s + 3, 3 * t:3 * t + 3] = c[:, None, None] * _I3
        return G


def dense_g(G, rows=None):
    """``G`` as an (n, 3S, 3S) array (or None), a :class:`PairBlocks` expanded; ``rows``: only
    those instances."""
    if isinstance(G, PairBlocks):
        return G.dense(rows)
    if G is None or rows is None:
        return G
    return G[rows]


_POINTS = per_object.table()      # family -> (point mask (n, S), its slot masks)


def slot_points(fam) -> tuple:
    """``(pt, (pt.all(axis=0), pt.any(axis=0)))`` of a family's slot kinds (``pt``: point
    slots), made once per family: a big family without a
    :class:`~poise.elements.slot_index.SlotIndex` read them at every evaluation (at 10^5
    links a few ms each)."""
    def make():
        pt = np.asarray(fam.slot_kind) == POINT
        pt.setflags(write=False)
        return pt, (pt.all(axis=0), pt.any(axis=0))
    return per_object.once_per(_POINTS, fam, make)


def slot_kinematics(markers, slot_ml, slot_kind, P, A, marker_body, body_pos,
                    index: SlotIndex | None = None, points: tuple | None = None
                    ) -> SlotKinematics:
    """Evaluate slot vectors (the B-matrices are implicit, see :class:`SlotKinematics`).

    Parameters
    ----------
    markers : (n, K) int
        Marker indices of each instance.
    slot_ml : (S,) int
        Which of the K markers each slot reads.
    slot_kind : (n, S) int
        0 = origin, 1..3 = x/y/z axis.
    P : (nm, 3), A : (nm, 3, 3)
        Marker origins and axes (columns), global.
    marker_body : (nm,) int
        Body index of each marker (-1 = ground).
    body_pos : (nb, 3)
        Body reference (CG) positions.
    index : the family's :class:`SlotIndex` for these markers, kinds and marker bodies (the
        same gathers, made once), or None.
    points : :func:`slot_points` of the family (without ``index``), or None (made here).
    """
    if index is not None:
        mk, ix = index.mk, index
        if ix.case == POINT:
            Y = P[mk]
            V = Y - body_pos[ix.body]
        elif ix.case == AX_X:
            Y = A[mk, :, ix.ax]
            V = Y
        else:
            Pm = P[mk]
            Am = A[mk, :, ix.ax]
            Y = np.where(ix.is_pt, Pm, Am)
            V = np.where(ix.is_pt, Pm - body_pos[ix.body], Am)
        return SlotKinematics(Y=Y, V=V, pt=ix.pt, slot_ml=ix.slot_ml, K=markers.shape[1],
                              masks=ix.masks, rounds=ix.rounds, index=ix)
    n, K = markers.shape
    mk = markers[:, slot_ml]                                   # (n, S)
    kind = slot_kind
    pt, masks = (kind == POINT, None) if points is None else points
    if pt.all():                 # the same values as P[mk] etc., gathered faster by take
        Pm = P.take(mk, 0)
        Y = Pm
        V = Pm - body_pos.take(np.maximum(marker_body.take(mk), 0), 0)
    elif not pt.any():
        Y = A[mk, :, kind - 1]                                 # (n, S, 3): column kind-1
        V = Y
    else:
        Pm = P[mk]                                             # (n, S, 3)
        ax = np.clip(kind - 1, 0, 2)
        Am = A[mk, :, ax]                                      # (n, S, 3): column ax
        is_pt = pt[..., None]
        Y = np.where(is_pt, Pm, Am)
        lever = Pm - body_pos[np.maximum(marker_body[mk], 0)]
        V = np.where(is_pt, lever, Am)
    return SlotKinematics(Y=Y, V=V, pt=pt, slot_ml=np.asarray(slot_ml), K=K, masks=masks)


def cross3(a, b):
    """``a x b`` over the last axis (broadcasting), without ``np.cross`` overhead. Small arrays:
    the components gathered with two index orders (a few calls); large ones component by
    component (no full-size gathered copies: memory)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.size + b.size <= _GATHER_MAX:
        out = a.take(_NEXT, -1) * b.take(_PREV, -1)
        out -= a.take(_PREV, -1) * b.take(_NEXT, -1)
        return out
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    shape = a.shape if a.shape == b.shape else np.broadcast_shapes(a.shape, b.shape)
    out = np.empty(shape, a.dtype if a.dtype == b.dtype else np.result_type(a, b))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def local_residual(kin: SlotKinematics, rho: np.ndarray, K: int) -> np.ndarray:
    """``B^T rho`` (n, 6K): per slot ``pt_s rho_s`` on the marker's translation and
    ``v_s x rho_s`` on its rotation."""
    n, S = kin.pt.shape
    if kin.rounds is None and kin.index is None and n >= MAJOR_MIN:
        return local_residual_major(kin, rho, K)
    rho3 = rho.reshape(n, S, 3)
    vr = cross3(kin.V, rho3)                                   # (n, S, 3)
    if kin.rounds is not None and kin.index is not None:
        return kin.index.slot_sums(vr, rho3, K)
    r = np.zeros((n, 2 * K, 3))
    if kin.rounds is not None:
        _round_sums(kin.rounds, r[:, 1::2], r[:, 0::2], vr, rho3)
        return r.reshape(n, 6 * K)
    pt = kin.pt
    p_all, p_any = kin.masks                                # per slot, once
    for s in range(S):
        k = kin.slot_ml[s]
        r[:, 2 * k + 1] += vr[:, s]
        if p_all[s]:
            r[:, 2 * k] += rho3[:, s]
        elif p_any[s]:
            r[:, 2 * k] += rho3[:, s] * pt[:, s][:, None]
    return r.reshape(n, 6 * K)


def _round_sums(rounds, rot_rows, trans_rows, rot, trans, lead=()):
    """Slot sums onto the markers' rotation / translation rows (views ``(n, ..., K, 3)``) in
    the rounds of a :class:`SlotIndex`: ``rot[:, ..., s]`` for every slot, ``trans`` for the
    point slots (``lead``: index of the axes between the instance and the slot axes)."""
    a = (slice(None),) + lead
    for ks, ss in rounds[0]:
        rot_rows[a + (ks,)] += rot[a + (ss,)]
    for ks, ss in rounds[1]:
        trans_rows[a + (ks,)] += trans[a + (ss,)]


def _tangent_blocks(kin: SlotKinematics, rho, G, K: int, pat: LocalPattern | None):
    """``B^T G B + C`` (n, 6K, 6K): :func:`tangent_compact` scattered into the dense layout."""
    n = kin.pt.shape[0]
    Kc = tangent_compact(kin, rho, G, K, pat).reshape(-1, 3, 3, n)
    Km = np.zeros((n, 2 * K, 3, 2 * K, 3))
    bi, bj = np.nonzero(pat.bpos >= 0)
    Km[:, bi, :, bj, :] = Kc[pat.bpos[bi, bj]].transpose(0, 3, 1, 2)
    return Km.reshape(n, 6 * K, 6 * K)


def _cross_cols(v, M):
    """``skew(v) @ M`` for (3, n) ``v`` and (3, 3, n) ``M`` (component-major): each column of
    ``M`` crossed with ``v`` from the left (small: gathered by index, as :func:`cross3`)."""
    if M.size <= _GATHER_MAX:
        out = v.take(_NEXT, 0)[:, None] * M.take(_PREV, 0)
        out -= v.take(_PREV, 0)[:, None] * M.take(_NEXT, 0)
        return out
    out = np.empty(M.shape, M.dtype if M.dtype == v.dtype else np.result_type(v, M))
    out[0] = v[1] * M[2] - v[2] * M[1]
    out[1] = v[2] * M[0] - v[0] * M[2]
    out[2] = v[0] * M[1] - v[1] * M[0]
    return out


def _cross_rows(M, u):
    """``M @ skew(u)`` for (3, 3, n) ``M`` and (3, n) ``u``: row ``i`` is ``M[i] x u``."""
    if M.size <= _GATHER_MAX:
        out = M.take(_NEXT, 1) * u.take(_PREV, 0)[None]
        out -= M.take(_PREV, 1) * u.take(_NEXT, 0)[None]
        return out
    out = np.empty(M.shape, M.dtype if M.dtype == u.dtype else np.result_type(M, u))
    out[:, 0] = M[:, 1] * u[2] - M[:, 2] * u[1]
    out[:, 1] = M[:, 2] * u[0] - M[:, 0] * u[2]
    out[:, 2] = M[:, 0] * u[1] - M[:, 1] * u[0]
    return out


def tangent_compact(kin: SlotKinematics, rho, G, K: int, pat: LocalPattern,
                    out: np.ndarray | None = None) -> np.ndarray:
    """``B^T G B + C`` of a family with a compact pattern (``pat.compact``), as
    ``(9 * nblocks, n)`` values (entry-major) in the order of ``pat.order``, built block-wise.

    Only the slot-pair blocks of G that the family declares (``pat.s_idx, pat.t_idx``) are
    used; every pair is ``Sk_s G_st (-Sk_t)`` on (rot k, rot l), ``G_st (-Sk_t)`` on
    (trans k, rot l) for point slots s, ``Sk_s G_st`` on (rot k, trans l) and ``G_st`` on
    (trans k, trans l), with ``Sk = skew(v)`` applied as cross products. Blocks are built
    component-major, ``(nblocks, 3, 3, n)``: every operation runs over all instances at once
    (no per-instance 3x3 products) and the model registers the entries in this order (no
    transpose). Slots without a reaction (``rho_s = 0``) or at their body's reference point
    (not ``pat.conn``) add no connection term. ``out``: a ``(9 * nblocks, n)`` array (a view: a
    big family's columns of one chunk) the values are built in and returned (no copy of a
    chunk's values into the family's).
    """
    n, S = kin.pt.shape
    ml = kin.slot_ml
    bpos = pat.bpos
    if not pat.nblocks:             # no entry registered (a load at its body's reference point)
        return np.zeros((0, n)) if out is None else out
    if out is None:
        Kb = np.zeros((pat.nblocks, 3, 3, n))
    else:
        Kb = out.reshape(pat.nblocks, 3, 3, n)
        if not np.may_share_memory(Kb, out):
            raise ValueError("tangent_compact: out must reshape to (nblocks, 3, 3, n) as a view")
        Kb[...] = 0.0
    V = np.ascontiguousarray(kin.V.transpose(1, 2, 0))          # (S, 3, n)
    W = np.ascontiguousarray(rho.reshape(n, S, 3).transpose(1, 2, 0))
    # connection term: v w^T - (v . w) I on (rot k, rot k) per slot
    if 1 < S and n * S <= LocalPattern.SLOT_INDEX_MAX:
        # small: every slot's term at once, added in rounds of distinct markers (each block
        # gets its slots' terms in slot order, as below; a slot without a reaction adds zeros)
        VW = V[:, :, None, :] * W[:, None, :, :]                  # (S, 3, 3, n)
        d = V[:, 0] * W[:, 0] + V[:, 1] * W[:, 1] + V[:, 2] * W[:, 2]
        diag = Kb.reshape(-1, 9, n)
        for blocks, ss in pat.conn_rounds:
            if isinstance(blocks, slice):
                Kb[blocks] += VW[ss]
                diag[blocks, ::4] -= d[ss][:, None, :]
            else:
                Kb[blocks] += VW[ss]
                diag[blocks[:, None], _DIAG9] -= d[ss][:, None, :]
    else:
        live = np.logical_or.reduce(W.reshape(S, -1), axis=1).tolist()   # with a reaction
        for s in range(S):
            if not (live[s] and pat.conn[s]):
                continue
            v, w = V[s], W[s]
            k = ml[s]
            blk = Kb[bpos[2 * k + 1, 2 * k + 1]]
            blk += v[:, None, :] * w[None, :, :]
            d = v[0] * w[0] + v[1] * w[1] + v[2] * w[2]
            blk.reshape(9, n)[::4] -= d                            # the diagonal (a view)
    if G is not None and len(pat.s_idx):
        compact_g = isinstance(G, PairBlocks)
        pt = kin.pt
        for s, t in pat.pairs:
            k, l = ml[s], ml[t]
            if compact_g:      # G_st = c I: Sk_s G_st = skew(c v_s), the block only if read
                RT = G.skew_times(s, t, V[s])
                Gp = G.block(s, t) if pat.pt_any[s] or pat.pt_any[t] else None
            else:
                Gp = np.ascontiguousarray(G[:, 3 * s:3 * s + 3, 3 * t:3 * t + 3]
                                          .transpose(1, 2, 0))
                RT = _cross_cols(V[s], Gp)                      # Sk_s G_st
            Kb[bpos[2 * k + 1, 2 * l + 1]] -= _cross_rows(RT, V[t])
            ws = None if pat.pt_all[s] else pt[:, s]
            wt = None if pat.pt_all[t] else pt[:, t]
            if pat.pt_any[s]:
                blk = _cross_rows(Gp, V[t])                     # G_st Sk_t
                Kb[bpos[2 * k, 2 * l + 1]] -= blk if ws is None else blk * ws
            if pat.pt_any[t]:
                Kb[bpos[2 * k + 1, 2 * l]] += RT if wt is None else RT * wt
            if pat.pt_any[s] and pat.pt_any[t]:
                blk = Gp
                if ws is not None:
                    blk = blk * ws
                if wt is not None:
                    blk = blk * wt
                Kb[bpos[2 * k, 2 * l]] += blk
    return Kb.reshape(-1, n) if out is None else out


def constraint_jacobian_local(kin: SlotKinematics, phi_y: np.ndarray, K: int) -> np.ndarray:
    """``phi_y B`` (n, m, 6K) from the slot structure (no dense B)."""
    n, S = kin.pt.shape
    m = phi_y.shape[1]
    py = phi_y.reshape(n, m, S, 3)
    # rotation columns: p^T (-Sk_s) = (v_s x p)^T
    rot = cross3(kin.V[:, None, :, :], py)                     # (n, m, S, 3)
    if kin.rounds is not None and kin.index is not None:
        return kin.index.slot_sums(rot, py, K).reshape(n, m, 6 * K)
    Pq = np.zeros((n, m, 2 * K, 3))
    if kin.rounds is not None:
        _round_sums(kin.rounds, Pq[:, :, 1::2], Pq[:, :, 0::2], rot, py, (slice(None),))
        return Pq.reshape(n, m, 6 * K)
    pt = kin.pt
    p_all, p_any = kin.masks                                # per slot, once
    for s in range(S):
        k = kin.slot_ml[s]
        Pq[:, :, 2 * k + 1] += rot[:, :, s]
        if p_all[s]:
            Pq[:, :, 2 * k] += py[:, :, s]
        elif p_any[s]:
            Pq[:, :, 2 * k] += py[:, :, s] * pt[:, s][:, None, None]
    return Pq.reshape(n, m, 6 * K)


def local_residual_tangent(kin: SlotKinematics, rho: np.ndarray, G: np.ndarray | None,
                           slot_ml, K: int, need_jac: bool = True, ext: dict | None = None,
                           U: int = 0, pat: LocalPattern | None = None):
    """Local residual ``[B^T rho; rho_s]`` (n, 6K+U) and tangent (n, 6K+U, 6K+U).

    The marker block of the tangent is ``B^T G B + C``. With ``U`` scalar columns (extra unknowns
    the family reads), ``ext`` may hold ``rho_s`` (n, U) (residual rows of the scalar unknowns
    the family owns or its generalised forces on them), ``G_ys`` (n, 3S, U) = d rho / d s,
    ``G_sy`` (n, U, 3S) = d rho_s / d y and ``G_ss`` (n, U, U); missing pieces are zero.

    ``pat`` (the family's :class:`LocalPattern`) restricts ``G`` to its declared slot-pair
    blocks; without it (or for families declaring none) ``G`` is used as a dense matrix.
    """
    n = rho.shape[0]
    r = local_residual(kin, rho, K)
    ext = ext or {}
    if U:
        rs = ext.get("rho_s")
        r = np.concatenate([r, np.zeros((n, U)) if rs is None else rs], axis=1)
    if not need_jac:
        return r, None
    return r, local_tangent(kin, rho, G, slot_ml, K, ext, U, pat)


def local_tangent(kin: SlotKinematics, rho: np.ndarray, G, slot_ml, K: int,
                  ext: dict | None = None, U: int = 0, pat: LocalPattern | None = None):
    """The tangent of :func:`local_residual_tangent` alone (a Jacobian assembled after its
    residual: the residual is not formed again)."""
    n = rho.shape[0]
    ext = ext or {}
    if pat is not None and pat.declared:
        Kl = _tangent_blocks(kin, rho, G, K, pat)
    else:
        B = kin.B
        if G is None:
            Kl = np.zeros((n, 6 * K, 6 * K))
        else:
            Kl = np.matmul(B.swapaxes(1, 2), np.matmul(dense_g(G), B))
        # connection term v w^T - (v . w) I per slot, formed for every slot at once
        S = kin.V.shape[1]
        rho3 = rho.reshape(n, S, 3)
        blk = kin.V[:, :, :, None] * rho3[:, :, None, :]           # (n, S, 3, 3)
        d = np.einsum("nsi,nsi->ns", kin.V, rho3)
        blk.reshape(n, S, 9)[:, :, ::4] -= d[:, :, None]           # the diagonals (a view)
        rounds = None if pat is None else pat.slot_rounds
        if rounds is not None and kin.index is not None:
            # small: one bincount adds each slot's block (in slot order) onto Kl's entries
            Kl = kin.index.add_connection(Kl, blk, K)
        elif rounds is None:
            for s in range(S):
                k = slot_ml[s]
                Kl[:, 6 * k + 3:6 * k + 6, 6 * k + 3:6 * k + 6] += blk[:, s]
        else:       # the markers' (rot, rot) blocks as one view, slots added round by round
            diag = np.einsum("nkikj->nkij", Kl.reshape(n, K, 6, K, 6)[:, :, 3:, :, 3:])
            for ks, ss in rounds:
                diag[:, ks] += blk[:, ss]
    if U:
        B = kin.B
        full = np.zeros((n, 6 * K + U, 6 * K + U))
        full[:, :6 * K, :6 * K] = Kl
        if ext.get("G_ys") is not None:
            full[:, :6 * K, 6 * K:] = np.matmul(np.swapaxes(B, 1, 2), ext["G_ys"])
        if ext.get("G_sy") is not None:
            full[:, 6 * K:, :6 * K] = np.matmul(ext["G_sy"], B)
        if ext.get("G_ss") is not None:
            full[:, 6 * K:, 6 * K:] = ext["G_ss"]
        Kl = full
    return Kl
