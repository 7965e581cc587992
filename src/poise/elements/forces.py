"""Force families between two markers, vectorised.

Every two-body force element shares one slot layout (markers I, J and the reference marker R of
vector-force components; :mod:`poise.elements.two_body`). Each family computes the force ``F``
and torque ``T`` acting on the body of I at the I origin (global components) and their
derivatives with respect to the slot vectors; :func:`~poise.elements.two_body.apply_two_body`
applies them to I and, unless the element is action-only, the equal and opposite action to J.
Laws follow ``conventions.md`` (statics: velocities are zero, damping vanishes).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.core.errors import EvaluationError
from poise.core.lean import row_norms
from poise.core.user_routines import uses_user_routine
from poise.deck.spec import Expr
from poise.elements.base import ForceFamily
from poise.elements.context import GLOBAL, num as _num
from poise.elements.registry import ElementType, FDCase, OutputGroup, kernel_potential, static
from poise.elements.two_body import (ANGLE_SLOTS, N_SLOTS, S_PI, S_PJ, S_XI, S_XJ,  # noqa: F401
                                     S_XR, S_YI, S_YJ, S_YR, S_ZI, S_ZJ, S_ZR, SLOT_KIND, SLOT_ML,
                                     angle_gradient, apply_two_body, principal_angle, sl)

_I3 = np.eye(3)
_SL_PI, _SL_PJ = sl(S_PI), sl(S_PJ)      # the I and J point slots' columns


@dataclass(frozen=True, eq=False, kw_only=True)
class TwoBodyForce(ForceFamily):
    """Common part of the marker-pair force families: ``action_only`` (n,) bool (no reaction
    on J), ``angle_index`` (n,) or (n, 3) continuous-angle table entries of the laws that read
    angles (None otherwise)."""

    action_only: np.ndarray
    angle_index: np.ndarray | None = None

    @classmethod
    def build(cls, name, I, J, R, owner, action_only=None, *, group=None, element_locs=(),
              angle_index=None, **params):
        """The family of instances with markers ``I, J, R`` (n,); ``params``: the class's
        numeric parameters, one entry (or row) per instance."""
        n = len(I)
        return cls(name=name, markers=np.stack([I, J, R], 1).astype(int), slot_ml=SLOT_ML,
                   slot_kind=np.broadcast_to(SLOT_KIND, (n, N_SLOTS)).copy(),
                   owner=np.asarray(owner, int), group=group, element_locs=tuple(element_locs),
                   action_only=(np.zeros(n, bool) if action_only is None
                                else np.asarray(action_only, bool)),
                   angle_index=None if angle_index is None else np.asarray(angle_index, int),
                   **{k: np.asarray(v) for k, v in params.items()})

    def compute(self, Y, ctx, need_jac):
        """Return F, T (n,3) and dF, dT (n,3,33); T and dT None: no torque on I (a law along a
        line: nothing is applied for it); F and dF None: no force (a pure torque)."""
        raise NotImplementedError

    def forces(self, kin, ctx, need_jac=True):
        F, T, dF, dT = self.compute(kin.Y, ctx, need_jac)
        return apply_two_body(kin.Y, F, T, dF, dT, self.action_only, need_jac)


@dataclass(frozen=True, eq=False, kw_only=True)
class LineForce(TwoBodyForce):
    """Force of magnitude ``f = -k (L - length) + preload`` along J->I (positive repels).

    Covers ``Force_SpringDamper TRANSLATIONAL`` (k, length, preload) and
    ``Force_Scalar_TwoBody FORCE`` (k = 0, preload = value). Parameters: ``k``, ``length``,
    ``preload`` (n,).
    """

    k: np.ndarray
    length: np.ndarray
    preload: np.ndarray

    def _law(self, ctx):
        """The law's per-instance constants (``c``, ``c != 0``, ``-k`` and ``c`` as columns,
        ``-k I``): the same every evaluation, kept in the solve's workspace."""
        sc = ctx.workspace.scratch(self, dict) if getattr(ctx, "workspace", None) else {}
        law = sc.get("law")
        if law is None:
            c = self.k * self.length + self.preload
            law = sc["law"] = (c, c != 0.0, -self.k[:, None], c[:, None],
                               (-self.k)[:, None, None] * _I3)
        return law

    def forces(self, kin, ctx, need_jac=True):
        """``-F`` on J at its origin and nothing else: a force along the line through both
        origins has no moment about J's (:func:`apply_two_body`'s reaction torque
        ``-(P_I - P_J) x F`` and its derivative are zero here; formed, they would be round-off).
        ``G`` has the four point-slot blocks ``-/+ dF/dd`` (the values apply_two_body puts)."""
        F, dFdd = self._line(kin.Y, ctx, need_jac)
        n = len(F)
        W = 3 * N_SLOTS
        rho = np.zeros((n, W))
        rho[:, _SL_PI] = -F
        react = (~self.action_only if np.logical_or.reduce(self.action_only, axis=None)
                 else None)
        rho[:, _SL_PJ] = F if react is None else F * react[:, None]
        if not need_jac:
            return rho, None
        G = np.zeros((n, W, W))
        m = -dFdd
        G[:, _SL_PI, _SL_PI] = m
        G[:, _SL_PI, _SL_PJ] = dFdd
        if react is not None:
            m = m * react[:, None, None]
            dFdd = dFdd * react[:, None, None]
        G[:, _SL_PJ, _SL_PI] = dFdd
        G[:, _SL_PJ, _SL_PJ] = m
        return rho, G

    def compute(self, Y, ctx, need_jac):
        F, dFdd = self._line(Y, ctx, need_jac)
        dF = None
        if need_jac:
            dF = np.zeros((len(F), 3, 3 * N_SLOTS))
            dF[:, :, _SL_PI] = dFdd
            dF[:, :, _SL_PJ] = -dFdd
        return F, None, dF, None

    def _line(self, Y, ctx, need_jac):
        """The force ``F`` (n, 3) on I and ``dF/d(P_I - P_J)`` (n, 3, 3) (None without
        ``need_jac``)."""
        # F = f u = -k d + c u with c = k length + preload: the first term is smooth everywhere,
        # the second needs a defined direction (L > 0) unless c = 0.
        d = Y[:, S_PI] - Y[:, S_PJ]
        L = row_norms(d)
        c, live, nk, cc, nkI = self._law(ctx)
        far = L > 1e-300
        Ls = L                          # (every line defined: the usual case, no selection)
        if not np.logical_and.reduce(far):
            bad = (L <= 1e-300) & live
            if np.logical_or.reduce(bad):
                i = int(np.nonzero(bad)[0][0])
                raise EvaluationError("the I and J markers coincide: the line of action is "
                                      "undefined",
                                      self.element_locs[i] if self.element_locs else None)
            Ls = np.where(far, L, 1.0)
        u = d / Ls[:, None]
        F = nk * d + cc * u
        if not need_jac:
            return F, None
        uu = u[:, :, None] * u[:, None, :]
        return F, nkI + (c / Ls)[:, None, None] * (_I3 - uu)

    def potential_energy(self, kin, ctx):
        """``k/2 (L - length)^2 - preload L`` per instance (MKEAM history)."""
        d = kin.Y[:, S_PI] - kin.Y[:, S_PJ]
        L = np.linalg.norm(d, axis=1)
        return 0.5 * self.k * (L - self.length) ** 2 - self.preload * L


