"""Reaction channels inside expression forces, evaluated at every ``Model.evaluate``.

:class:`ReactionFeed` evaluates the constraint families and the force families that read no
reaction first, then the channels the reading forces use, and gives the Newton Jacobian their
exact derivatives w.r.t. the multipliers and w.r.t. the coordinates at fixed multipliers
(docs/expressions.md), so Newton converges quadratically.
"""
from __future__ import annotations

import numpy as np

from poise.elements.base import GLOBAL
from poise.elements.channels import ExprInfo, resultant_side
from poise.elements.forces import apply_two_body
from poise.elements.kernel import SlotKinematics, cross3, dense_g, local_residual_tangent
from poise.elements.loads import loads_of
from poise.elements.rotation import skew

class _Weights:
    """How the derivative of E entries' contributions becomes the derivative of their channels:
    a channel is ``w_F . F' + w_T . T'`` to first order, ``(F', T')`` the contribution in global
    axes (taken on J when flipped), ``w`` the RM axis of the picked component (a unit axis for
    the global frame) or the unit vector ``V / |V|`` of the channel's whole global F or T (``|F|``,
    ``|T|``; zero at ``V = 0``). On J (``F' = -F``, ``T' = -T - d x F``, ``d = P_I - P_J``):
    ``w_F . F' + w_T . T' = (-w_F - w_T x d) . F + (-w_T) . T``. :meth:`weights` returns the
    ``(E, 6)`` weights of the unflipped ``(F, T)``, so every derivative of a channel is one
    contraction with the contributing instance's ``d(F, T)``."""

    __slots__ = ("isT", "W0", "rk", "rm", "rax", "mk", "mch", "moff", "fl", "fei", "fej")

    def __init__(self, ch, flip, ei, ej, rm, comp):
        c = comp[ch]
        mag = (c == 1) | (c == 5)
        self.isT = c >= 5
        ax = np.where(c <= 4, c - 2, c - 6)
        r = rm[ch]
        self.W0 = np.zeros((len(ch), 3))
        g = np.nonzero(~mag & (r == GLOBAL))[0]
        self.W0[g, ax[g]] = 1.0
        self.rk = np.nonzero(~mag & (r != GLOBAL))[0]
        self.rm, self.rax = r[self.rk], ax[self.rk]
        self.mk = np.nonzero(mag)[0]
        self.mch = ch[self.mk]
        self.moff = np.where(c[self.mk] == 1, 0, 3)
        self.fl = np.nonzero(flip)[0]
        self.fei, self.fej = ei[self.fl], ej[self.fl]

    def weights(self, P, A, Dg):
        W = self.W0.copy()
        if len(self.rk):
            W[self.rk] = A[self.rm, :, self.rax]
        if len(self.mk):
            v = Dg[self.mch[:, None], self.moff[:, None] + np.arange(3)]
            nv = np.linalg.norm(v, axis=1)[:, None]
            W[self.mk] = np.divide(v, nv, out=np.zeros_like(v), where=nv > 0)
        w = np.zeros((len(W), 6))
        w[:, :3] = np.where(self.isT[:, None], 0.0, W)
        w[:, 3:] = np.where(self.isT[:, None], W, 0.0)
        if len(self.fl):
            d = P[self.fei] - P[self.fej]
            b = w[self.fl, 3:]
            w[self.fl, :3] = -w[self.fl, :3] - cross3(b, d)
            w[self.fl, 3:] = -b
        return w


class _CouplingGroup:
    """The :class:`ReactionFeed` entries of one (reader family ``ri``, contributing family
    ``fi``) pair as index arrays (E entries): reader pair ``p`` (instance, local column) of
    ``ri``, contributing instance position ``pos`` among the read instances of ``fi``, its
    multiplier rows ``crows`` (E, m; constraint families, ``lam``) and the channel weights
    ``wt`` (:class:`_Weights`). ``q``: the block also has the contributing instance's local
    coordinate columns that its action on I depends on (empty: e.g. Coincident). ``ft``: the
    flipped torque entries (the lever ``P_I - P_J`` of the transfer moves) with their element
    markers ``ftei``/``ftej``; None when there are none (or both markers are on ground)."""

    __slots__ = ("ri", "fi", "p", "pos", "crows", "lam", "q", "wt", "ft", "ftei", "ftej")


