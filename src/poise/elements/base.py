"""The element-family contract: what every element kernel computes from its marker slots.

Every element acts on bodies through *markers*. A family instance reads a fixed list of
**slots**: 3-vectors attached to one of its markers, either the marker origin ``P`` (kind 0) or one
of its axes ``x, y, z`` (kinds 1, 2, 3), all in global components, ``y`` (shape ``(n, 3S)``):

* force families return ``rho = -w``, ``w`` the generalised force work-conjugate to the slots
  (a force ``F`` at origin slot ``s``: ``rho_s = -F``; a torque ``T`` through the three axes
  ``a_c`` of a marker: ``rho_c = -T x a_c / 2``), and ``G = d rho / d y`` (n, 3S, 3S);
* constraint families return ``phi`` (n, m), ``phi_y`` (n, m, 3S) and the multiplier-weighted
  Hessian ``G = sum_r lam_r d2 phi_r / d y2``; their ``rho = phi_y^T lam``.

:mod:`poise.elements.kernel` maps slots to body coordinates. Residual sign: the global residual
is ``Phi_q^T lam - Q`` (internal minus applied), so a stable spring has a positive tangent.
"""
from __future__ import annotations

from dataclasses import FrozenInstanceError, dataclass, field
from typing import ClassVar

import numpy as np

from poise.elements.kernel import SlotKinematics, cross3
from poise.elements.rotation import skew

GLOBAL = 0  # compiled marker index of the global frame (marker id 0)


@dataclass(frozen=True, eq=False, kw_only=True)
class Family:
    """Base class of element families (vectorised over ``n`` instances), immutable.

    A family is built once, with every field its class declares (scikit-fem style: a kernel's
    parameters are dataclass fields of its class, never attributes added later); the model
    compiler completes the layout fields with :func:`dataclasses.replace`. Subclasses declare
    their parameters and implement :meth:`forces` (force families) or :meth:`constraints`
    (constraint families).

    Attributes
    ----------
    name : str
        Effect name listed in the results' ``active_effects``.
    markers : (n, K) int
        Marker indices per instance.
    slot_ml : (S,) int
        Marker (0..K-1) read by each slot.
    slot_kind : (n, S) int
        Slot kinds per instance.
    owner : (n,) int
        Index of the owning deck element in its output group (joints, forces, ...).
    m : int
        Constraint rows per instance (0 for force families).
    crow : (n, m) int
        Global constraint row of each instance row.
    scols : (n, U) int or None
        Indices (into ``State.extra``) of the scalar unknowns each instance reads (-1 = none).
    row_names : tuple
        Names of the rows (user constraints).
    group : str or None
        The output group ``owner`` indexes (``joints``, ``forces``, ...).
    element_locs : tuple of SourceLoc
        The deck element of each instance (messages).
    reads_reactions : bool
        The family's expressions read reaction channels (:mod:`poise.elements.reaction_feed`).
    gcol : (n, 6K + U) int
        Global coordinate index of each local coordinate, -1 where the body has none (model
        layout); the last U columns are the scalar unknowns of ``scols``.
    pattern : poise.elements.kernel.LocalPattern
        Static structure of the local tangent (model layout).
    """

    name: str
    markers: np.ndarray
    slot_ml: np.ndarray
    slot_kind: np.ndarray
    owner: np.ndarray
    m: int = 0
    crow: np.ndarray | None = field(default=None, repr=False)
    scols: np.ndarray | None = field(default=None, repr=False)
    row_names: tuple = ()
    group: str | None = None
    element_locs: tuple = field(default=(), repr=False)
    reads_reactions: bool = False
    gcol: np.ndarray | None = field(default=None, repr=False)
    pattern: object = field(default=None, repr=False)

    #: evaluated after every other family (``Model.eval_order``; gravity's uniform load)
    eval_last: ClassVar[bool] = False

    @property
    def U(self) -> int:
        """Number of scalar-unknown columns per instance."""
        return 0 if self.scols is None else int(self.scols.shape[1])

    @property
    def n(self) -> int:
        return self.markers.shape[0]

    @property
    def K(self) -> int:
        return self.markers.shape[1]

    @property
    def is_constraint(self) -> bool:
        return self.m > 0

    def g_blocks(self):
        """Static structure of ``G``: (S, S) bool array of the slot-pair 3x3 blocks of ``G`` that
        can be non-zero (all False: ``G`` is always None or zero), or None (the default): ``G``
        may be dense. Declaring it lets the kernel skip zero blocks and keeps structural zeros
        out of the sparse KKT pattern; a block returned non-zero outside the declaration would
        be dropped, so declare conservatively."""
        return None

    def phi_y_mask(self):
        """Static structure of ``phi_y`` (constraint families): (m, 3S) bool array of the entries
        that can be non-zero, or None (the default): dense."""
        return None

    def zero_lever(self):
        """(S,) bool array of the point slots at their body's reference point (the CG marker:
        a lever of exactly zero), whose connection term ``v rho^T - (v . rho) I`` is zero: not
        formed and kept out of the sparse KKT pattern; or None (the default): every slot may
        have a lever."""
        return None

    def tile_fields(self, F: int, model) -> dict:
        """Fields of the copy covering ``F`` frames besides the per-instance arrays the frame
        tiler repeats (:mod:`poise.model.frame_batch`; tileable kernels only)."""
        return {}


def _refuse_set(self, name, value):
    raise FrozenInstanceError(f"cannot assign to {name!r}: element families are immutable "
                              "(build a new one with dataclasses.replace)")