@dataclass(frozen=True, eq=False, kw_only=True)
class AxisForce(TwoBodyForce):
    """Action-only force of constant magnitude along J's z axis (``Force_Scalar_TwoBody``
    ``FORCE`` with ``is_action_only``). Parameter ``value`` (n,)."""

    value: np.ndarray

    def compute(self, Y, ctx, need_jac):
        z = Y[:, S_ZJ]
        F = self.value[:, None] * z
        dF = None
        if need_jac:
            n = len(F)
            dF = np.zeros((n, 3, 3 * N_SLOTS))
            dF[:, :, sl(S_ZJ)] = self.value[:, None, None] * _I3
        return F, None, dF, None


@dataclass(frozen=True, eq=False, kw_only=True)
class AxisTorque(TwoBodyForce):
    """Torque ``tau = -k (AZ(I,J) - length) + preload`` about J's z axis.

    ``Force_SpringDamper ROTATIONAL`` and ``Force_Scalar_TwoBody TORQUE`` (k = 0). AZ is the
    continuous angle (full turns counted) held in ``ctx.angle[self.angle_index]``.
    """

    k: np.ndarray
    length: np.ndarray
    preload: np.ndarray

    def compute(self, Y, ctx, need_jac):
        theta = ctx.angle[self.angle_index]
        tau = -self.k * (theta - self.length) + self.preload
        z = Y[:, S_ZJ]
        T = tau[:, None] * z
        F = dF = dT = None                  # a pure torque (no force, no offset moment)
        if need_jac:
            n = len(T)
            g = angle_gradient(Y, 2)
            dT = np.zeros((n, 3, 3 * N_SLOTS))
            dT += z[:, :, None] * (-self.k)[:, None, None] * g[:, None, :]
            dT[:, :, sl(S_ZJ)] += tau[:, None, None] * _I3
        return F, T, dF, dT

    def potential_energy(self, kin, ctx):
        """``k/2 (AZ - length)^2 - preload AZ`` (AZ continuous; exact when I's z stays along J's
        z, as in a hinge); per instance."""
        theta = ctx.angle[self.angle_index]
        return 0.5 * self.k * (theta - self.length) ** 2 - self.preload * theta