class _RMBlock:
    """Coordinate derivative of components read in a moving RM marker's axes, for reader family
    ``ri``: its pairs ``sel`` (positions among the reader's read pairs), channels ``ch``, RM
    markers ``rm``, the RM axis ``axis`` and the offset ``off`` (0 F, 3 T) of the component."""

    __slots__ = ("ri", "sel", "ch", "rm", "axis", "off")


class ReactionChannels:
    """What the compiler registers (:meth:`poise.elements.context.CompileContext.
    set_reaction_channels`): the reaction channels forces read. The model compiler builds the
    :class:`ReactionFeed` from it once the families are laid out."""

    __slots__ = ("channels",)

    def __init__(self, channels):
        self.channels = tuple(channels)


class ReactionFeed:
    """Reaction channels read by expression forces, evaluated inside ``Model.evaluate``.

    ``Model.evaluate`` evaluates every family not in :attr:`readers` first (constraints with the
    current multipliers, forces that read no reaction), then calls :meth:`values` with their
    kept ``(fam, kin, rho, phi_y)`` tuples and passes the result as ``EvalContext.reactions`` to
    the reader families. The values are exact at the current iterate (no lag), and so is the
    Jacobian of the readers through them (:meth:`coupling`): the derivative of every channel
    w.r.t. the multipliers and w.r.t. the coordinates (and scalar unknowns) at fixed
    multipliers.

    Both :meth:`values` and :meth:`coupling` are vectorised over channels and entries: their
    index arrays are built once, with the model (:class:`ChannelPlan`, :meth:`_setup`), the
    per-evaluation Python work is O(groups), not O(channels) or O(entries). ``model`` is the
    model being built (its families laid out); ``element_markers`` ``(tag, id) -> (I, J)``.
    :attr:`blocks`: the coupling pattern the model's assembler registers.
    """

    __slots__ = ("channels", "info", "plan", "blocks", "entries", "groups", "rm_blocks",
                 "_mlever", "_pairs", "_inst", "_qcols", "_need_f")

    def __init__(self, model, reaction_channels, element_markers):
        self.channels = tuple(reaction_channels.channels)
        self.info = ExprInfo(model.outputs, element_markers)
        self.plan = self.info.plan(model, self.channels)
        self.blocks = tuple(self._setup(model))

    def values(self, model, items, P, A):
        """``(channel values, Dg)``: the channels at the evaluation's families ``items``
        (kept ``(fam, kin, rho, phi_y)``) and their (F, T) in global axes (:meth:`coupling`)."""
        D, Dg = self._vectors(model, items, P, A)
        return self.plan.pick(D), Dg

    def _vectors(self, model, items, P, A):
        return self.plan.vectors(loads_of(model, items), P, A, glob=True)

    # ------------------------------------------------------------------ Jacobian blocks
    def _setup(self, model):
        """Coupling pattern (with the model). Per (reader instance, channel,
        contributing instance the channel sums: a constraint-family instance of a joint, jprim
        or motion, or a force-family instance of a force element) one ``(12, m + Lq)`` block
        of the KKT Jacobian: the reader's I and J coordinates x the contributor's multipliers (m,
        constraints) and the Lq local coordinates (markers' bodies, scalar unknowns) its action
        on I can depend on, grouped per (reader family, contributing family) into one
        ``(E, 12, m + Lq)`` block; per group also the flipped torque entries x the
        coordinates of the element's I and J markers (the transfer lever), and per reader
        family the components read in a moving RM marker x that marker's rotation. Returns the
        blocks.

        :attr:`entries` (E, 9) lists the entries in reader order: ``(reader family, instance,
        local column u, channel, contributing family, instance j, flip, I, J)``."""
        fams = model.families
        owners = self.info.owners
        inv = {g: {o: key for key, o in om.items()} for g, om in owners.items()}
        by_key, by_mk = {}, {}              # contributing instances with a reaction output
        for fi, f in enumerate(fams):
            if f.reads_reactions or f.group not in inv:
                continue
            for j, o in enumerate(np.asarray(f.owner).ravel().tolist()):
                key = inv[f.group].get(o)
                if key is None:
                    continue
                ei, ej = self.info.markers[key]
                rec = (fi, j, ei, ej)
                by_key.setdefault((f.group,) + key, []).append(rec)
                by_mk.setdefault(ei, []).append(rec)
                if ej != ei:
                    by_mk.setdefault(ej, []).append(rec)
        contrib = []                        # per channel: [(fi, j, flip, ei, ej)]
        for ch in self.channels:
            if ch[0] == "EL":
                contrib.append([(fi, j, int(bool(ch[4])), ei, ej)
                                for fi, j, ei, ej in by_key.get(tuple(ch[1:4]), ())])
                continue
            mi, mj = ch[1], ch[2]
            sides = [(r, resultant_side(mi, mj, r[2], r[3])) for r in by_mk.get(mi, ())]
            contrib.append([(fi, j, side, ei, ej) for (fi, j, ei, ej), side in sides
                            if side is not None])
        rows = []
        for ri, f in enumerate(fams):
            if not f.reads_reactions:
                continue
            for i, cs in enumerate(f.rcols.tolist()):
                for u, c in enumerate(cs):
                    if c >= 0:
                        rows += [(ri, i, u, c) + t for t in contrib[c]]
        E = np.array(rows, np.intp).reshape(-1, 9)
        self.entries = E
        # stable: same-(row, col) entries keep their order (identical assembly sums)
        E = E[np.lexsort((E[:, 4], E[:, 0]))]
        rm = np.array([ch[6] if ch[0] == "EL" else ch[4] for ch in self.channels], np.intp)
        comp = np.array([ch[5] if ch[0] == "EL" else ch[3] for ch in self.channels], np.intp)
        mcols = _marker_columns(model)
        # body origin -> marker origin in the marker's axes: lever = A_marker @ _mlever
        self._mlever = np.einsum("nji,nj->ni", model.marker_A0, model.marker_s0)
        self._pairs = {}                    # reader family -> (instances, local columns) read
        self._inst = {}                     # contributing family -> instances read
        self._qcols = {}                    # contributing family -> local columns of d(F, T)
        self._need_f = {}                   # contributing family -> F needed (lever blocks)
        for ri in np.unique(E[:, 0]).tolist():
            pr = np.unique(E[E[:, 0] == ri][:, 1:3], axis=0)
            self._pairs[ri] = (pr[:, 0], pr[:, 1])
        for fi in np.unique(E[:, 4]).tolist():
            self._inst[fi] = np.unique(E[E[:, 4] == fi, 5])
            self._qcols[fi] = _action_columns(fams[fi])
            self._need_f[fi] = False
        self.groups = []
        blocks = []
        key = E[:, 0] * len(fams) + E[:, 4]
        for s in np.split(np.arange(len(E)), np.nonzero(np.diff(key))[0] + 1):
            if not len(s):
                continue
            e = E[s]
            ri, fi = int(e[0, 0]), int(e[0, 4])
            f, g = fams[ri], fams[fi]
            gp = _CouplingGroup()
            gp.ri, gp.fi = ri, fi
            pi, pu = self._pairs[ri]
            gp.p = _pair_index(pi, pu, f.rcols.shape[1], e[:, 1], e[:, 2])
            gp.pos = np.searchsorted(self._inst[fi], e[:, 5])
            gp.lam = g.is_constraint
            gp.q = len(self._qcols[fi]) > 0
            gp.crows = g.crow[e[:, 5]] if gp.lam else None
            gp.wt = _Weights(e[:, 3], e[:, 6], e[:, 7], e[:, 8], rm, comp)
            ft = np.nonzero(e[:, 6] & (comp[e[:, 3]] >= 5))[0]
            ftc = np.concatenate([mcols[e[ft, 7]], mcols[e[ft, 8]]], axis=1)
            gp.ft = ft if (ftc >= 0).any() else None
            nr = _READER_ROWS
            rrow = f.gcol[e[:, 1], :nr]
            cols = []
            if gp.lam:
                cols.append(model.nq + gp.crows)
            if gp.q:
                cols.append(g.gcol[e[:, 5]][:, self._qcols[fi]])
            if cols:
                c = np.concatenate(cols, axis=1)
                shape = (len(e), nr, c.shape[1])
                blocks.append((np.broadcast_to(rrow[:, :, None], shape),
                               np.broadcast_to(c[:, None, :], shape)))
            if gp.ft is not None:
                self._need_f[fi] = True
                gp.ftei, gp.ftej = e[ft, 7], e[ft, 8]
                shape = (len(ft), nr, 12)
                blocks.append((np.broadcast_to(rrow[ft][:, :, None], shape),
                               np.broadcast_to(ftc[:, None, :], shape)))
            self.groups.append(gp)
        # components in a moving RM's axes: d (a_c . V) / d theta_RM = a_c x V
        self.rm_blocks = []
        for ri, (pi, pu) in self._pairs.items():
            f = fams[ri]
            ch = f.rcols[pi, pu]
            c, r = comp[ch], rm[ch]
            sel = np.nonzero((c != 1) & (c != 5) & (r != GLOBAL) &
                             (mcols[r, 3:] >= 0).any(axis=1))[0]
            if not len(sel):
                continue
            rb = _RMBlock()
            rb.ri, rb.sel, rb.ch, rb.rm = ri, sel, ch[sel], r[sel]
            cs = c[sel]
            rb.axis = np.where(cs <= 4, cs - 2, cs - 6)
            rb.off = np.where(cs <= 4, 0, 3)
            self.rm_blocks.append(rb)
            nr = _READER_ROWS
            shape = (len(sel), nr, 3)
            blocks.append((np.broadcast_to(f.gcol[pi[sel], :nr][:, :, None], shape),
                           np.broadcast_to(mcols[rb.rm, 3:][:, None, :], shape)))
        return blocks

    def coupling(self, model, kept, P, A, row_active, tangents, Dg=None):
        """Values of the :meth:`setup` blocks, exact: ``d r_reader / d (lambda, q)`` through
        the channels. A channel sums, per contributing instance, its action on I (``F = -sum
        rho_s`` over I's point slots, ``T = -sum y_s x rho_s`` over I's axis slots; ``rho =
        phi_y^T lam`` for constraints), optionally taken on J (``-F``, ``-T - (P_I - P_J) x F``)
        and resolved in RM's axes (``A_RM^T``); ``|F|``, ``|T|`` chain through the unit vector
        of the channel's whole F or T (:class:`_Weights`). Per instance: ``d/d lambda`` from
        ``phi_y``; ``d/d q`` at fixed multipliers from the family's own ``G = d rho / d y`` (for
        constraints the multiplier-weighted Hessian: the geometric stiffness) through the slot
        maps ``B``, plus the turning axes ``rho_s x dy_s`` and ``G_ys`` for scalar columns
        (:func:`_action_derivatives`); the transfer lever ``F x (dP_I - dP_J)``; a moving RM's
        ``a_c x V``.

        ``kept``: ``{family index: (fam, kin, rho, phi_y)}`` of the families evaluated before
        the readers; ``tangents``: per family index ``Model.evaluate``'s pending tuple ``(fam,
        kin, rho, G, phi_y, ext)`` (``G``, ``ext`` used; a reader's ``ext["d_reaction"]``);
        ``Dg``: :meth:`values`' second result at this iterate (computed again when None).
        One batched kernel per group."""
        fams = model.families
        if Dg is None:
            Dg = self._vectors(model, kept.values(), P, A)[1]
        rl = {ri: _reader_dreaction(fams[ri], kept[ri][1], pi, pu,
                                    tangents[ri][5]["d_reaction"])
              for ri, (pi, pu) in self._pairs.items()}
        base = {}
        for fi, js in self._inst.items():
            _, kin, rho, phy = kept[fi]
            t = tangents[fi]
            base[fi] = _action_derivatives(fams[fi], kin, rho, phy, t[3], t[5], js,
                                           self._qcols[fi], self._need_f[fi])
        out = []
        for gp in self.groups:
            dl, dq, F = base[gp.fi]
            w = gp.wt.weights(P, A, Dg)[:, None, :]                      # (E, 1, 6)
            parts = []
            if gp.lam:
                parts.append(np.matmul(w, dl[gp.pos])[:, 0] * row_active[gp.crows])
            if gp.q:
                parts.append(np.matmul(w, dq[gp.pos])[:, 0])
            r = rl[gp.ri][gp.p]
            if parts:
                dch = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
                out.append(np.einsum("ei,el->eil", r, dch))
            if gp.ft is not None:
                # w_T . (F x dP) = dP . z, z = w_T x F, w_T = -w[3:] (flipped entries);
                # dP = dr + dtheta x v: columns [z, v x z] on I, [-z, -v x z] on J
                z = cross3(-w[gp.ft, 0, 3:], F[gp.pos[gp.ft]])
                dch = np.empty((len(gp.ft), 12))
                dch[:, 0:3] = z
                dch[:, 3:6] = cross3(self._lever(gp.ftei, A), z)
                dch[:, 6:9] = -z
                dch[:, 9:12] = -cross3(self._lever(gp.ftej, A), z)
                out.append(np.einsum("ei,el->eil", r[gp.ft], dch))
        for rb in self.rm_blocks:
            a = A[rb.rm, :, rb.axis]                                         # (Np, 3)
            V = Dg[rb.ch[:, None], rb.off[:, None] + np.arange(3)]
            out.append(np.einsum("ei,el->eil", rl[rb.ri][rb.sel], cross3(a, V)))
        return out

    def _lever(self, mk, A):
        """(n, 3) marker origin minus its body's origin (CG), global."""
        return np.einsum("nij,nj->ni", A[mk], self._mlever[mk])


