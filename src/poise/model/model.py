"""The compiled model (flat arrays + index maps) and the solver state.

Coordinates: each moving rigid body has 6 tangent coordinates (translation of its CG marker
origin, then a spatial rotation increment), each point body 3; ground has none. The
configuration itself is stored on the rotation group (``State.rot``), so there is no singular
parametrisation and any number of full turns is possible; continuous relative angles (AZ etc.)
are tracked in ``State.angle`` by unwrapping along the solution path.
Evaluation (residual, Jacobian, constraints, energy; one or many frames) is the engine of
:mod:`poise.model.evaluate`.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from poise.core import per_object
from poise.core.lean import concatenate, einsum, row_norms
from poise.model.assembly import Assembler
from poise.model.evaluate import Evaluation, evaluate, jacobian
from poise.elements.chunked import CHUNK
from poise.elements.kernel import cross3
from poise.elements.rotation import (lift_rotation_vector, rotation_vector, screw_exp,
                                     wrap_angle)

MAX_SUBSTEP_ROTATION = np.pi / 4   # rad; larger rotation updates are applied in sub-steps
DENSE_MAX = 600                    # KKT size up to which dense LU is used

_I3 = np.eye(3)
_I3.flags.writeable = False
_GROUND_MARKERS = per_object.table()     # model -> the markers on the ground
_MARKER_ROWS = per_object.table()        # model -> Model._marker_rows()
_RIGID_BLOCKS = per_object.table()       # model -> Model.rigid_blocks()

@dataclass
class State:
    """Configuration and multipliers.

    Attributes
    ----------
    pos : (nb, 3) CG marker origins of moving bodies [length]
    rot : (nb, 3, 3) CG marker axes as columns [-]
    lam : (nc,) constraint multipliers (forces [force] / torques [force*length])
    angle : (na,) continuous relative angles of the model's angle table [rad]
    t : float analysis time
    extra : (ne,) scalar unknowns (Control_Diff states, implicit variables, curve and surface
        parameters, ...), the last ``ne`` tangent coordinates
    rotvec : (nb, 3) rotation of each body from its input orientation as a continuous rotation
        vector (``rot = expm(rotvec) init_rot``, full turns counted; Model.track_rotation)
    """

    pos: np.ndarray
    rot: np.ndarray
    lam: np.ndarray
    angle: np.ndarray
    t: float = 0.0
    extra: np.ndarray = None
    rotvec: np.ndarray = None
    rotvec_drift: float = 0.0      # rotation [rad] applied since rotvec was last made exact

    def copy(self) -> "State":
        return State(self.pos.copy(), self.rot.copy(), self.lam.copy(), self.angle.copy(), self.t,
                     None if self.extra is None else self.extra.copy(),
                     None if self.rotvec is None else self.rotvec.copy(), self.rotvec_drift)


@dataclass(frozen=True, eq=False, kw_only=True)
class Model:
    """Compiled model, immutable: built in one step by :func:`poise.model.layout.build_model`
    (from :func:`poise.model.compile.compile_model`), every array read-only (MuJoCo's
    ``mjModel``/``mjData`` split: what a solve changes lives in the solve's data and workspace,
    :class:`poise.model.workspace.Workspace`).

    Attributes (n* sizes: nb moving bodies, nm markers (index 0 = global frame), nc rows)
    ----------
    body_id, body_label : (nb,) deck ids and labels of moving bodies (labels: a sequence of str,
        :class:`poise.elements.rows.Texts`)
    body_kind : (nb,) 0 rigid, 1 point
    body_mass : (nb,) effective mass (deck mass x units factor) [force*time^2/length]
    body_inertia : (nb, 3, 3) inertia about the CG in the body (CG marker) frame, effective
    mass_factor : the units factor; shown/written masses are ``body_mass / mass_factor``
    body_off : (nb,) first tangent coordinate of each body
    marker_id : (nm,); marker_body : (nm,) moving-body index or nb for ground
    marker_s0 : (nm, 3) origin in the body frame (ground: global)
    marker_A0 : (nm, 3, 3) axes in the body frame (ground: global)
    families : tuple of Family (laid out: ``gcol``, ``pattern``)
    nq, nc, nb, N : sizes (N = nq + nc, the KKT size)
    row_info : tuple of dict per constraint row (tag, id, equation, line, kind 'trans'|'rot')
        (a :class:`poise.elements.rows.RowTable`: a sequence of those dicts, made on access)
    angle_I, angle_J, angle_axis : (na,) continuous-angle table
    L : model length scale [length]
    time_sources : deck places through which the solution depends on time (from the element
        types' ``time_dependent``, :func:`poise.elements.registry.time_sources`)
    energy_terms : ``(family index, potential_energy)`` the energy pass sums (the element
        types' declarations, :func:`poise.elements.registry.energy_terms`)
    assembler : the fixed-pattern KKT assembler; dense : N <= DENSE_MAX
    small : the dense slot pass of a small model (:mod:`poise.model.small_dense`) or None
    trans_idx, rot_idx, rot_body, extra_idx, extra_off, q_kind, q_scale, body_scale, row_kind :
        coordinate and row index maps (:func:`poise.model.layout.build_model`)
    eval_order : family evaluation order (reaction readers after the others, gravity last)
    """

    body_id: np.ndarray
    body_label: Sequence
    body_kind: np.ndarray
    body_mass: np.ndarray
    body_inertia: np.ndarray
    body_off: np.ndarray
    marker_id: np.ndarray
    marker_body: np.ndarray
    marker_s0: np.ndarray
    marker_A0: np.ndarray
    families: tuple
    nq: int
    nc: int
    row_info: tuple
    angle_I: np.ndarray
    angle_J: np.ndarray
    angle_axis: np.ndarray
    L: float
    init_pos: np.ndarray
    init_rot: np.ndarray
    active_effects: tuple = ()
    outputs: dict
    coord_info: tuple = ()
    units: str = ""
    frame_hooks: tuple = ()
    n_extra: int = 0
    extra0: np.ndarray
    extra_names: tuple = ()
    reaction_feed: object = None     # ReactionFeed: reaction channels read by forces, else None
    time_sources: tuple = ()         # what reads TIME (see above)
    energy_terms: tuple = ()         # (family index, declared potential_energy) (registry)
    mass_factor: float = 1.0         # body_mass = deck mass x mass_factor (poise.model.units)
    spec_warnings: tuple = ()        # compile warnings (poise.core.errors.Problem)
    user_routines: tuple = ()        # Python user routines the deck names (described)
    input_files: dict                # script path -> SHA-256
    # derived (poise.model.layout.build_model)
    nb: int
    N: int
    dense: bool
    trans_idx: np.ndarray
    rot_body: np.ndarray
    rot_idx: np.ndarray
    extra_off: int
    extra_idx: np.ndarray
    q_kind: np.ndarray
    assembler: Assembler
    body_scale: np.ndarray
    q_scale: np.ndarray
    row_kind: np.ndarray
    eval_order: tuple
    small: object = None             # SmallDense tables (poise.model.small_dense) or None

    # ------------------------------------------------------------------ state
    def initial_state(self, t: float = 0.0) -> State:
        st = State(self.init_pos.copy(), self.init_rot.copy(), np.zeros(self.nc),
                   np.zeros(len(self.angle_I)), t, np.array(self.extra0, float).copy(),
                   np.zeros((self.nb, 3)))
        if len(self.angle_I):
            st.angle = self._principal_angles(st)
        return st

    def _ext(self, state):
        """Positions (nb + 1, 3), the ground's last (zero): read at a marker's body index, -1
        for the ground."""
        pos = np.zeros((self.nb + 1, 3))
        pos[:self.nb] = state.pos
        return pos

    def marker_kinematics(self, state):
        """Marker origins (nm,3) and axes (nm,3,3) in global components."""
        pos, rot = self._ext(state), state.rot
        mb = self.marker_body
        nm = len(mb)
        if nm <= 2 * CHUNK:
            # gathered once for both products, the ground's identity appended (one gather)
            R = concatenate((rot, _I3[None])).take(self._marker_rows(), 0)
            P = pos.take(mb, 0) + einsum("nij,nj->ni", R, self.marker_s0)
            A = np.matmul(R, self.marker_A0)
            return P, A, pos
        # many markers: the same products chunk by chunk (no full-size temporaries)
        P, A = np.empty((nm, 3)), np.empty((nm, 3, 3))
        for a in range(0, nm, CHUNK):
            b = min(a + CHUNK, nm)
            R = self._marker_rot(rot, mb[a:b], a)
            P[a:b] = pos.take(mb[a:b], 0) + np.einsum("nij,nj->ni", R, self.marker_s0[a:b])
            A[a:b] = np.matmul(R, self.marker_A0[a:b])
        return P, A, pos

    def _marker_rows(self) -> np.ndarray:
        """Each marker's row in the bodies' rotations with the identity appended (ground's
        markers: the last row), made once per model."""
        return per_object.once_per(_MARKER_ROWS, self, lambda: np.where(
            (self.marker_body < 0) | (self.marker_body >= self.nb), self.nb, self.marker_body))

    def _marker_rot(self, rot, mb, at: int):
        """The rotations of the markers ``mb`` (body indices, the ground's -1 or ``nb``;
        markers ``at`` on): the bodies' ``rot`` (nb, 3, 3) gathered, the ground's rows the
        identity, as a gather from the extended array (ground last) would give, without that
        copy of every rotation."""
        R = rot.take(mb, 0, mode="clip") if len(rot) else np.empty((len(mb), 3, 3))
        g = per_object.once_per(_GROUND_MARKERS, self, lambda: np.flatnonzero(
            (self.marker_body < 0) | (self.marker_body >= self.nb)))
        if at or len(mb) < len(self.marker_body):     # a chunk: its own ground markers
            g = g[(g >= at) & (g < at + len(mb))] - at
        R[g] = _I3
        return R

    def _principal_angles(self, state):
        return self._angles_of(state.rot)

    def _angles_of(self, rot):
        """The angle table's principal angles (..., na) for body rotations ``rot`` (..., nb,
        3, 3), from the axes of its own markers only (the same products as
        :meth:`marker_kinematics` for those markers)."""
        I, J = self.angle_I, self.angle_J
        na = len(I)
        mk = np.concatenate([I, J])
        mb = self.marker_body[mk]
        ground = np.broadcast_to(np.eye(3), rot.shape[:-3] + (1, 3, 3))
        A = np.matmul(np.concatenate([rot, ground], axis=-3)[..., mb, :, :], self.marker_A0[mk])
        return principal_angles(A, np.arange(na), np.arange(na, 2 * na), self.angle_axis)

    def retract(self, state: State, dq: np.ndarray, dlam: np.ndarray | None = None) -> State:
        """New state ``state (+) dq`` on the configuration manifold.

        Rotation increments larger than ``MAX_SUBSTEP_ROTATION`` are applied in equal sub-steps
        so that continuous angles count every full turn.
        """
        if self.nb and len(self.rot_body) == self.nb:
            # every body rigid: positions and axes are new arrays below, so are the
            # multipliers with ``dlam`` and the tracked rotation vectors (no copies made first)
            new = State(state.pos, state.rot, state.lam if dlam is not None else state.lam.copy(),
                        state.angle.copy(), state.t,
                        None if state.extra is None else state.extra.copy(), state.rotvec,
                        state.rotvec_drift)
        else:
            new = state.copy()
        dq = np.asarray(dq, float)
        dt, dr = self.coord_parts(dq)
        nsub = 1
        if len(self.angle_I) and len(dr):
            nsub = max(1, int(np.ceil(float(np.max(row_norms(dr))) / MAX_SUBSTEP_ROTATION)))
        rb = self.rot_body
        # rigid bodies move along the screw of the spatial twist (w, v0), v0 = dr_cg - w x r_cg:
        # a rotation about any fixed point (a hinge) is then followed exactly, for any angle.
        # (x / 1 is x: one step divides nothing)
        w = dr / nsub if nsub > 1 else dr
        every = len(rb) == self.nb           # every body rigid: rb is 0..nb-1, no gathers
        v0 = ((dt if every else dt[rb]) - cross3(dr, state.pos if every else state.pos[rb])
              if len(rb) else np.zeros((0, 3)))
        if nsub > 1:
            v0 = v0 / nsub
        E, V = screw_exp(w)
        Vv = einsum("nij,nj->ni", V, v0)
        move_pt = len(rb) < self.nb          # rot_body: distinct bodies
        if move_pt:
            pt = np.ones(self.nb, bool)
            pt[rb] = False
        na = len(self.angle_I)
        rots = np.empty((nsub,) + new.rot.shape) if na else None
        if na:
            rots[:] = new.rot               # point bodies keep their axes; rows rb set below
        dtp = dt[pt] / nsub if move_pt else None
        # the rigid bodies' CGs and axes, sub-step by step (new arrays each step)
        p, R = (new.pos, new.rot) if every else (new.pos[rb], new.rot[rb])
        for k in range(nsub):
            if move_pt:
                new.pos[pt] += dtp
            if len(rb):
                p = einsum("nij,nj->ni", E, p) + Vv
                R = np.matmul(E, R)
                if na:
                    rots[k, rb] = R
        if every:
            new.pos, new.rot = p, R
        elif len(rb):
            new.pos[rb], new.rot[rb] = p, R
        if na:             # principal angles of every sub-step at once, unwrapped in turn
            ang = new.angle
            for p in self._angles_of(rots):
                ang = ang + wrap_angle(p - ang)
            new.angle = ang
        if self.n_extra:
            new.extra = new.extra + dq[self.extra_idx]
        if dlam is not None:
            new.lam = new.lam + dlam
        self.track_rotation(new, state, dr)
        return new

    def rigid_blocks(self) -> bool:
        """Every body rigid, its six coordinates (translation, rotation) the ``6 b`` to
        ``6 b + 5``: a tangent vector's translations and rotations are then strided views of
        its first ``6 nb`` entries (no index gathers or scatters)."""
        return per_object.once_per(_RIGID_BLOCKS, self, lambda: (
            len(self.rot_body) == self.nb
            and np.array_equal(self.trans_idx, (6 * np.arange(self.nb)[:, None]
                                                + np.arange(3)).ravel())
            and np.array_equal(self.rot_idx, np.asarray(self.trans_idx) + 3)))

    def coord_parts(self, v: np.ndarray) -> tuple:
        """``(v[trans_idx].reshape(-1, 3), v[rot_idx].reshape(-1, 3))``: the translations
        (nb, 3) and rotations (nr, 3) of a tangent vector, new arrays."""
        if self.rigid_blocks():
            v6 = v[:6 * self.nb].reshape(self.nb, 6)
            return v6[:, :3].copy(), v6[:, 3:].copy()
        return (v[self.trans_idx].reshape(-1, 3),
                v[self.rot_idx].reshape(-1, 3) if len(self.rot_idx) else np.zeros((0, 3)))

    def track_rotation(self, new: State, old: State, w: np.ndarray) -> None:
        """Carry ``rotvec`` from ``old`` to ``new`` (``w``: the spatial rotation increments of
        the rigid bodies between them): ``old.rotvec + w`` (one addition per update), made exact
        (:meth:`rotation_from_input`) once the increments since the last exact value exceed
        pi/2 rad: the signed length of ``old.rotvec + w`` follows the rotation angle to first
        order for any increment, so the turn count it picks (2 pi apart) stays right."""
        rb = self.rot_body
        if old.rotvec is None or not len(rb):
            return
        if len(rb) == self.nb:
            rv = old.rotvec + w
        else:
            rv = old.rotvec.copy()
            rv[rb] += w
        new.rotvec = rv
        new.rotvec_drift = old.rotvec_drift + (
            float(np.sqrt(np.maximum.reduce(np.add.reduce(w * w, axis=1)))) if len(w) else 0.0)
        if new.rotvec_drift > np.pi / 2:
            new.rotvec = self.rotation_from_input(new)
            new.rotvec_drift = 0.0

    def rotation_from_input(self, state: State, rot=None, rotvec=None) -> np.ndarray:
        """(nb, 3) rotation vectors ``v`` with ``state.rot = expm(v) init_rot``, the turn count
        taken from ``state.rotvec`` (the nearest equivalent vector; principal if None).
        ``rot`` (..., nb, 3, 3) and ``rotvec`` (..., nb, 3) instead of ``state``: many frames
        at once."""
        rot = state.rot if rot is None else rot
        rotvec = state.rotvec if rotvec is None and state is not None else rotvec
        v = rotation_vector(np.matmul(rot, np.swapaxes(self.init_rot, 1, 2)))
        return v if rotvec is None else lift_rotation_vector(v, rotvec)

    def local_difference(self, a: State, b: State) -> np.ndarray:
        """Tangent increment ``dq`` at ``a`` with ``retract(a, dq) == b`` (the log map).

        Rotation part ``w = log(R_b R_a^T)`` (spatial, per rigid body; |w| < pi); translation
        part the CG increment of the screw ``retract`` follows (point bodies: ``p_b - p_a``),
        so the two maps are exact inverses and extrapolating ``dq`` linearly follows hinges.
        Used by quasi-static predictors.
        """
        dq = np.zeros(self.nq)
        dp = b.pos - a.pos
        dq[self.trans_idx] = dp.ravel()
        rb = self.rot_body
        if len(rb):
            w = log_so3(np.matmul(b.rot[rb], np.swapaxes(a.rot[rb], 1, 2)))
            E, V = screw_exp(w)
            v0 = np.linalg.solve(V, (b.pos[rb] - np.einsum("nij,nj->ni", E, a.pos[rb]))[..., None])[..., 0]
            dt = v0 + np.cross(w, a.pos[rb])
            ti = self.body_off[rb][:, None] + np.arange(3)
            dq[ti.ravel()] = dt.ravel()
            dq[(self.body_off[rb][:, None] + 3 + np.arange(3)).ravel()] = w.ravel()
        if self.n_extra:
            dq[self.extra_idx] = b.extra - a.extra
        return dq

    def depends_on_time(self) -> bool:
        """True if the solution may change with the analysis time: a compiled family's element
        type says so (``time_sources``: expressions of TIME in forces, gravity, motions and
        states, velocity / acceleration motions, user routines as opaque code)."""
        return bool(self.time_sources)

    # ------------------------------------------------------------------ mass
    def deck_mass(self) -> np.ndarray:
        """Body masses (nb,) in the deck's mass unit (``body_mass`` is scaled by the units
        factor so that F = m a holds in deck units; never show or write it as a mass)."""
        f = self.mass_factor
        return self.body_mass / f if f else np.zeros_like(self.body_mass)

    def mass_blocks(self, state):
        """Translational (nb,3,3) and rotational (nr,3,3) mass blocks in global axes."""
        return self.body_mass[:, None, None] * _I3, self.world_inertia(state)

    def world_inertia(self, state):
        """The rigid bodies' inertias about their CGs in global axes (nr, 3, 3): the
        rotational mass blocks alone."""
        R, I = state.rot, self.body_inertia
        # every body rigid (rot_body is 0..nb-1): the arrays the gathers would copy
        if not (len(self.rot_body) == self.nb and R.flags.c_contiguous and I.flags.c_contiguous):
            R, I = R[self.rot_body], I[self.rot_body]
        return np.matmul(R, np.matmul(I, R.swapaxes(1, 2)))

    def mass_diagonal(self, state) -> np.ndarray:
        """Diagonal of the mass matrix in tangent coordinates, (nq,)."""
        Jg = self.world_inertia(state)
        d = np.zeros(self.nq)
        d[self.trans_idx] = np.repeat(self.body_mass, 3)
        if len(self.rot_idx):
            d[self.rot_idx] = np.einsum("nii->ni", Jg).ravel()
        return d

    # ------------------------------------------------------------------ evaluate
    def evaluate(self, state: State, need_jac=True, eps_mass: float = 0.0,
                 keep: bool = False, active: np.ndarray | None = None,
                 workspace=None) -> Evaluation:
        """Residual and (``need_jac``: True, False or ``"defer"``) the KKT Jacobian of one
        frame: :func:`poise.model.evaluate.evaluate` (the evaluation engine), kept as a
        method for the solvers' many one-frame calls. ``workspace``: the solve's (a fresh one
        when None: nothing is kept between calls)."""
        what = ("defer" if isinstance(need_jac, str) and need_jac == "defer"
                else "jacobian" if need_jac else "residual")
        return evaluate(self, state, what, active=active, keep=keep, eps_mass=eps_mass,
                        workspace=workspace)

    def jacobian(self, ev: Evaluation):
        """The KKT Jacobian of an evaluation (assembled now if it was deferred); sets ``ev.J``."""
        return jacobian(self, ev)


def log_so3(R):
    """Rotation vectors (n, 3) of rotation matrices (n, 3, 3) (angle in [0, pi])."""
    tr = np.einsum("nii->n", R)
    c = np.clip(0.5 * (tr - 1.0), -1.0, 1.0)
    th = np.arccos(c)
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    s = np.sin(th)
    small = th < 1e-6
    fac = np.where(small, 0.5 + th ** 2 / 12.0, th / (2.0 * np.where(small, 1.0, s)))
    w = fac[:, None] * v
    near_pi = th > np.pi - 1e-3
    for i in np.nonzero(near_pi)[0]:
        B = 0.5 * (R[i] + np.eye(3))          # = cos-part + (1-c) a a^T
        k = int(np.argmax(np.diag(B)))
        a = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
        a /= np.linalg.norm(a)
        if np.dot(a, v[i]) < 0:
            a = -a
        w[i] = th[i] * a
    return w


#: columns of the continuous-angle table's kinds (0 AX, 1 AY, 2 AZ, 3 the rack-and-pinion angle):
#: angle = atan2(u . e2, u . e1), u an axis of the first marker, e1 and e2 axes of the second.
#: Kind 3 is the direction of the first marker's z axis in the second's x-y plane.
ANGLE_U_COL = np.array([1, 2, 0, 2])     # AX: y_I, AY: z_I, AZ: x_I, 3: z_I
ANGLE_E1_COL = np.array([1, 2, 0, 0])    # AX: y_J, AY: z_J, AZ: x_J, 3: x_J
ANGLE_E2_COL = np.array([2, 0, 1, 1])    # AX: z_J, AY: x_J, AZ: y_J, 3: y_J


def principal_angles(A, I, J, axis):
    """Principal relative angles (..., na) of the angle table (:data:`ANGLE_U_COL`): marker I
    about marker J's axis (kinds 0 x, 1 y, 2 z) or kind 3. ``A`` (..., nm, 3, 3) marker axes
    as columns, optionally with leading frame axes."""
    A = np.asarray(A)
    lead = A.shape[:-3]
    if len(I) == 0:
        return np.zeros(lead + (0,))
    axis = np.asarray(axis)

    At = np.swapaxes(A, -1, -2)          # (..., nm, column, component): plain indexing

    def col(idx, c):
        return At[..., idx, c[axis], :]
    u, e1, e2 = col(I, ANGLE_U_COL), col(J, ANGLE_E1_COL), col(J, ANGLE_E2_COL)
    return np.arctan2(np.sum(u * e2, axis=-1), np.sum(u * e1, axis=-1))
