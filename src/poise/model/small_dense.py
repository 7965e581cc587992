"""One dense pass for the residual and KKT Jacobian of a small model (a few bodies).

The generic engine (:mod:`poise.model.evaluate`) maps every family's slot outputs to its local
body coordinates and scatters them into the residual and the fixed-pattern assembly: about a
dozen small-array calls per family and evaluation, which at three bodies cost more than the
arithmetic. Here every slot of the model (families in ``Model.eval_order``, instance-major,
slot-minor) is one row block of a single dense slot-to-coordinate map ``B`` (``3 S_tot x nq``:
``[I | -skew(v)]`` for a point slot, ``[0 | -skew(a)]`` for an axis, ground columns absent),
built from the slot levers with one gather per evaluation. Then

* residual ``r = B^T rho`` (one product over every family),
* coordinate block ``sum_f B_f^T G_f B_f`` (one product per family with a ``G``) plus the
  connection term ``v rho^T - (v . rho) I`` on each slot's body rotation block and the mass
  shift, added with one ``bincount``,
* constraint block ``phi_y B`` (one batched product per constraint family),

and the KKT matrix is written directly as a dense array. The values equal the generic
assembly's up to summation order (round-off); the structure declarations
(``g_blocks``) restrict ``G`` the same way. Only models assembled dense with no scalar unknowns
and no reaction feed, up to :data:`SMALL_MAX` unknowns (beyond, the products of the dense maps
cost more than the generic path's sparse work): :func:`small_dense` decides at layout time.
"""
from __future__ import annotations

import numpy as np

from poise.core.lean import concatenate
from poise.elements.kernel import PairBlocks, SlotKinematics
from poise.elements.slot_index import POINT

#: KKT size up to which a model gets the dense slot pass
SMALL_MAX = 96

# -skew(v) entries (row a, col b) from (v, -v): (a, b, index into the 6 values [v, -v])
_NSKEW = ((0, 1, 2), (0, 2, 4), (1, 0, 5), (1, 2, 0), (2, 0, 1), (2, 1, 3))


def small_dense(model) -> "SmallDense | None":
    """The :class:`SmallDense` tables of a laid-out model (a namespace with the model's
    fields), or None when the model does not qualify (see the module docstring)."""
    if (not model.dense or model.N > SMALL_MAX or model.reaction_feed is not None
            or model.n_extra or model.nq == 0):
        return None
    if any(f.U or f.pattern is None for f in model.families):
        return None
    rows = [np.asarray(f.crow).ravel() for f in model.families if f.is_constraint and f.n]
    if not np.array_equal(np.sort(np.concatenate(rows)) if rows else np.zeros(0, int),
                          np.arange(model.nc)):        # every row in one family instance
        return None
    return SmallDense(model)


class _FamilyTable:
    """One family's place in the slot map: its row range and structure."""

    __slots__ = ("fam", "a", "b", "n", "S", "gmask", "pairs", "partner")

    def __init__(self, fam, a, b):
        self.fam, self.a, self.b, self.n, self.S = fam, a, b, fam.n, len(fam.slot_ml)
        gb = fam.g_blocks()
        # declared G structure: blocks outside it are not part of the tangent (as assembled)
        m = None
        self.pairs = self.partner = None
        if gb is not None:
            gb = np.asarray(gb, bool)
            if not gb.all():
                m = np.kron(gb, np.ones((3, 3))).astype(float)
            # at most one declared partner per slot: a PairBlocks G (c I blocks) times B is
            # B's partner rows scaled (PairBlocks.times)
            if (gb.sum(axis=1) <= 1).all():
                t = gb.argmax(axis=1)
                self.pairs = tuple((s, int(t[s])) for s in range(self.S) if gb[s, t[s]])
                self.partner = t
        self.gmask = m

    def g_times(self, G, B3):
        """``G B_f`` (n, 3S, nq) of the family's ``G`` and its slot map ``B3`` (n, S, 3, nq)."""
        if isinstance(G, PairBlocks) and self.pairs is not None:
            n = self.n
            c = np.zeros((n, self.S))
            for s, t in self.pairs:
                v = G.coef.get((s, t))
                if v is not None:
                    c[:, s] = v
            GB = B3.take(self.partner, axis=1)
            GB *= c[:, :, None, None]
            return GB.reshape(n, 3 * self.S, -1)
        Gd = G.dense() if isinstance(G, PairBlocks) else G
        if self.gmask is not None:
            Gd = Gd * self.gmask
        return np.matmul(Gd, B3.reshape(self.n, 3 * self.S, -1))