def _marker_columns(model):
    """(nm, 6) global coordinate columns (translation, rotation) of each marker's body; -1 on
    ground and for the rotation of point bodies (as the compiler's ``gcol``)."""
    nb = model.nb
    mb = np.asarray(model.marker_body)
    out = np.full((len(mb), 6), -1, np.intp)
    if not nb:
        return out
    mov = mb < nb
    b = mb[mov]
    c = model.body_off[b][:, None] + np.arange(6)
    c[model.body_kind[b] == 1, 3:] = -1
    out[mov] = c
    return out


def _action_columns(g):
    """Local columns (of ``6K + U``) on which family ``g``'s action on its I marker can depend
    at fixed multipliers, from its slot structure and declared ``G`` blocks (``g_blocks``):
    for an I slot ``s``, the columns of every slot ``t`` with a ``G_st`` block (rotation; also
    translation for point slots), I's rotation when ``s`` is an axis, every scalar column.
    Empty for e.g. Coincident (``F = -lam``)."""
    K, S = g.K, len(g.slot_ml)
    ml = np.asarray(g.slot_ml)
    kind = np.asarray(g.slot_kind).reshape(-1, S)
    pt_any = (kind == 0).any(axis=0)
    ax_any = (kind != 0).any(axis=0)
    gb = g.g_blocks()
    gb = np.ones((S, S), bool) if gb is None else np.asarray(gb, bool)
    cols = np.zeros(6 * K + g.U, bool)
    for s in np.nonzero(ml == 0)[0]:
        if ax_any[s]:
            cols[3:6] = True
        for t in np.nonzero(gb[s])[0]:
            k = ml[t]
            cols[6 * k + 3:6 * k + 6] = True
            if pt_any[t]:
                cols[6 * k:6 * k + 3] = True
    cols[6 * K:] = True
    return np.nonzero(cols)[0]


