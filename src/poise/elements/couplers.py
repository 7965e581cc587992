"""Coupler constraint between the free coordinates of up to three joints (also used by gears).

``Constraint_Coupler`` (deck_format.md §3.3) and ``Constraint_Gear`` (§3.4, position-level form,
see :mod:`poise.elements.gears`) are one scalar equation

    sum_k c_k (q_k - q0_k) = 0,   k = 1..3

where ``q_k`` is joint k's free coordinate between its I and J markers (freedom ``R``: the
continuous angle ``AZ(I_k, J_k)``; ``T``: ``DZ(I_k, J_k, J_k)``) and ``q0_k`` its value in the
input configuration. The coordinates, the two-joint form and the slot layout: :class:`Coupler`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.elements.base import ConstraintFamily
from poise.elements.context import GLOBAL
from poise.elements.measures import measure
from poise.elements.registry import ElementType, OutputGroup, static, workless


N_JOINTS = 3
N_SLOTS = 8 * N_JOINTS
W = 3 * N_SLOTS
SLOT_ML = np.repeat(np.arange(2 * N_JOINTS), 4)
SLOT_KIND = np.tile(np.array([0, 1, 2, 3]), 2 * N_JOINTS)


@dataclass(frozen=True, eq=False, kw_only=True)
class Coupler(ConstraintFamily):
    """``sum_k c_k (q_k - q0_k) = 0``.

    Attributes
    ----------
    coef : (n, 3) coefficients c_k (0 for an absent third joint)
    rot : (n, 3) bool, freedom R (True) or T (False) per joint
    q0 : (n, 3) values in the input configuration
    angle_index : (n, 3) int, continuous-angle table entry of R joints (-1 for T joints)

    where ``q_k`` is joint k's free coordinate measured between its I and J markers:

    * freedom ``R``: the continuous angle ``AZ(I_k, J_k)`` (angle table, full turns counted);
    * freedom ``T``: ``DZ(I_k, J_k, J_k) = (P_I - P_J) . z_J``;

    and ``q0_k`` its value in the input configuration (so the input configuration satisfies the
    coupler; see docs/elements.md "Couplers", "Gears"). A two-joint coupler has ``c_3 = 0`` and a
    dummy third joint on the global frame (ground markers: no coordinates).

    Slot layout (markers ``[I1, J1, I2, J2, I3, J3]``): per joint k the 8 slots
    ``[P_I, x_I, y_I, z_I, P_J, x_J, y_J, z_J]`` of :mod:`poise.elements.motions` (24 slots, W = 72).
    Gradient and multiplier-weighted Hessian are the exact ones of the motion measures
    (:func:`poise.elements.motions.measure`), placed in joint k's block.
    """

    coef: np.ndarray
    rot: np.ndarray
    q0: np.ndarray
    angle_index: np.ndarray

    @classmethod
    def build(cls, name, markers, coef, rot, q0, owner, angle_index=None, **layout):
        markers = np.asarray(markers, int).reshape(-1, 2 * N_JOINTS)
        n = markers.shape[0]
        return cls(name=name, markers=markers, slot_ml=SLOT_ML,
                   slot_kind=np.broadcast_to(SLOT_KIND, (n, N_SLOTS)).copy(),
                   owner=np.asarray(owner, int), m=1,
                   coef=np.asarray(coef, float).reshape(n, N_JOINTS),
                   rot=np.asarray(rot, bool).reshape(n, N_JOINTS),
                   q0=np.asarray(q0, float).reshape(n, N_JOINTS),
                   angle_index=(-np.ones((n, N_JOINTS), int) if angle_index is None
                                else np.asarray(angle_index, int)), **layout)

    def joint_values(self, kin, ctx):
        """Current q_k, (n, 3)."""
        n = self.n
        q = np.zeros((n, N_JOINTS))
        for k in range(N_JOINTS):
            Yk = kin.Y[:, 8 * k:8 * k + 8]
            r = self.rot[:, k]
            if (~r).any():
                v, _, _ = measure(Yk, "Z", need_hess=False)
                q[~r, k] = v[~r]
            if r.any():
                q[r, k] = ctx.angle[self.angle_index[r, k]]
        return q

    def constraints(self, kin, lam, ctx):
        n = self.n
        q = self.joint_values(kin, ctx)
        phi = np.sum(self.coef * (q - self.q0), axis=1)[:, None]
        phi_y = np.zeros((n, 1, W))
        G = np.zeros((n, W, W))
        lv = lam[:, 0]
        for k in range(N_JOINTS):
            c = self.coef[:, k]
            if not np.any(c != 0):
                continue
            Yk = kin.Y[:, 8 * k:8 * k + 8]
            blk = slice(24 * k, 24 * k + 24)
            r = self.rot[:, k]
            for name, mask in (("AZ", r), ("Z", ~r)):
                if not mask.any():
                    continue
                _, g, H = measure(Yk[mask], name, need_hess=True)
                idx = np.nonzero(mask)[0]
                phi_y[idx, 0, blk] = c[mask, None] * g
                G[idx, blk, blk] = (lv[mask] * c[mask])[:, None, None] * H
        return phi, phi_y, G


# ----------------------------------- compile
_FREEDOMS = {"REVOLUTE": ("R",), "TRANSLATIONAL": ("T",), "CYLINDRICAL": ("R", "T")}


def marker_pose(ctx, el, attr):
    """Input-configuration origin and axes (columns) of the marker ``el.attrs[attr]``."""
    pose = ctx.marker_pose(el.attrs.get(attr))
    return (np.zeros(3), np.eye(3)) if pose is None else pose


def joint_coordinate(ctx, owner_el, jid, freedom, attr_j, attr_f):
    """Resolve one coupled joint: (I, J, rot, q0, jel) or None (problem reported).

    ``freedom`` may be None (derived from the joint type)."""
    pc = ctx.pc
    jel = ctx.element("Constraint_Joint", jid)
    if jel is None:
        pc.error(owner_el.loc, f"joint {jid} does not exist; expected the id of a "
                 "Constraint_Joint", attr_j)
        return None
    jt = str(jel.attrs.get("type", "")).upper()
    ok = _FREEDOMS.get(jt)
    if ok is None:
        pc.error(owner_el.loc, f"joint {jid} is a {jt} joint; expected a REVOLUTE, "
                 "TRANSLATIONAL or CYLINDRICAL joint", attr_j)
        return None
    fr = str(freedom).upper() if freedom else (ok[0] if len(ok) == 1 else None)
    if fr not in ok:
        pc.error(owner_el.loc, f"freedom {fr} is not possible on the {jt} joint {jid}; expected "
                 + " or ".join(ok) + (" (required for a CYLINDRICAL joint)" if jt == "CYLINDRICAL"
                                      else ""), attr_f)
        return None
    I, J = ctx.marker(jel, "i_marker_id"), ctx.marker(jel, "j_marker_id")
    pI, RI = marker_pose(ctx, jel, "i_marker_id")
    pJ, RJ = marker_pose(ctx, jel, "j_marker_id")
    if fr == "R":
        q0 = float(np.arctan2(RI[:, 0] @ RJ[:, 1], RI[:, 0] @ RJ[:, 0]))
    else:
        q0 = float((pI - pJ) @ RJ[:, 2])
    return dict(I=I, J=J, rot=fr == "R", q0=q0, jel=jel, pI=pI, RI=RI, pJ=pJ, RJ=RJ)


def user_routine_error(pc, el, what):
    """True (and a located error) if ``el`` names a user subroutine or script."""
    for a in ("usrsub_dll_name", "usrsub_fnc_name", "usrsub_param_string", "script_name"):
        if el.attrs.get(a):
            pc.error(el.loc, f"user {what} routines ({a}) are not supported; expected "
                     "coefficients", a)
            return True
    return False


def add_coupler_family(ctx, group, tag, items, cls=Coupler):
    """items: list of (el, [joint dicts], coef (3,), kind 'rot'|'trans')."""
    if not items:
        return
    mk, coef, rot, q0, rows, owners = [], [], [], [], [], []
    for k, (el, js, c, kind) in enumerate(items):
        m = []
        for j in range(N_JOINTS):
            if j < len(js):
                m += [js[j]["I"], js[j]["J"]]
            else:
                m += [GLOBAL, GLOBAL]
        mk.append(m)
        coef.append(list(c) + [0.0] * (N_JOINTS - len(c)))
        rot.append([js[j]["rot"] if j < len(js) else False for j in range(N_JOINTS)])
        q0.append([js[j]["q0"] if j < len(js) else 0.0 for j in range(N_JOINTS)])
        rows.append([ctx.add_row(el, "sum c_k (q_k - q0_k)", kind, group, k)])
        owners.append(k)
    ai = -np.ones((len(items), N_JOINTS), int)
    for k, it in enumerate(items):
        for j, jd in enumerate(it[1]):
            if jd["rot"]:
                ai[k, j] = ctx.angle(jd["I"], jd["J"], 2)
    ctx.add_family(cls.build(f"{group}:{cls.__name__.lower()}", mk, coef, rot, q0, owners,
                             angle_index=ai, crow=np.array(rows, int), group=group,
                             element_locs=tuple(it[0].loc for it in items)))
    ctx.output(group, np.array([tag] * len(items)), [it[0].id for it in items])


def compile_couplers(spec, ctx):
    """Compile ``Constraint_Coupler`` into :class:`poise.elements.couplers.Coupler` rows.

    Each coupler is one constraint row ``c1 (q1 - q1_0) + c2 (q2 - q2_0) [+ c3 (q3 - q3_0)] = 0``
    (see :mod:`poise.elements.couplers`): q_k is AZ(I,J) (freedom R, continuous angle) or
    DZ(I,J,J) (freedom T) of joint k's markers, q_k0 its value in the input configuration.
    Joints must be REVOLUTE (R), TRANSLATIONAL (T) or CYLINDRICAL (R or T, ``freedom_k`` required).
    User couplers (COUSUB via ``usrsub_*`` / ``script_name``) are rejected (exit 3).
    Output group ``couplers``: force and torque of the coupler's multiplier acting through joint 1's
    I marker on its body (torque about that marker's origin, global axes).
    """
    els = spec.elements("Constraint_Coupler")
    if not els:
        return
    pc = ctx.pc
    items = []
    for el in els:
        if user_routine_error(pc, el, "coupler (COUSUB)"):
            continue
        coef = el.attrs.get("coefficients")
        if isinstance(coef, str):
            coef = [float(x) for x in coef.replace(",", " ").split()]
        coef = [float(x) for x in (coef or [])]
        nj = 3 if el.attrs.get("joint3_id") else 2
        if len(coef) != nj:
            pc.error(el.loc, f"{len(coef)} coefficients for {nj} joints; expected "
                     f"coefficients=\"c1, c2{', c3' if nj == 3 else ''}\"", "coefficients")
            continue
        js = []
        for j in range(1, nj + 1):
            jd = joint_coordinate(ctx, el, el.attrs.get(f"joint{j}_id"),
                                  el.attrs.get(f"freedom_{j}"), f"joint{j}_id", f"freedom_{j}")
            if jd is None:
                break
            js.append(jd)
        if len(js) != nj:
            continue
        kind = "rot" if all(jd["rot"] for jd in js) else "trans"
        items.append((el, js, coef, kind))
        ctx.effect("Constraint_Coupler")
    pc.raise_if_any()
    add_coupler_family(ctx, "couplers", "Constraint_Coupler", items)


ELEMENTS = (ElementType(
    "couplers", ("Constraint_Coupler",), compile_couplers,
    rank=40,                    # coupler rows after the motion rows
    kernels=lambda: (Coupler,), potential_energy=workless,
    time_dependent=static,      # displacements from the input configuration: no time
    outputs=(OutputGroup("couplers", "Cp", "coupler", "coupler",
                         "`Constraint_Coupler`", ("Constraint_Coupler",),
                         load="load the coupler's multiplier applies **through joint 1's I "
                         "marker** to that marker's body (e.g. the coupling torque on shaft "
                         "1)"),),
    fd_tests="tests/kernels/test_couplers_gears_fields_beams.py"),)
