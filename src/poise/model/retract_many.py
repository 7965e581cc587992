"""``Model.retract`` and Newton's step limits for many states of one model at once.

A sweep's cases solved together (:mod:`poise.solvers.batched`) move ``C`` states of one model
per trial; one Python retraction per case would cost more than the batched evaluation. These
functions do per case exactly what :meth:`poise.model.model.Model.retract` and
:func:`poise.solvers.steps.limit_step` do (the same sub-steps of at most
``MAX_SUBSTEP_ROTATION`` per case, the same continuous-angle unwrapping and rotation-vector
tracking), with the case as a leading axis.
"""
from __future__ import annotations

import numpy as np

from poise.elements.rotation import expm_so3, se3_left_jacobian, wrap_angle
from poise.model.model import MAX_SUBSTEP_ROTATION, State, principal_angles


def retract_many(model, states: list, dq: np.ndarray, dlam: np.ndarray | None = None) -> list:
    """``[model.retract(s, dq[c], dlam[c]) for c, s in enumerate(states)]``, batched."""
    C = len(states)
    if not C:
        return []
    pos = np.stack([s.pos for s in states])
    rot = np.stack([s.rot for s in states])
    ang = np.stack([s.angle for s in states])
    dq = np.asarray(dq, float)
    nb = model.nb
    rb = model.rot_body
    dt = dq[:, model.trans_idx].reshape(C, -1, 3)
    dr = dq[:, model.rot_idx].reshape(C, -1, 3) if len(model.rot_idx) else np.zeros((C, 0, 3))
    big = np.linalg.norm(dr, axis=2).max(axis=1) if dr.shape[1] else np.zeros(C)
    if len(model.angle_I):
        nsub = np.maximum(1, np.ceil(big / MAX_SUBSTEP_ROTATION).astype(int))
    else:
        nsub = np.ones(C, int)
    new_pos, new_rot, new_ang = pos.copy(), rot.copy(), ang.copy()
    ns = nsub.astype(float)
    w = dr / ns[:, None, None]
    if len(rb):
        v0 = (dt[:, rb] - np.cross(dr, pos[:, rb])) / ns[:, None, None]
        E = expm_so3(w)
        Vv = np.einsum("cnij,cnj->cni", se3_left_jacobian(w), v0)
    pt = np.ones(nb, bool)
    pt[rb] = False
    for k in range(int(nsub.max())):
        on = nsub > k
        if pt.any():
            sel = np.nonzero(on)[0]
            new_pos[np.ix_(sel, np.nonzero(pt)[0])] += dt[sel][:, pt] / ns[sel, None, None]
        if len(rb):
            sel = np.nonzero(on)[0]
            p = new_pos[sel][:, rb]
            new_pos[np.ix_(sel, rb)] = np.einsum("cnij,cnj->cni", E[sel], p) + Vv[sel]
            new_rot[np.ix_(sel, rb)] = np.matmul(E[sel], new_rot[sel][:, rb])
        if len(model.angle_I):
            sel = np.nonzero(on)[0]
            mb = model.marker_body
            rx = np.zeros((len(sel), nb + 1, 3, 3))
            rx[:, :nb] = new_rot[sel]
            rx[:, nb] = np.eye(3)
            A = np.matmul(rx[:, mb], model.marker_A0)
            p = principal_angles(A, model.angle_I, model.angle_J, model.angle_axis)
            new_ang[sel] = new_ang[sel] + wrap_angle(p - new_ang[sel])
    out = []
    for c, s in enumerate(states):
        n = State(new_pos[c], new_rot[c], s.lam + dlam[c] if dlam is not None else s.lam.copy(),
                  new_ang[c], s.t, None if s.extra is None else s.extra.copy(),
                  None if s.rotvec is None else s.rotvec.copy(), s.rotvec_drift)
        if model.n_extra:
            n.extra = s.extra + dq[c, model.extra_idx]
        out.append(n)
    _track(model, out, states, dr)
    return out


def _track(model, new: list, old: list, w: np.ndarray) -> None:
    """``Model.track_rotation`` of every state (exact rotation vectors recomputed together)."""
    rb = model.rot_body
    if not len(rb):
        return
    have = [c for c, o in enumerate(old) if o.rotvec is not None]
    for c, o in enumerate(old):
        if o.rotvec is None:
            new[c].rotvec = None
    if not have:
        return
    rv = np.stack([old[c].rotvec for c in have])
    rv[:, rb] += w[have]
    drift = np.array([old[c].rotvec_drift for c in have]) + np.sqrt(
        (w[have] * w[have]).sum(2).max(axis=1))
    again = []
    for k, c in enumerate(have):
        new[c].rotvec = rv[k]
        new[c].rotvec_drift = float(drift[k])
        if drift[k] > np.pi / 2:
            again.append(c)
    if again:
        rot = np.stack([new[c].rot for c in again])
        rv = np.stack([new[c].rotvec for c in again])
        exact = model.rotation_from_input(None, rot, rv)
        for k, c in enumerate(again):
            new[c].rotvec = exact[k]
            new[c].rotvec_drift = 0.0


def limit_many(model, states: list, dq: np.ndarray, settings):
    """``limit_step`` per case: ``(factors (C,), [accepted configuration or None])``."""
    C = len(states)
    fac = np.ones(C)
    if len(model.rot_idx):
        r = dq[:, model.rot_idx].reshape(C, -1, 3)
        mr = np.linalg.norm(r, axis=2).max(axis=1)
        over = mr > settings.max_rotation_step
        fac[over] = settings.max_rotation_step / mr[over]
    lim = settings.max_translation_step * model.L
    out: list = [None] * C
    todo = np.arange(C)
    for _ in range(4):
        if not len(todo):
            break
        trial = retract_many(model, [states[c] for c in todo], fac[todo, None] * dq[todo])
        if model.nb:
            moved = np.stack([t.pos for t in trial]) - np.stack([states[c].pos for c in todo])
            disp = np.linalg.norm(moved, axis=2).max(axis=1)
        else:
            disp = np.zeros(len(todo))
        fine = disp <= lim * 1.0001
        for k in np.nonzero(fine)[0]:
            out[todo[k]] = trial[k]
        over = todo[~fine]
        fac[over] *= 0.9 * lim / disp[~fine]
        todo = over
    return fac, out


__all__ = ["retract_many", "limit_many"]