def _refuse_del(self, name):
    raise FrozenInstanceError(f"cannot delete {name!r}: element families are immutable")


# A frozen dataclass refuses only its declared fields on instances of undecorated subclasses
# (e.g. ``Gear(Coupler)``): every other assignment ends here and is refused too.
Family.__setattr__ = _refuse_set
Family.__delattr__ = _refuse_del


class ForceFamily(Family):
    """Force families implement ``forces(kin, ctx, need_jac) -> (rho (n,3S), G (n,3S,3S) or
    None[, ext])``; ``ext`` (families with scalar columns) as in :func:`local_residual_tangent`."""

    def forces(self, kin: SlotKinematics, ctx) -> tuple[np.ndarray, np.ndarray | None]:
        raise NotImplementedError


class ConstraintFamily(Family):
    """Constraint families implement ``constraints(kin, lam, ctx) -> (phi, phi_y, G[, ext])``.

    ``lam`` has shape (n, m); ``phi`` (n, m); ``phi_y`` (n, m, 3S); ``G`` (n, 3S, 3S), a
    compact :class:`~poise.elements.kernel.PairBlocks` (identity-multiple slot-pair blocks:
    nothing dense is built for a residual-only evaluation) or None.
    Families with scalar columns may return ``ext`` with ``phi_s`` (n, m, U) = d phi / d s and
    the multiplier-weighted Hessian blocks ``G_ys`` (n, 3S, U) and ``G_ss`` (n, U, U)
    (``G_sy`` defaults to the transpose of ``G_ys``); ``rho_s = phi_s^T lam`` is added by the
    model.
    """

    def constraints(self, kin: SlotKinematics, lam: np.ndarray, ctx):
        raise NotImplementedError

    def values(self, kin: SlotKinematics, ctx) -> np.ndarray:
        """``phi`` (n, m) alone (projections onto the constraints evaluate nothing else);
        families whose derivatives are costly override it."""
        return self.constraints(kin, np.zeros((self.n, self.m)), ctx)[0]

    def phi_t(self, kin: SlotKinematics, ctx) -> np.ndarray | None:
        """d phi / d t, (n, m); None when the constraint does not depend on time."""
        return None


def add_force_at_point(rho, G, s, F, dF):
    """Apply force ``F`` (n,3) at the point slot ``s``: ``rho_s -= F``; ``G_s,: -= dF`` (n,3,3S)."""
    rho[:, 3 * s:3 * s + 3] -= F
    if G is not None and dF is not None:
        G[:, 3 * s:3 * s + 3, :] -= dF


def add_torque_via_axes(rho, G, axis_slots, T, dT, Y):
    """Apply torque ``T`` (n,3) to the body carrying the three axis slots ``axis_slots``.

    Uses ``rho_c = -T x a_c / 2 = (a_c x T)/2`` so that ``sum_c a_c x w_c = T``.
    ``dT`` (n, 3, 3S) is dT/dy or None. Consecutive slots (the two-body layout) are done in
    one product each (the same values as axis by axis).
    """
    s0 = axis_slots[0]
    if tuple(axis_slots) != (s0, s0 + 1, s0 + 2):
        for s in axis_slots:
            _torque_rows(rho, G, slice(3 * s, 3 * s + 3), Y[:, s], T, dT)
        return
    n = len(T)
    rows = slice(3 * s0, 3 * s0 + 9)
    _torque_rows(rho, G, rows, Y[:, s0:s0 + 3], T[:, None], None if dT is None else dT[:, None],
                 (n, 9))
    if G is not None:
        hT = -0.5 * skew(T)                                 # the same for the three axes
        for k in range(3):
            r = slice(3 * (s0 + k), 3 * (s0 + k) + 3)
            G[:, r, r] += hT


def _torque_rows(rho, G, rows, a, T, dT, shape=None):
    """``a x T / 2`` on ``rho[:, rows]`` and ``skew(a) dT / 2`` on ``G[:, rows]`` (one axis
    ``a`` (n, 3), or three stacked (n, 3, 3) with ``shape`` their flat rows); one axis alone
    also adds its ``-skew(T) / 2`` block."""
    c = 0.5 * cross3(a, T)
    rho[:, rows] += c if shape is None else c.reshape(shape)
    if G is None:
        return
    if dT is not None:
        m = 0.5 * np.matmul(skew(a), dT)
        G[:, rows, :] += m if shape is None else m.reshape(shape + (m.shape[-1],))
    if shape is None:
        G[:, rows, rows] += -0.5 * skew(T)


def column_map(index, cols):
    """Map per-instance global indices to per-instance local columns (compile time).

    ``index`` (n, C) holds global indices (negative = unused); ``cols`` is a list of n dicts
    ``global -> local column`` extended in place (first use gets the next column). Returns the
    ``(rows, c, local)`` int arrays of every used entry.
    """
    rows, cs, fs = [], [], []
    for i in range(len(cols)):
        d = cols[i]
        for c, k in enumerate(index[i]):
            k = int(k)
            if k < 0:
                continue
            if k not in d:
                d[k] = len(d)
            rows.append(i)
            cs.append(c)
            fs.append(d[k])
    ip = np.intp
    return np.array(rows, ip), np.array(cs, ip), np.array(fs, ip)


def columns_array(cols, width=None, fill=-1):
    """(n, width) array with ``out[i, local] = global`` from the dicts of :func:`column_map`."""
    width = max((len(d) for d in cols), default=0) if width is None else width
    out = np.full((len(cols), width), fill, int)
    for i, d in enumerate(cols):
        for k, c in d.items():
            out[i, c] = k
    return out
