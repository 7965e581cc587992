"""Gravity (``Force_Gravity``): a uniform acceleration ``g`` acting on every moving body at its CG.

``g`` is constant or a function of TIME (``grav_x/y/z`` expressions, possibly through variables
and splines; an expression reading the state is a located error: that is a Force_Vector). The
last ``Force_Gravity`` of the deck counts (a command may add or change it, model/commands.py).
One family instance per moving body, one point slot at its CG marker: ``rho = -m g`` on the
body's translation. The lever from the CG is zero, so gravity adds no moment and no stiffness
(``G`` declared empty). Potential energy ``-m g . P_cg`` at the frame's time. The family is
evaluated after every other (``eval_last``): the residual is then summed in the order it had
when gravity was a special case of the evaluation, which keeps results files byte-identical.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.deck.spec import Expr
from poise.elements.base import ForceFamily
from poise.elements.context import num
from poise.elements.registry import (ElementType, FDCase, batch_time_sources,
                                     kernel_potential)
from poise.elements.resolver import compile_batch_located
from poise.expr import EvalContext

ATTRS = ("grav_x", "grav_y", "grav_z")


@dataclass(frozen=True, eq=False, kw_only=True)
class GravityLoad(ForceFamily):
    """``rho = -m g`` at each body's CG marker. ``mass`` (n,) effective body masses; ``g``
    (1, 3) constant acceleration (one row: the frame tiler repeats only per-instance arrays),
    or ``batch``: the three components as TIME-only expressions."""

    eval_last = True
    mass: np.ndarray
    g: np.ndarray | None = None
    batch: object = None

    def g_blocks(self):
        return np.zeros((1, 1), bool)        # a constant load: no tangent

    def zero_lever(self):
        return np.ones(1, bool)              # at the CG marker: no moment, no connection term

    def acceleration(self, t) -> np.ndarray:
        """``g`` per instance, (n, 3) or (1, 3); ``t`` one time or one per frame of a tiled
        copy (instances frame-major)."""
        if self.batch is None:
            return self.g
        ts = np.atleast_1d(np.asarray(t, float))
        gs = np.array([np.asarray(self.batch.evaluate(EvalContext(t=float(x))).value, float)
                       for x in ts]).reshape(len(ts), 3)
        return np.repeat(gs, self.n // len(ts), axis=0)

    def forces(self, kin, ctx, need_jac=True):
        return -(self.mass[:, None] * self.acceleration(ctx.t)), None

    def potential_energy(self, kin, ctx):
        """``-m g . P`` per instance and component (the energy pass sums them)."""
        return -(self.mass[:, None] * kin.Y[:, 0] * self.acceleration(ctx.t))


def compile_gravity(spec, ctx):
    """The deck's last ``Force_Gravity`` as one :class:`GravityLoad` over the moving bodies (none
    when every component is the number 0)."""
    els = spec.elements("Force_Gravity")
    if not els:
        return
    el = els[-1]
    ctx.effect("gravity")
    comps = [el.attrs.get(k, 0.0) for k in ATTRS]
    g, batch = None, None
    if any(isinstance(c, Expr) for c in comps):
        batch = compile_batch_located(comps, ctx.resolver("gravity"), ctx.pc)
        if batch is None:
            return
        if batch.depends_on_state:
            k = int(np.argmax(batch.state_mask))
            ctx.pc.error(el.loc, "gravity may depend on TIME only; for a state-dependent load "
                         "use a Force_Vector_TwoBody", ATTRS[k])
            return
    else:
        g = np.array([num(el, k, 0.0) for k in ATTRS], float).reshape(1, 3)
        if not np.any(g != 0):
            return
    cg, mass = ctx.geometry.body_cg, ctx.geometry.body_mass
    n = len(cg)
    ctx.add_family(GravityLoad(name="gravity", markers=np.asarray(cg, int).reshape(n, 1),
                               slot_ml=np.zeros(1, int), slot_kind=np.zeros((n, 1), int),
                               owner=np.arange(n), mass=np.asarray(mass, float), g=g,
                               batch=batch, element_locs=(el.loc,) * n))


def _time_sources(fam) -> list:
    """``time_dependent``: the component expressions reading TIME."""
    return batch_time_sources([fam.batch])


ELEMENTS = (ElementType(
    "gravity", ("Force_Gravity",), compile_gravity,
    # first: its family leads the model's families (the order in which the potential energy
    # is summed)
    rank=0,
    kernels=lambda: (GravityLoad,), tileable=lambda: (GravityLoad,),
    potential_energy=kernel_potential, time_dependent=_time_sources,
    fd_cases=lambda: (FDCase("Force_Gravity", (("Force_Gravity", {
        "grav_x": 0.7, "grav_y": -9.81, "grav_z": 1.3}),), pairs=((),), marker_attrs=()),)),)