class SmallDense:
    """Index tables of the dense slot pass of one model (built once, at layout time)."""

    def __init__(self, model):
        nq = model.nq
        self.nq, self.nc, self.N = nq, model.nc, model.N
        tabs, tcols, rcols, at = [], [], [], 0
        for fi in model.eval_order:
            fam = model.families[fi]
            n, S = fam.n, len(fam.slot_ml)
            if n == 0:
                continue
            g = np.asarray(fam.gcol)
            ml = np.asarray(fam.slot_ml)
            cols = g[:, (6 * ml[:, None] + np.arange(6)).ravel()].reshape(n, S, 6)
            pt = np.asarray(fam.slot_kind) == POINT
            t = np.where(pt[:, :, None], cols[:, :, :3], -1)
            tcols.append(t.reshape(n * S, 3))
            rcols.append(cols[:, :, 3:].reshape(n * S, 3))
            tabs.append(_FamilyTable(fam, 3 * at, 3 * (at + n * S)))
            at += n * S
        self.families = tuple(tabs)
        self.S = at
        # the constraint rows as the families give them (eval order): the order to put back
        crow = [np.asarray(t.fam.crow).ravel() for t in tabs if t.fam.is_constraint]
        rows = np.concatenate(crow) if crow else np.zeros(0, int)
        self.row_order = (None if np.array_equal(rows, np.arange(model.nc))
                          else np.argsort(rows, kind="stable"))
        self.kin_at = _kinematics_index(model)
        T = np.concatenate(tcols) if tcols else np.zeros((0, 3), int)
        R = np.concatenate(rcols) if rcols else np.zeros((0, 3), int)
        W = 3 * at
        B0 = np.zeros((W, nq))
        sl, ca = np.nonzero(T >= 0)
        B0[3 * sl + ca, T[sl, ca]] = 1.0
        self.B0 = B0
        # rotation columns: -skew(v) of each slot whose marker's body rotates
        rot = np.nonzero((R >= 0).all(axis=1))[0]
        dst, src, sgn = [], [], []
        for a, b, k in _NSKEW:
            dst.append((3 * rot + a) * nq + R[rot, b])
            src.append(3 * rot + k % 3)
            sgn.append(np.full(rot.size, 1.0 if k < 3 else -1.0))
        self.skew_dst = np.concatenate(dst)
        self.skew_src = np.concatenate(src)       # lever entries, times their sign (exact)
        self.skew_sgn = np.concatenate(sgn)
        # additive terms of the coordinate block, one bincount: the connection term of every
        # rotating slot (its 3x3 block), then the mass shift (translations, rotations)
        i3 = np.arange(3)
        cdst = ((R[rot][:, :, None] * nq + R[rot][:, None, :])).ravel()
        tb = (model.body_off[:, None] + i3).ravel()
        rigid = model.body_kind == 0
        rb = model.body_off[rigid][:, None] + 3 + i3
        jdst = (rb[:, :, None] * nq + rb[:, None, :]).ravel()
        # entry (a, b) of slot s's term: lever entry 3 s + a times reaction entry 3 s + b, less
        # the slot's v . rho on the diagonal (the rotating slots' entries only, none formed for
        # the others)
        self.conn_v = (3 * rot[:, None] + np.repeat(i3, 3)).ravel()
        self.conn_w = (3 * rot[:, None] + np.tile(i3, 3)).ravel()
        self.conn_diag = (9 * np.arange(rot.size)[:, None] + 4 * i3).ravel()
        self.conn_slot = np.repeat(rot, 3)
        self.add_dst = np.concatenate([cdst, tb * (nq + 1), jdst])
        self.n_conn = 9 * rot.size
        self.mass3 = np.repeat(model.body_mass, 3)
        self.diag_c = np.arange(self.nc) * (self.N + 1) + nq * (self.N + 1)   # flat, in J

    def kinematics(self, P, A, pos) -> dict | None:
        """The slot kinematics of every family (``{family index: SlotKinematics}``) from the
        marker origins ``P``, axes ``A`` and body positions ``pos`` (ground last) of one frame:
        one gather for all (the values of :func:`~poise.elements.kernel.slot_kinematics`),
        None when a family keeps no :class:`~poise.elements.slot_index.SlotIndex`."""
        if self.kin_at is None:
            return None
        yat, vat, fams = self.kin_at
        # Y: each slot's origin or axis column, one gather from (P, A); V: Y less its body's
        # position for a point (the ground row of ``pos``, zeros, for an axis: Y - 0 is Y)
        Y = concatenate((P.ravel(), A.ravel())).take(yat)
        V = Y - pos.take(vat)
        # (positional arguments: a keyword call per family costs more than its views)
        return {fi: SlotKinematics(Y[a:b].reshape(shape), V[a:b].reshape(shape), ix.pt,
                                   ix.slot_ml, K, None, ix.masks, ix.rounds, ix)
                for fi, a, b, shape, K, ix in fams}

    def outputs(self, passes, need_jac):
        """``(r, phi, pend, items)`` of one frame from the family pass ``passes`` (the
        generator of :func:`poise.model.evaluate._family_pass`), ``pend`` a
        :class:`SmallTerms` when ``need_jac``; None when ``r`` is not finite (the caller's
        generic pass then names the element)."""
        last, rhos, levers, terms, phis = [], [], [], [], []
        for _, fam, kin, rho, G, ph, phy, _ in passes:
            if ph is not None:
                phis.append(ph.ravel())
            last.append((fam, kin, rho, phy))
            rhos.append(rho.ravel())
            levers.append(kin.V)
            terms.append((G, phy))
        # every constraint row once (small_dense): in row order, or gathered into it
        phi = concatenate(phis) if phis else np.zeros(self.nc)
        if self.row_order is not None:
            phi = phi.take(self.row_order)
        # the levers of one gather (SmallDense.kinematics, eval order) are that array already
        V = levers[0].base
        if V is not None and V.size == 3 * self.S:
            for v in levers:
                if v.base is not V:
                    V = None
                    break
        V = concatenate([v.ravel() for v in levers]) if V is None else V.ravel()
        B = self.B0.copy()
        B.put(self.skew_dst, V.take(self.skew_src) * self.skew_sgn)
        rho = concatenate(rhos)
        r = rho @ B
        if not np.isfinite(np.add.reduce(r)):      # (r.sum() without its Python wrapper)
            return None
        return r, phi, (SmallTerms(self, B, V, rho, terms) if need_jac else None), last


