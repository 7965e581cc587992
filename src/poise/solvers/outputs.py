"""Per-frame outputs: body poses, reactions of constraints, element forces."""
from __future__ import annotations

import numpy as np


def element_loads(model, state):
    """Force and torque each element applies to the body of its I marker (at I, global).

    Returns ``{group: (F (n_group, 3), T (n_group, 3))}`` for the groups ``joints``, ``jprims``,
    ``forces`` present in the model. Uses ``state.lam`` for constraint reactions.
    """
    model.evaluate(state, need_jac=False, keep=True)
    out = {}
    for fam, kin, rho in model.last:
        group = getattr(fam, "group", None)
        if group is None or group not in model.outputs:
            continue
        n_out = len(model.outputs[group]["ids"])
        F, T = out.setdefault(group, (np.zeros((n_out, 3)), np.zeros((n_out, 3))))
        S = len(fam.slot_ml)
        rho3 = rho.reshape(fam.n, S, 3)
        Fi = np.zeros((fam.n, 3))
        Ti = np.zeros((fam.n, 3))
        for s in range(S):
            if fam.slot_ml[s] != 0:
                continue
            kind = fam.slot_kind[:, s]
            pt = kind == 0
            Fi[pt] -= rho3[pt, s]
            ax = ~pt
            Ti[ax] -= np.cross(kin.Y[ax, s], rho3[ax, s])
        np.add.at(F, fam.owner, Fi)
        np.add.at(T, fam.owner, Ti)
    return out
