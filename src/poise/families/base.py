"""The element-family contract and the generic marker-slot kinematics kernel.

Every element acts on bodies through *markers*. A family instance reads a fixed list of
**slots**: 3-vectors attached to one of its markers, either the marker origin ``P`` (kind 0) or one
of its axes ``x, y, z`` (kinds 1, 2, 3), all in global components. A family only has to express
its physics as a function of the slot vectors ``y`` (shape ``(n, 3S)``):

* force families return ``rho = -w`` where ``w`` is the generalised force work-conjugate to the
  slot vectors (for a force ``F`` applied at marker origin slot ``s``: ``rho_s = -F``; for a torque
  ``T`` applied through the three axes ``a_c`` of a marker: ``rho_c = -T x a_c / 2``), and its
  derivative ``G = d rho / d y``, shape ``(n, 3S, 3S)``;
* constraint families return ``phi`` (n, m), ``phi_y = d phi / d y`` (n, m, 3S) and the
  multiplier-weighted Hessian ``G = sum_r lam_r d2 phi_r / d y2`` (n, 3S, 3S); their
  ``rho = phi_y^T lam``.

The kernel maps slots to the 6 local coordinates of each marker's body: a translation ``dr`` and a
spatial rotation increment ``dtheta`` (``R <- expm(skew(dtheta)) R``). For a point slot with
lever ``v = P - r_body``: ``dP = dr - v x dtheta``; for an axis ``a``: ``da = -a x dtheta``. The
local residual is ``B^T rho`` and the local tangent is ``B^T G B + C`` where ``C`` is the
connection term from rotating levers/axes, ``C_thth += v rho_s^T - (v . rho_s) I`` per slot. This
gives the complete Newton Jacobian (including the geometric stiffness of constraint reactions,
d(Phi_q^T lam)/dq) for every family from first principles.

Residual sign: the global residual is ``Phi_q^T lam - Q`` (internal minus applied), so a stable
spring contributes a positive-definite tangent.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from poise.model.rotation import skew

POINT, AX_X, AX_Y, AX_Z = 0, 1, 2, 3

_I3 = np.eye(3)


@dataclass
class SlotKinematics:
    """Slot vectors and their maps to local body coordinates for n instances.

    Attributes
    ----------
    Y : (n, S, 3) slot vectors (global)
    B : (n, 3S, 6K) d y / d local coordinates
    V : (n, S, 3) lever (point slots) or axis (axis slots) used by the connection term
    """

    Y: np.ndarray
    B: np.ndarray
    V: np.ndarray


def slot_kinematics(markers, slot_ml, slot_kind, P, A, marker_body, body_pos) -> SlotKinematics:
    """Evaluate slot vectors and their B-matrices.

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
    """
    n, K = markers.shape
    S = len(slot_ml)
    mk = markers[:, slot_ml]                                   # (n, S)
    kind = slot_kind
    Pm = P[mk]                                                 # (n, S, 3)
    ax = np.clip(kind - 1, 0, 2)
    Am = A[mk, :, ax]                                          # (n, S, 3): column ax
    is_pt = (kind == POINT)[..., None]
    Y = np.where(is_pt, Pm, Am)
    bodies = marker_body[mk]
    lever = Pm - body_pos[np.maximum(bodies, 0)]
    V = np.where(is_pt, lever, Am)
    B = np.zeros((n, 3 * S, 6 * K))
    sk = -skew(V)                                              # (n, S, 3, 3)
    for s in range(S):
        k = slot_ml[s]
        rows = slice(3 * s, 3 * s + 3)
        pt = kind[:, s] == POINT
        if pt.any():
            B[pt, rows, 6 * k:6 * k + 3] = _I3
        B[:, rows, 6 * k + 3:6 * k + 6] = sk[:, s]
    return SlotKinematics(Y=Y, B=B, V=V)


def local_residual_tangent(kin: SlotKinematics, rho: np.ndarray, G: np.ndarray | None,
                           slot_ml, K: int, need_jac: bool = True, ext: dict | None = None,
                           U: int = 0):
    """Local residual ``[B^T rho; rho_s]`` (n, 6K+U) and tangent (n, 6K+U, 6K+U).

    The marker block of the tangent is ``B^T G B + C``. With ``U`` scalar columns (extra unknowns
    the family reads), ``ext`` may hold ``rho_s`` (n, U) (residual rows of the scalar unknowns
    the family owns or its generalised forces on them), ``G_ys`` (n, 3S, U) = d rho / d s,
    ``G_sy`` (n, U, 3S) = d rho_s / d y and ``G_ss`` (n, U, U); missing pieces are zero.
    """
    B = kin.B
    n = B.shape[0]
    r = np.einsum("nyi,ny->ni", B, rho)
    ext = ext or {}
    if U:
        rs = ext.get("rho_s")
        r = np.concatenate([r, np.zeros((n, U)) if rs is None else rs], axis=1)
    if not need_jac:
        return r, None
    if G is None:
        Kl = np.zeros((n, 6 * K, 6 * K))
    else:
        Kl = np.matmul(np.swapaxes(B, 1, 2), np.matmul(G, B))
    S = kin.V.shape[1]
    rho3 = rho.reshape(n, S, 3)
    for s in range(S):
        k = slot_ml[s]
        v = kin.V[:, s]
        w = rho3[:, s]
        blk = v[:, :, None] * w[:, None, :]
        d = np.einsum("ni,ni->n", v, w)
        blk[:, 0, 0] -= d
        blk[:, 1, 1] -= d
        blk[:, 2, 2] -= d
        Kl[:, 6 * k + 3:6 * k + 6, 6 * k + 3:6 * k + 6] += blk
    if U:
        full = np.zeros((n, 6 * K + U, 6 * K + U))
        full[:, :6 * K, :6 * K] = Kl
        if ext.get("G_ys") is not None:
            full[:, :6 * K, 6 * K:] = np.matmul(np.swapaxes(B, 1, 2), ext["G_ys"])
        if ext.get("G_sy") is not None:
            full[:, 6 * K:, :6 * K] = np.matmul(ext["G_sy"], B)
        if ext.get("G_ss") is not None:
            full[:, 6 * K:, 6 * K:] = ext["G_ss"]
        Kl = full
    return r, Kl


@dataclass
class Family:
    """Base class of element families (vectorised over ``n`` instances).

    Subclasses set the class attributes and implement :meth:`forces` (force families) or
    :meth:`constraints` (constraint families).

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
    gcol : (n, 6K + U) int
        Global coordinate index of each local coordinate, -1 where the body has none (set by the
        compiler); the last U columns are the scalar unknowns of ``scols``.
    scols : (n, U) int or None
        Indices (into ``State.extra``) of the scalar unknowns each instance reads (-1 = none).
    crow : (n, m) int
        Global constraint row of each instance row (set by the compiler).
    """

    name: str
    markers: np.ndarray
    slot_ml: np.ndarray
    slot_kind: np.ndarray
    owner: np.ndarray
    m: int = 0
    gcol: np.ndarray = field(default=None, repr=False)
    crow: np.ndarray = field(default=None, repr=False)
    row_names: tuple = ()
    scols: np.ndarray = field(default=None, repr=False)

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

    def depends_on_time(self) -> bool:
        return False


class ForceFamily(Family):
    """Force families implement ``forces(kin, ctx, need_jac) -> (rho (n,3S), G (n,3S,3S) or
    None[, ext])``; ``ext`` (families with scalar columns) as in :func:`local_residual_tangent`."""

    def forces(self, kin: SlotKinematics, ctx) -> tuple[np.ndarray, np.ndarray | None]:
        raise NotImplementedError


class ConstraintFamily(Family):
    """Constraint families implement ``constraints(kin, lam, ctx) -> (phi, phi_y, G[, ext])``.

    ``lam`` has shape (n, m); ``phi`` (n, m); ``phi_y`` (n, m, 3S); ``G`` (n, 3S, 3S) or None.
    Families with scalar columns may return ``ext`` with ``phi_s`` (n, m, U) = d phi / d s and
    the multiplier-weighted Hessian blocks ``G_ys`` (n, 3S, U) and ``G_ss`` (n, U, U)
    (``G_sy`` defaults to the transpose of ``G_ys``); ``rho_s = phi_s^T lam`` is added by the
    model.
    """

    def constraints(self, kin: SlotKinematics, lam: np.ndarray, ctx):
        raise NotImplementedError

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
    ``dT`` (n, 3, 3S) is dT/dy or None.
    """
    for s in axis_slots:
        a = Y[:, s]
        rows = slice(3 * s, 3 * s + 3)
        rho[:, rows] += 0.5 * np.cross(a, T)
        if G is not None:
            if dT is not None:
                G[:, rows, :] += 0.5 * np.matmul(skew(a), dT)
            G[:, rows, rows] += -0.5 * skew(T)