def _pair_index(pi, pu, C, i, u):
    """Positions of the (instance, column) pairs ``(i, u)`` in the sorted unique ``(pi, pu)``."""
    return np.searchsorted(pi * C + pu, np.asarray(i) * C + np.asarray(u))


#: local rows of a reader's residual that a channel can move: its I and J markers (the force
#: acts on their bodies only; R and the further markers its expressions read carry no force)
_READER_ROWS = 12


def _reader_dreaction(f, kin, pi, pu, rgrads):
    """(P, 12) local residual (I and J rows, :data:`_READER_ROWS`) of reader family ``f``'s
    instance ``pi[p]`` per unit change of the reaction channel in its local column ``pu[p]``
    (the force law is linear in (F, T) at fixed slots: rho(dF/dc, dT/dc)); ``rgrads`` the
    family's ``d_reaction`` at this iterate."""
    dFs, dTs = f.scalar_chain(kin.Y, rgrads)                        # (n, 3, C) each
    sub = SlotKinematics(kin.Y[pi], kin.V[pi], kin.pt[pi], kin.slot_ml, kin.K)
    drho = apply_two_body(sub.Y, dFs[pi, :, pu], dTs[pi, :, pu], None, None,
                          f.action_only[pi], False)[0]
    r = local_residual_tangent(sub, drho, None, f.slot_ml, f.K, False, None, 0)[0]
    return r[:, :_READER_ROWS]