@dataclass(frozen=True, eq=False, kw_only=True)
class Bushing(TwoBodyForce):
    """``Force_Bushing``: ``F_J = -K (DX,DY,DZ)(I,J,J) + preload``, ``T_J = -Kt (AX,AY,AZ)(I,J)
    + preload_t`` in J's axes, applied at I; reaction on J with the offset moment.

    Parameters: ``kt3`` (n,3) translational stiffness, ``kr3`` (n,3) rotational, ``f0`` (n,3),
    ``t0`` (n,3), ``angle_index`` (n,3) into ``ctx.angle``.
    """

    kt3: np.ndarray
    kr3: np.ndarray
    f0: np.ndarray
    t0: np.ndarray

    def compute(self, Y, ctx, need_jac):
        n = Y.shape[0]
        d = Y[:, S_PI] - Y[:, S_PJ]
        AJ = np.stack([Y[:, S_XJ], Y[:, S_YJ], Y[:, S_ZJ]], axis=2)       # columns
        D = np.einsum("nik,ni->nk", AJ, d)
        th = ctx.angle[self.angle_index]                                    # (n,3)
        FJ = -self.kt3 * D + self.f0
        TJ = -self.kr3 * th + self.t0
        F = np.einsum("nik,nk->ni", AJ, FJ)
        T = np.einsum("nik,nk->ni", AJ, TJ)
        dF = dT = None
        if need_jac:
            W = 3 * N_SLOTS
            dD = np.zeros((n, 3, W))
            AJt = np.swapaxes(AJ, 1, 2)
            dD[:, :, _SL_PI] = AJt
            dD[:, :, _SL_PJ] = -AJt
            for k, s in enumerate((S_XJ, S_YJ, S_ZJ)):
                dD[:, k, sl(s)] += d
            dth = np.stack([angle_gradient(Y, k) for k in range(3)], axis=1)   # (n,3,W)
            dFJ = -self.kt3[:, :, None] * dD
            dTJ = -self.kr3[:, :, None] * dth
            dF = np.matmul(AJ, dFJ)
            dT = np.matmul(AJ, dTJ)
            for k, s in enumerate((S_XJ, S_YJ, S_ZJ)):
                dF[:, :, sl(s)] += FJ[:, k][:, None, None] * _I3
                dT[:, :, sl(s)] += TJ[:, k][:, None, None] * _I3
        return F, T, dF, dT

    def potential_energy(self, kin, ctx):
        """Translational part ``D^T K D / 2 - f0 . D``; None (not conservative in general) when a
        rotational stiffness or torque preload is present."""
        if np.any(self.kr3 != 0) or np.any(self.t0 != 0):
            return None
        Y = kin.Y
        AJ = np.stack([Y[:, S_XJ], Y[:, S_YJ], Y[:, S_ZJ]], axis=2)
        D = np.einsum("nik,ni->nk", AJ, Y[:, S_PI] - Y[:, S_PJ])
        return np.sum(0.5 * self.kt3 * D * D - self.f0 * D, axis=1)


