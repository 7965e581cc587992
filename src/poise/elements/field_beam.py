"""Linear 6x6 field forces between two markers: ``Force_Field`` and ``Force_Beam``.

Both are the law (deck_format.md §5.6, §5.7; statics: damping terms vanish)

    [F; T]_J = -K (X - L) + F0,   X = [DX, DY, DZ, AX, AY, AZ](I, J) in J's axes,

with the translations ``D = A_J^T (P_I - P_J)`` and the continuous angles AX, AY, AZ of the
model's angle table (as in ``Force_Bushing``), applied at I on I's body; the equal and opposite
force and torque plus the moment of the I-J offset act on J's body
(:func:`poise.elements.forces.apply_two_body`). ``K`` is dense (any 6x6 matrix).

``Force_Beam`` builds K from the section data (:func:`beam_stiffness`), L = [length, 0, ...],
F0 = the preloads. The Jacobian with respect to the slot vectors is exact (FD-checked in
``tests/kernels/test_couplers_gears_fields_beams.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.elements.context import GLOBAL, num as _num
from poise.elements.couplers import user_routine_error
from poise.elements.forces import (FORCES, N_SLOTS, S_PI, S_PJ, S_XJ, S_YJ, S_ZJ, TwoBodyForce,
                                   angle_gradient, sl)
from poise.elements.registry import ElementType, kernel_potential, static


_I3 = np.eye(3)


def beam_stiffness(length, E, G, area, ixx, iyy, izz, asy, asz) -> np.ndarray:
    """6x6 Timoshenko stiffness of a cantilever tip (I) relative to its root (J), J axes.

    Order [x, y, z, ax, ay, az]; shear parameters ``Py = 12 E izz asy / (G area L^2)`` and
    ``Pz = 12 E iyy asz / (G area L^2)`` (``asy``, ``asz`` = shear-area correction factors,
    effective shear area = area / as):

    K11 = E A / L, K44 = G ixx / L,
    K22 = 12 E izz / (L^3 (1 + Py)), K26 = K62 = -6 E izz / (L^2 (1 + Py)),
    K66 = (4 + Py) E izz / (L (1 + Py)),
    K33 = 12 E iyy / (L^3 (1 + Pz)), K35 = K53 = +6 E iyy / (L^2 (1 + Pz)),
    K55 = (4 + Pz) E iyy / (L (1 + Pz)).

    Its inverse gives the tip deflection under a tip force P along y:
    ``P L^3 / (3 E izz) + P L asy / (G area)``.
    """
    L = float(length)
    Py = 12.0 * E * izz * asy / (G * area * L * L) if G * area else 0.0
    Pz = 12.0 * E * iyy * asz / (G * area * L * L) if G * area else 0.0
    K = np.zeros((6, 6))
    K[0, 0] = E * area / L
    K[3, 3] = G * ixx / L
    K[1, 1] = 12.0 * E * izz / (L ** 3 * (1.0 + Py))
    K[1, 5] = K[5, 1] = -6.0 * E * izz / (L ** 2 * (1.0 + Py))
    K[5, 5] = (4.0 + Py) * E * izz / (L * (1.0 + Py))
    K[2, 2] = 12.0 * E * iyy / (L ** 3 * (1.0 + Pz))
    K[2, 4] = K[4, 2] = 6.0 * E * iyy / (L ** 2 * (1.0 + Pz))
    K[4, 4] = (4.0 + Pz) * E * iyy / (L * (1.0 + Pz))
    return K


@dataclass(frozen=True, eq=False, kw_only=True)
class FieldForce(TwoBodyForce):
    """``[F; T]_J = -K (X - L) + F0`` (see module doc).

    Parameters: ``K6`` (n,6,6), ``L6`` (n,6), ``F06`` (n,6), ``angle_index`` (n,3).
    """

    K6: np.ndarray
    L6: np.ndarray
    F06: np.ndarray

    def _X(self, Y, ctx):
        AJ = np.stack([Y[:, S_XJ], Y[:, S_YJ], Y[:, S_ZJ]], axis=2)
        d = Y[:, S_PI] - Y[:, S_PJ]
        D = np.einsum("nik,ni->nk", AJ, d)
        th = ctx.angle[self.angle_index]
        return AJ, d, np.concatenate([D, th], axis=1)

    def compute(self, Y, ctx, need_jac):
        n = Y.shape[0]
        AJ, d, X = self._X(Y, ctx)
        FJ6 = -np.einsum("nij,nj->ni", self.K6, X - self.L6) + self.F06
        F = np.einsum("nik,nk->ni", AJ, FJ6[:, :3])
        T = np.einsum("nik,nk->ni", AJ, FJ6[:, 3:])
        dF = dT = None
        if need_jac:
            Wd = 3 * N_SLOTS
            dX = np.zeros((n, 6, Wd))
            AJt = np.swapaxes(AJ, 1, 2)
            dX[:, :3, sl(S_PI)] = AJt
            dX[:, :3, sl(S_PJ)] = -AJt
            for k, s in enumerate((S_XJ, S_YJ, S_ZJ)):
                dX[:, k, sl(s)] += d
            for k in range(3):
                dX[:, 3 + k] = angle_gradient(Y, k)
            dFJ6 = -np.matmul(self.K6, dX)
            dF = np.matmul(AJ, dFJ6[:, :3])
            dT = np.matmul(AJ, dFJ6[:, 3:])
            for k, s in enumerate((S_XJ, S_YJ, S_ZJ)):
                dF[:, :, sl(s)] += FJ6[:, k][:, None, None] * _I3
                dT[:, :, sl(s)] += FJ6[:, 3 + k][:, None, None] * _I3
        return F, T, dF, dT

    def potential_energy(self, kin, ctx):
        """``(X-L)^T K (X-L) / 2 - F0 . (X-L)`` when only the symmetric translational block is
        non-zero; None otherwise (angles AX/AY/AZ are not exact potentials' coordinates)."""
        K = self.K6
        if np.any(K[:, 3:, :] != 0) or np.any(K[:, :, 3:] != 0) or np.any(self.F06[:, 3:] != 0) \
                or not np.allclose(K, np.swapaxes(K, 1, 2)):
            return None
        _, _, X = self._X(kin.Y, ctx)
        e = X - self.L6
        return 0.5 * np.einsum("ni,nij,nj->n", e, K, e) - np.sum(self.F06 * e, axis=1)


# ----------------------------------- compile
_C6 = ("x", "y", "z", "tx", "ty", "tz")


def compile_field_beam(spec, ctx):
    """Compile ``Force_Field`` (linear form) and ``Force_Beam`` into one
    :class:`poise.elements.field_beam.FieldForce` family (output group ``forces``).

    * ``Force_Field``: ``K11 … K66`` (row i, column j of K; absent entries 0), ``length_x … tz``
      (reference X), ``preload_x … tz`` (F0); damping (``C11…``/``cratio``) vanishes in statics.
      User fields (FIESUB via ``usrsub_*``/``script_name``) are rejected (exit 3).
    * ``Force_Beam``: K from :func:`poise.elements.field_beam.beam_stiffness`, L = [length, 0 …],
      F0 = ``preload_*``.
    """
    els = spec.elements("Force_Field") + spec.elements("Force_Beam")
    if not els:
        return
    pc = ctx.pc
    items = []
    for el in els:
        def g(name, default=0.0, el=el):
            v = _num(el, name, default, pc)
            return float(default if v is None else v)
        if el.tag == "Force_Field":
            if user_routine_error(pc, el, "field (FIESUB)"):
                continue
            K = np.array([[g(f"k{i}{j}") for j in range(1, 7)] for i in range(1, 7)])
            L = np.array([g(f"length_{c}") for c in _C6])
        else:
            vals = {k: g(k, None) if el.attrs.get(k) is not None else None
                    for k in ("length", "e", "g", "area", "ixx", "iyy", "izz", "asy", "asz")}
            missing = [k for k in ("length", "e", "g", "area", "ixx", "iyy", "izz")
                       if vals[k] is None]
            if missing:
                pc.error(el.loc, "missing " + ", ".join(missing) + "; expected the beam's "
                         "length, E, G, area, ixx, iyy, izz", missing[0])
                continue
            bad = [k for k in ("length", "e", "g", "area") if vals[k] <= 0]
            if bad:
                pc.error(el.loc, f"{bad[0]} = {vals[bad[0]]}; expected a positive value", bad[0])
                continue
            K = beam_stiffness(vals["length"], vals["e"], vals["g"], vals["area"], vals["ixx"],
                               vals["iyy"], vals["izz"], vals["asy"] or 0.0, vals["asz"] or 0.0)
            L = np.array([vals["length"], 0, 0, 0, 0, 0], float)
        F0 = np.array([g(f"preload_{c}") for c in _C6])
        I, J = ctx.marker(el, "i_marker_id"), ctx.marker(el, "j_marker_id")
        items.append((el, I, J, K, L, F0))
        ctx.effect(el.tag)
    pc.raise_if_any()
    if not items:
        return
    # owners in the shared "forces" output group (after compile_forces' elements)
    first = ctx.extend_output("forces", np.array([it[0].tag for it in items]),
                              [it[0].id for it in items])
    n = len(items)
    owners = list(range(first, first + n))
    f = FieldForce.build("forces:Field", np.array([it[1] for it in items]),
                         np.array([it[2] for it in items]), np.full(n, GLOBAL), owners,
                         group="forces", element_locs=[it[0].loc for it in items],
                         K6=np.array([it[3] for it in items]), L6=np.array([it[4] for it in items]),
                         F06=np.array([it[5] for it in items]),
                         angle_index=np.array([[ctx.angle(it[1], it[2], a) for a in range(3)]
                                               for it in items], int))
    ctx.add_family(f)


ELEMENTS = (ElementType(
    "field_beam", ("Force_Field", "Force_Beam"), compile_field_beam,
    rank=60,                    # extends the "forces" output group after compile_forces
    kernels=lambda: (FieldForce,), tileable=lambda: (FieldForce,),
    potential_energy=kernel_potential, time_dependent=static,
    outputs=(FORCES,),
    reactions={"BEAM": ("forces", ("Force_Beam",)), "FIELD": ("forces", ("Force_Field",))},
    reaction_aliases={"FORCE_BEAM": "BEAM", "FORCE_FIELD": "FIELD"},
    fd_tests="tests/kernels/test_diffs_variables_user_routines.py"),)
