"""Force and torque each element applies to the body of its I marker, from kept slot data.

The loads of output groups (``joints``, ``forces``, ...) are read by results, by reaction
channels of expressions (:mod:`poise.elements.compile_expr`) and by requests; they depend only
on the element families' slot data, so they live with the elements.
"""
from __future__ import annotations

import numpy as np

from poise.core import per_object
from poise.core.lean import einsum
from poise.elements.kernel import cross3


def element_loads(model, state, lam=None, ev=None):
    """Force and torque each element applies to the body of its I marker (at I, global).

    Returns ``{group: (F (n_group, 3), T (n_group, 3))}`` for the output groups present in the
    model (``joints``, ``jprims``, ``motions``, ``forces``, ...). Constraint reactions use
    ``lam`` (default ``state.lam``). ``ev``: an evaluation of ``state`` made with ``keep=True``
    (its slot data are used instead of evaluating again).
    """
    if ev is None or ev.items is None:
        ev = model.evaluate(state, need_jac=False, keep=True)
    lam = state.lam if lam is None else lam
    return loads_of(model, ev.items, lam)


def loads_of(model, items, lam=None, frames: int = 1):
    """:func:`element_loads` from kept ``(fam, kin, rho, phi_y)`` tuples (``rho`` used as is
    when ``lam`` is None, else ``phi_y^T lam`` for constraint families).

    ``frames > 1``: the items cover that many frames (:func:`poise.model.evaluate.
    evaluate` of a list of states; owners and rows shifted per frame, ``lam`` (frames * nc,)); the arrays
    returned are (frames * n_group, 3), frame-major."""
    out = {}
    for fam, kin, rho, phy in items:
        if phy is not None and lam is not None:
            rho = einsum("nmy,nm->ny", phy, lam[fam.crow])
        group = fam.group
        if group is None or group not in model.outputs:
            continue
        n_out = len(model.outputs[group]["ids"]) * frames
        F, T = out.setdefault(group, (np.zeros((n_out, 3)), np.zeros((n_out, 3))))
        own = getattr(fam, "reaction_on_i", None)   # families reducing several markers
        if own is not None:
            Fi, Ti = own(kin, rho)
            np.add.at(F, fam.owner, Fi)
            np.add.at(T, fam.owner, Ti)
            continue
        S = len(fam.slot_ml)
        rho3 = rho.reshape(fam.n, S, 3)
        Fi = np.zeros((fam.n, 3))
        Ti = np.zeros((fam.n, 3))
        slots, distinct = _layout(fam)
        if any(k == 2 for _, k in slots):   # a slot that is a point in some instances only
            for s, _ in slots:
                pt = fam.slot_kind[:, s] == 0
                Fi[pt] -= rho3[pt, s]
                ax = ~pt
                Ti[ax] -= cross3(kin.Y[ax, s], rho3[ax, s])
        else:                               # each slot's terms in slot order
            axes = [s for s, k in slots if k == 1]
            for s, k in slots:
                if k == 0:
                    Fi -= rho3[:, s]
            if axes:                        # their cross products at once (elementwise)
                C = cross3(kin.Y[:, axes], rho3[:, axes])
                for j in range(len(axes)):
                    Ti -= C[:, j]
        if distinct:           # one instance per owner: add.at's sums, without its slow path
            F[fam.owner] += Fi
            T[fam.owner] += Ti
        else:
            np.add.at(F, fam.owner, Fi)
            np.add.at(T, fam.owner, Ti)
    return out


#: family -> its :func:`_layout` (the family's arrays never change: made once)
_LAYOUTS = per_object.table()


def _layout(fam):
    """``([(slot, kind)], owners distinct)``: the I marker's slots of ``fam`` (``slot_ml ==
    0``), kind 0 a point in every instance, 1 an axis in every instance, 2 either."""
    def make():
        slots = []
        for s in range(len(fam.slot_ml)):
            if fam.slot_ml[s] == 0:
                pt = fam.slot_kind[:, s] == 0
                slots.append((s, 0 if np.logical_and.reduce(pt)
                              else 1 if not np.logical_or.reduce(pt) else 2))
        own = np.asarray(fam.owner).ravel().tolist()     # (np.unique imports numpy.ma)
        return tuple(slots), len(set(own)) == len(own)
    return per_object.once_per(_LAYOUTS, fam, make)