@dataclass(frozen=True, eq=False, kw_only=True)
class VectorForce(TwoBodyForce):
    """Constant force and torque components along the reference marker R's axes, applied at I.

    ``Force_Vector_OneBody`` (action-only; reaction to ground) and ``Force_Vector_TwoBody``
    (reaction on the floating marker's body). Parameters ``fc`` (n,3), ``tc`` (n,3).
    """

    fc: np.ndarray
    tc: np.ndarray

    def compute(self, Y, ctx, need_jac):
        AR = np.stack([Y[:, S_XR], Y[:, S_YR], Y[:, S_ZR]], axis=2)
        F = np.einsum("nik,nk->ni", AR, self.fc)
        T = np.einsum("nik,nk->ni", AR, self.tc)
        dF = dT = None
        if need_jac:
            n = Y.shape[0]
            dF = np.zeros((n, 3, 3 * N_SLOTS))
            dT = np.zeros_like(dF)
            for k, s in enumerate((S_XR, S_YR, S_ZR)):
                dF[:, :, sl(s)] = self.fc[:, k][:, None, None] * _I3
                dT[:, :, sl(s)] = self.tc[:, k][:, None, None] * _I3
        return F, T, dF, dT

    potential_needs_ground = True

    def potential_energy(self, kin, ctx, on_ground=None):
        """``-F . P_I`` per instance when the force is constant in space: reference marker R
        and the reaction side (J, or action-only) on ground and no torque; None otherwise.
        ``on_ground`` (n, 3) bool: which of the slots' markers I, J, R are fixed."""
        if on_ground is None or np.any(self.tc != 0):
            return None
        fixed_j = self.action_only | on_ground[:, 1]
        if not np.all(on_ground[:, 2] & fixed_j):
            return None
        Y = kin.Y
        AR = np.stack([Y[:, S_XR], Y[:, S_YR], Y[:, S_ZR]], axis=2)
        F = np.einsum("nik,nk->ni", AR, self.fc)
        return -np.sum(F * Y[:, S_PI], axis=1)