def _kinematics_index(model):
    """``(markers, axis columns, point mask, bodies, families)`` of every slot of the model
    (:meth:`SmallDense.kinematics`), from the families' slot indices; None if one has none."""
    mk, ax, pt, body, fams, at = [], [], [], [], [], 0
    for fi in model.eval_order:            # the slot map's order (SmallDense.outputs)
        fam = model.families[fi]
        if fam.n == 0:
            continue
        ix = fam.pattern.slots
        if ix is None:
            return None
        n, S = ix.mk.shape
        mk.append(ix.mk.ravel())
        ax.append(np.broadcast_to(ix.ax, (n, S)).ravel())
        pt.append(ix.pt.ravel())
        body.append(ix.body.ravel())
        fams.append((fi, at, at + n * S, (n, S, 3), fam.markers.shape[1], ix))
        at += n * S
    if not fams:
        return None
    mk, ax, pt, body = (np.concatenate(x) for x in (mk, ax, pt, body))
    c = np.arange(3)
    nm = model.marker_body.size
    # flat positions in concatenate((P.ravel(), A.ravel())): P[mk, c] or A[mk, c, ax]
    yat = np.where(pt[:, None], 3 * mk[:, None] + c, 3 * nm + 9 * mk[:, None] + 3 * c + ax[:, None])
    # in pos (nb + 1, 3), ground last (zeros): the body's row for a point, ground's for an axis
    vat = 3 * np.where(pt, body, model.nb)[:, None] + c
    return yat, vat, tuple(fams)


class SmallTerms:
    """What the Jacobian of one small-model evaluation is made from (deferred: line-search
    trials never form it): the slot map, levers, slot reactions and each family's ``G`` and
    ``phi_y``. Read only (a kept evaluation may be assembled again)."""

    __slots__ = ("tab", "B", "V", "rho", "terms")

    def __init__(self, tab, B, V, rho, terms):
        self.tab, self.B, self.V, self.rho, self.terms = tab, B, V, rho, terms

    def jacobian(self, Jg, eps_mass, row_active, stiffness) -> np.ndarray:
        """The dense KKT matrix: coordinate block (``stiffness``: with the tangents, else the
        mass shift alone), constraint rows of ``row_active`` and their transpose, 1 on the
        multiplier diagonal of the other rows."""
        tab, B = self.tab, self.B
        nq, N = tab.nq, tab.N
        J = np.zeros((N, N))
        K = J[:nq, :nq]
        mass = (eps_mass * tab.mass3, eps_mass * Jg.ravel())
        if stiffness:
            V, rho = self.V, self.rho
            C = V.take(tab.conn_v) * rho.take(tab.conn_w)      # the outer products' entries
            C[tab.conn_diag] -= np.add.reduce((V * rho).reshape(-1, 3), axis=1).take(tab.conn_slot)
            add = concatenate((C,) + mass)
        else:
            add = concatenate(mass)
        dst = tab.add_dst if stiffness else tab.add_dst[tab.n_conn:]
        K += np.bincount(dst, weights=add, minlength=nq * nq).reshape(nq, nq)
        pqs = []
        for ft, (G, phy) in zip(tab.families, self.terms):
            Bf = B[ft.a:ft.b]
            if stiffness and G is not None:
                K += Bf.T @ ft.g_times(G, Bf.reshape(ft.n, ft.S, 3, nq)).reshape(-1, nq)
            if phy is not None:
                pqs.append(np.matmul(phy, Bf.reshape(ft.n, 3 * ft.S, nq)).reshape(-1, nq))
        if pqs:       # every constraint row once: in row order (or gathered into it)
            Pq = concatenate(pqs) if len(pqs) > 1 else pqs[0]
            J[nq:, :nq] = Pq if tab.row_order is None else Pq.take(tab.row_order, axis=0)
        if not np.logical_and.reduce(row_active, axis=None):
            off = ~row_active
            J[nq:, :nq][off] = 0.0
            J.ravel()[tab.diag_c[off]] = 1.0
        J[:nq, nq:] = J[nq:, :nq].T
        return J