def _action_derivatives(g, kin, rho, phy, G, ext, js, qc, need_f):
    """The action on I of family ``g``'s instances ``js`` (F at the I origin, T) and its
    derivatives, stacked ``(F, T)``: ``d/d lambda`` (len(js), 6, m) (constraints, else None),
    ``d/d x`` (len(js), 6, len(qc)) at fixed multipliers w.r.t. the instance's local
    coordinates ``qc`` (of 6K + U; None when empty) and ``F`` (len(js), 3) (``need_f``, else
    None).

    ``F = -sum rho_s`` over I's point slots, ``T = -sum y_s x rho_s`` over I's axis slots. With
    ``d rho = G dy + G_ys ds`` (``G`` the family's ``d rho / d y``: for constraints the
    multiplier-weighted Hessian) and ``dy = B dx`` (the slot map): ``dF = -(G B)_s``,
    ``dT = rho_s x (B_s dx) - y_s x (G B)_s``."""
    n, S = len(js), len(g.slot_ml)
    ml = np.asarray(g.slot_ml)
    on_i = np.nonzero(ml == 0)[0]
    pt = kin.pt[js]
    dl = dq = F = None
    if phy is not None:
        dl = np.concatenate(_constraint_dlam(g, kin, phy, js), axis=1)
    if need_f or len(qc):
        rho3 = rho[js].reshape(n, S, 3)
    if need_f:
        F = np.zeros((n, 3))
        for s in on_i:
            F -= rho3[:, s] * pt[:, s, None]
    if len(qc):
        Y = kin.Y[js]
        K6 = 6 * g.K
        L = K6 + g.U
        sub = SlotKinematics(Y, kin.V[js], pt, kin.slot_ml, kin.K)
        B = sub.B                                                        # (n, 3S, 6K)
        rows = (3 * on_i[:, None] + np.arange(3)).ravel()
        GB = np.zeros((n, len(rows), L))                                 # (G B)_s, s on I
        if G is not None:
            GB[:, :, :K6] = np.matmul(dense_g(G, js)[:, rows], B)
        gys = None if ext is None else ext.get("G_ys")
        if gys is not None and g.U:
            GB[:, :, K6:] = gys[js[:, None], rows]
        dq = np.zeros((n, 6, L))
        for k, s in enumerate(on_i):
            blk = GB[:, 3 * k:3 * k + 3]                                 # (n, 3, L)
            p = pt[:, s]
            if p.any():
                dq[p, :3] -= blk[p]
            a = ~p
            if a.any():
                dq[a, 3:, :K6] += np.matmul(skew(rho3[a, s]), B[a, 3 * s:3 * s + 3])
                dq[a, 3:] -= np.matmul(skew(Y[a, s]), blk[a])
        dq = dq[:, :, qc]
    return dl, dq, F


def _constraint_dlam(g, kin, phy, js):
    """``d F / d lambda``, ``d T / d lambda`` (len(js), 3, m) of constraint family ``g``'s
    instances ``js``: the action on I (at the I origin) is linear in the multipliers,
    F = -sum phi_y^T lam over I's point slots, T = -sum y x (phi_y^T lam) over I's axis slots."""
    Y = kin.Y[js]
    ph = phy[js]
    n, m = len(js), phy.shape[1]
    dF = np.zeros((n, 3, m))
    dT = np.zeros((n, 3, m))
    for s in range(len(g.slot_ml)):
        if g.slot_ml[s] != 0:
            continue
        blk = np.swapaxes(ph[:, :, 3 * s:3 * s + 3], 1, 2)              # (n, 3, m)
        pt = g.slot_kind[js, s] == 0
        if pt.any():
            dF[pt] -= blk[pt]
        ax = ~pt
        if ax.any():
            dT[ax] -= np.cross(Y[ax, s][:, :, None], blk[ax], axis=1)
    return dF, dT