# ----------------------------------- compile
def compile_forces(spec, ctx):
    """Compile force elements (springs, bushings, vector and scalar forces) into force families.
    """
    mk = ctx.marker
    angle = ctx.angle
    pc = ctx.pc
    force_rows = []   # (tag, id, loc) per force element, output group "forces"
    per_type: dict[str, list] = {}

    def add(kind, el, **kw):
        force_rows.append(el)
        per_type.setdefault(kind, []).append(dict(owner=len(force_rows) - 1, el=el, **kw))

    def defer(el, to, effect):
        """Its force row now, its kernel from the later compiler ``to`` (``user`` or
        ``expressions``)."""
        force_rows.append(el)
        ctx.route(to, (len(force_rows) - 1, el))
        ctx.effect(effect)

    for el in spec.elements("Force_SpringDamper"):
        t = str(el.attrs.get("type", "TRANSLATIONAL")).upper()
        I, J = mk(el, "i_marker_id"), mk(el, "j_marker_id")
        k = _num(el, "stiffness", 0.0, pc)
        pre = _num(el, "preload", 0.0, pc)
        if t == "ROTATIONAL":
            L0 = _num(el, "length", None, pc)
            if L0 is None:
                L0 = _num(el, "angle", 0.0, pc)
            add("AxisTorque", el, I=I, J=J, R=GLOBAL, k=k, length=L0, preload=pre, ax=False,
                ang=angle(I, J, 2))
        else:
            add("LineForce", el, I=I, J=J, R=GLOBAL, k=k, length=_num(el, "length", 0.0, pc),
                preload=pre, ax=False)
        ctx.effect(f"Force_SpringDamper:{t}")
    for el in spec.elements("Force_Scalar_TwoBody"):
        t = str(el.attrs.get("type", "FORCE")).upper()
        if uses_user_routine(el):          # Python SFOSUB: compiled by compile_user
            defer(el, "user", f"Force_Scalar_TwoBody:{t}:python")
            continue
        I, J = mk(el, "i_marker_id"), mk(el, "j_marker_id")
        val = el.attrs.get("val", el.attrs.get("val_expression", 0.0))
        if isinstance(val, Expr):          # expression force: compiled by compile_expr
            defer(el, "expressions", f"Force_Scalar_TwoBody:{t}")
            continue
        ao = bool(el.attrs.get("is_action_only", False))
        if t == "TORQUE":
            add("AxisTorque", el, I=I, J=J, R=GLOBAL, k=0.0, length=0.0, preload=val, ax=ao,
                ang=angle(I, J, 2))
        elif ao:
            add("AxisForce", el, I=I, J=J, R=GLOBAL, value=val, ax=True)
        else:
            add("LineForce", el, I=I, J=J, R=GLOBAL, k=0.0, length=0.0, preload=val, ax=False)
        ctx.effect(f"Force_Scalar_TwoBody:{t}")
    for el in spec.elements("Force_Bushing"):
        I, J = mk(el, "i_marker_id"), mk(el, "j_marker_id")
        def g(n, el=el):
            return float(_num(el, n, 0.0, pc) or 0.0)
        add("Bushing", el, I=I, J=J, R=GLOBAL, ax=False,
            kt3=[g("kx"), g("ky"), g("kz")], kr3=[g("ktx"), g("kty"), g("ktz")],
            f0=[g("preload_x"), g("preload_y"), g("preload_z")],
            t0=[g("preload_tx"), g("preload_ty"), g("preload_tz")],
            ang=[angle(I, J, 0), angle(I, J, 1), angle(I, J, 2)])
        ctx.effect("Force_Bushing")
    for tag in ("Force_Vector_OneBody", "Force_Vector_TwoBody"):
        for el in spec.elements(tag):
            one = tag.endswith("OneBody")
            I = mk(el, "marker_id" if one else "i_marker_id")
            J = GLOBAL if one else mk(el, "j_floating_marker_id")
            R = mk(el, "ref_marker_id", required=False)
            t = str(el.attrs.get("type", "FORCEANDTORQUE")).upper()
            if uses_user_routine(el):      # Python GFOSUB: compiled by compile_user
                defer(el, "user", f"{tag}:python")
                continue
            if any(isinstance(el.attrs.get(f"{nm}_expression"), Expr)
                   for nm in ("fx", "fy", "fz", "tx", "ty", "tz")):
                defer(el, "expressions", tag)   # expression force: compiled by compile_expr
                continue
            comp = []
            for nm in ("fx", "fy", "fz", "tx", "ty", "tz"):
                v = el.attrs.get(f"{nm}_expression", el.attrs.get(nm, 0.0))
                if isinstance(v, Expr):
                    pc.error(el.loc, "expressions are not supported yet (coming with the "
                             "expression language); expected a number", f"{nm}_expression")
                    v = 0.0
                comp.append(float(v or 0.0))
            if t == "FORCEONLY":
                comp[3:] = [0.0] * 3
            elif t == "TORQUEONLY":
                comp[:3] = [0.0] * 3
            add("VectorForce", el, I=I, J=J, R=R, fc=comp[:3], tc=comp[3:], ax=one)
            ctx.effect(tag)

    classes = {"LineForce": LineForce, "AxisForce": AxisForce, "AxisTorque": AxisTorque,
               "Bushing": Bushing, "VectorForce": VectorForce}
    for kind, items in per_type.items():
        cls = classes[kind]
        params = {}
        for key in items[0]:
            if key in ("owner", "el", "I", "J", "R", "ax", "ang"):
                continue
            params[key] = np.array([it[key] for it in items], float)
        ctx.add_family(cls.build(
            f"forces:{kind}", np.array([it["I"] for it in items]),
            np.array([it["J"] for it in items]), np.array([it["R"] for it in items]),
            [it["owner"] for it in items], action_only=[it["ax"] for it in items],
            group="forces", element_locs=[it["el"].loc for it in items],
            angle_index=(np.array([it["ang"] for it in items], int) if "ang" in items[0]
                         else None), **params))
    if force_rows:
        ctx.output("forces", np.array([e.tag for e in force_rows]),
                   [e.id for e in force_rows])


_VEC = ("Force_Vector_TwoBody", "Force_Vector_OneBody")


def _fd_cases():
    def case(name, tag, **attrs):
        jm = "j_floating_marker_id" if tag == "Force_Vector_TwoBody" else "j_marker_id"
        return FDCase(name, ((tag, attrs),), marker_attrs=("i_marker_id", jm))
    return (
        case("spring_translational", "Force_SpringDamper", type="TRANSLATIONAL",
             stiffness=30.0, damping=1.0, length=0.7, preload=2.0),
        case("spring_rotational", "Force_SpringDamper", type="ROTATIONAL", stiffness=30.0,
             damping=1.0, length=7.0, preload=2.0),
        case("bushing", "Force_Bushing", kx=10.0, ky=20.0, kz=30.0, ktx=4.0, kty=5.0,
             ktz=6.0, preload_x=1.0, preload_tz=2.0),
        case("scalar_force", "Force_Scalar_TwoBody", type="FORCE", val=3.0),
        case("scalar_force_action_only", "Force_Scalar_TwoBody", type="FORCE", val=3.0,
             is_action_only=True),
        case("scalar_torque", "Force_Scalar_TwoBody", type="TORQUE", val=3.0),
        case("vector_twobody", "Force_Vector_TwoBody", type="FORCEANDTORQUE", fx_expression=1.0,
             fy_expression=2.0, fz_expression=-3.0, tx_expression=0.5, ty_expression=-1.0,
             tz_expression=2.0, ref_marker_id=32))


_KERNELS = lambda: (LineForce, AxisForce, AxisTorque, Bushing,  # noqa: E731
                    VectorForce)
#: the output group of every force element (the results schema's, too)
FORCES = OutputGroup("forces", "E", "force_element", "force element", "force element", None,
                     ("id", "label", "tag", "force", "torque"),
                     load="force the element applies to the body of its I marker, at the I "
                     "marker origin, global axes")

ELEMENTS = (ElementType(
    "forces", ("Force_SpringDamper", "Force_Scalar_TwoBody", "Force_Bushing") + _VEC,
    compile_forces,
    rank=20,                    # force families after the joint families
    kernels=_KERNELS, tileable=_KERNELS, potential_energy=kernel_potential,
    time_dependent=static,      # constant parameters (expression forces: "expressions")
    outputs=(FORCES,),
    reactions={"SFORCE": ("forces", ("Force_Scalar_TwoBody",)), "VFORCE": ("forces", _VEC),
               "VTORQ": ("forces", _VEC), "GFORCE": ("forces", _VEC),
               "BUSH": ("forces", ("Force_Bushing",)), "SPDP": ("forces", ("Force_SpringDamper",))},
    reaction_aliases={"FORCE_SCALAR_TWOBODY": "SFORCE", "FORCE_VECTOR_TWOBODY": "GFORCE",
                      "FORCE_VECTOR_ONEBODY": "GFORCE", "FORCE_BUSHING": "BUSH",
                      "BUSHING": "BUSH", "FORCE_SPRINGDAMPER": "SPDP", "SPRINGDAMPER": "SPDP"},
    fd_cases=_fd_cases),)
