"""No equilibrium, proved: a free rigid motion of the model along which a constant load pushes.

A *free motion* moves groups of bodies rigidly (each group by one constant screw: a translation,
a rotation or both) so that no constraint equation changes and nothing resists. When the
applied loads do work ``w != 0`` per unit of such a motion, ``w`` is the same at every
configuration and the virtual work along the motion can never vanish: no equilibrium exists,
and no strategy can find one. :func:`probe` (at Newton's first iteration, with Newton's
factorisation) and :func:`candidate` (with its own) propose the direction: the part of a
regularised Newton step that only the ``stability`` mass term carries, i.e. the null space of
the constrained tangent stiffness loaded by the residual; :func:`certify` proves it or returns
"". The argument, the element types it holds for and why each check is needed:
docs/solvers.md, "No equilibrium".
"""
from __future__ import annotations

import numpy as np

from poise.core.errors import EvaluationError
from poise.elements.registry import kernel_types
from poise.solvers.history import History
from poise.solvers.downhill import unit_name
from poise.solvers.linalg import SingularMatrix
from poise.solvers.newton import Scales
from poise.solvers.reach import assemble
from poise.solvers.steps import mass_times

#: Element types whose laws are polynomial or analytic in the marker poses and never switch on
#: along a motion (contacts, expressions, user routines, curves and scalar unknowns may).
ANALYTIC = frozenset({"gravity", "joints", "forces", "motions", "couplers", "gears",
                      "field_beam", "screw", "rack_pinion"})
SHARE = 0.1                  # the mass term carries this share of the residual: a free direction
STILL = 1e-6                 # a body slower than this x the fastest one does not move
SAME = 1e-6                  # twists closer than this (relative) belong to one group
TRANSLATIONS = (1e-3, 0.37, 1.0, 3.3, 10.0, 100.0, 1000.0)    # sample distances x L
TURNS = (1e-3, 0.37, 1.1, 2.3, 3.9, 5.2, 8.6)                   # sample angles [rad]
LOAD_REL = 1e-9              # a load differing by more than this (relative) is not constant
POSE_REL = 1e-7              # the same at configurations assembled to the position tolerance
OTHER_POSES = 2              # configurations off the motion where the load is checked too
OFF_SIZE = 0.05              # their distance from the input (x each body's size, rad)


def probe(model, state, settings, cnt, f, x, eps, zinf) -> str:
    """Newton's first step ``x`` (factorisation ``f`` of ``K + eps M`` with the constraints):
    when the ``eps M`` term carries at least ``SHARE`` of the scaled residual ``zinf``, its
    free part is certified (:func:`certify`). Returns the message, or ""."""
    if not eps > 0 or model.nq == 0:
        return ""
    sc = Scales(model, settings)
    reg = eps * mass_times(model, state, x[:model.nq])
    if not float(np.maximum.reduce(np.abs(reg) / sc.r_tol)) >= SHARE * max(zinf, 1e-300):
        return ""
    return certify(model, state, settings, cnt, _free_part(model, state, f, x, eps))


def candidate(model, state, settings, cnt) -> str:
    """:func:`certify` the free part of a regularised Newton step from ``state`` made with
    its own factorisation (plain Newton failed before trying, e.g. ``stability`` 0)."""
    if model.nq == 0:
        return ""
    eps = max(float(np.sqrt(settings.stability)), 1e-5)
    try:
        ev = cnt.evaluate(model, state, "jacobian", eps=eps)
        f = cnt.factor(ev.J)
        x = f.solve(-np.concatenate([ev.r, ev.phi]))
    except (EvaluationError, SingularMatrix):
        return ""
    if not np.all(np.isfinite(x)):
        return ""
    return certify(model, state, settings, cnt, _free_part(model, state, f, x, eps))


def _free_part(model, state, f, x, eps):
    """The part of ``x`` along directions without stiffness: ``x - (I - S)(I + 2S) x`` with
    ``S = eps A^-1 M`` (1 along zero stiffness, ``O(eps / stiffness)`` elsewhere)."""
    nq = model.nq
    pad = np.zeros(len(x) - nq)
    try:
        Sx = f.solve(np.concatenate([eps * mass_times(model, state, x[:nq]), pad]))
        z = x + 2.0 * Sx
        Sz = f.solve(np.concatenate([eps * mass_times(model, state, z[:nq]), pad]))
    except SingularMatrix:
        return x[:nq]
    v = (x - z + Sz)[:nq]
    return v if np.all(np.isfinite(v)) else x[:nq]


class _Motion:
    """Per-body constant screws (spatial twists ``(w, v0)``: a point ``p`` of the body moves
    with velocity ``v0 + w x p``), the groups of bodies sharing one, and the tangent vector of
    the motion at any configuration."""

    def __init__(self, model, w, v0, group, pos):
        self.model, self.w, self.v0, self.group, self.pos = model, w, v0, group, pos
        self.moving = np.nonzero(group >= 0)[0]

    def tangent(self, state):
        m = self.model
        dq = np.zeros(m.nq)
        dt = self.v0 + np.cross(self.w, state.pos)
        dq[m.trans_idx] = dt.ravel()
        if len(m.rot_idx):
            dq[m.rot_idx] = self.w[m.rot_body].ravel()
        return dq

    def turning(self) -> bool:
        return bool(np.any(np.abs(self.w) > 0))

    def translation_only(self):
        """The same groups translating with their mass centre's velocity."""
        m = self.model
        w = np.zeros_like(self.w)
        v0 = np.zeros_like(self.v0)
        for g in np.unique(self.group[self.moving]):
            b = np.nonzero(self.group == g)[0]
            mass = m.body_mass[b]
            c = (mass @ self.pos[b]) / max(float(mass.sum()), 1e-300)
            v0[b] = self.v0[b[0]] + np.cross(self.w[b[0]], c)
        return _Motion(m, w, v0, self.group, self.pos).unit()

    def split(self):
        """Each group's screw as its two free parts: the slide along its axis (every point
        moves by the same ``(w.v0) w / |w|^2``) and the pure turn about it (a cylindrical
        joint's body: the slide carries a constant load, the turn a changing one)."""
        n2 = np.maximum(np.sum(self.w * self.w, axis=1), 1e-300)[:, None]
        slide = np.sum(self.w * self.v0, axis=1)[:, None] / n2 * self.w
        out = []
        if np.any(np.abs(slide) > 0):
            for part in (_Motion(self.model, np.zeros_like(self.w), slide, self.group, self.pos),
                         _Motion(self.model, self.w, self.v0 - slide, self.group, self.pos)):
                if part.top() > SAME * self.top():      # a part at round-off is no motion
                    out.append(part.unit())
        return out

    def top(self) -> float:
        """The fastest speed of the motion (a turn's by the model size L)."""
        b = self.moving
        v = self.v0[b] + np.cross(self.w[b], self.pos[b])
        return float(max(np.max(np.linalg.norm(v, axis=1), initial=0.0),
                         np.max(np.linalg.norm(self.w[b], axis=1), initial=0.0) * self.model.L))

    def unit(self):
        """The same motion at unit fastest speed: sample distances and the constraint
        tolerance then mean lengths, whatever share of the step the motion was."""
        t = self.top()
        return _Motion(self.model, self.w / t, self.v0 / t, self.group, self.pos) if t > 0 else self


def _snap(model, state, dq):
    """Group the bodies of the tangent vector ``dq`` by their screw; None when it is not a
    rigid motion of body groups (scalar unknowns move, a point body in a turning group)."""
    nb = model.nb
    if nb == 0:
        return None
    dt = dq[model.trans_idx].reshape(-1, 3)
    w = np.zeros((nb, 3))
    if len(model.rot_idx):
        w[model.rot_body] = dq[model.rot_idx].reshape(-1, 3)
    speed = np.maximum(np.linalg.norm(dt, axis=1), np.linalg.norm(w, axis=1) * model.L)
    top = float(speed.max())
    if not (np.isfinite(top) and top > 0):
        return None
    if model.n_extra and float(np.max(np.abs(dq[model.extra_idx]))) > STILL * top:
        return None
    # a rotation at the rounding level of the step is none (its split or lever would make a
    # motion of its own out of round-off)
    w[np.linalg.norm(w, axis=1) * model.L <= SAME * top] = 0.0
    v0 = dt - np.cross(w, state.pos)
    reach = top + float(np.max(np.linalg.norm(w, axis=1))) * float(
        np.max(np.linalg.norm(state.pos, axis=1)))
    group = np.full(nb, -1)
    reps = []
    for b in np.nonzero(speed > STILL * top)[0]:
        for k, (wr, vr) in enumerate(reps):
            if (np.linalg.norm(w[b] - wr) * model.L <= SAME * top
                    and np.linalg.norm(v0[b] - vr) <= SAME * reach):
                group[b] = k
                break
        else:
            group[b] = len(reps)
            reps.append((w[b], v0[b]))
    W = np.zeros((nb, 3))
    V = np.zeros((nb, 3))
    for k in range(len(reps)):
        b = np.nonzero(group == k)[0]
        W[b] = w[b].mean(axis=0)
        V[b] = v0[b].mean(axis=0)
    point = model.body_kind == 1
    if np.any(point & (group >= 0) & (np.linalg.norm(W, axis=1) > 0)):
        return None
    return _Motion(model, W / top, V / top, group, state.pos.copy())


def _acting(model, mo) -> str:
    """Why an element acting on a moving body may stop the motion somewhere the samples do
    not see, or "": every element touching a moving body must be of an :data:`ANALYTIC`
    type (its law cannot switch on between the samples)."""
    owners = kernel_types()
    grp = np.append(mo.group, -1)          # ground and the global frame: index nb
    for fam in model.families:
        if fam.n == 0:
            continue
        touch = np.any(grp[np.asarray(model.marker_body)[fam.markers]] >= 0, axis=1)
        if touch.any():
            name = getattr(owners.get(type(fam)), "name", "?")
            if name not in ANALYTIC:
                return f"{name} elements act on a moving body"
    return ""


def _load(model, cnt, state, mo):
    """Work of the applied loads per unit of the motion at ``state`` (multipliers do none)."""
    st = state.copy()
    st.lam = np.zeros_like(st.lam)
    ev = cnt.evaluate(model, st, "residual")
    return -float(ev.r @ mo.tangent(st)), ev


def _along(model, cnt, state, mo, sc, w0, phi0, samples, rel=LOAD_REL) -> bool:
    """The constraints keep their values and the load its work ``w0`` (to ``rel``) at
    ``samples`` along the motion from ``state``."""
    v = mo.tangent(state)
    for s in samples:
        for sg in (1.0, -1.0):
            q = model.retract(state, sg * s * v)
            w, ev = _load(model, cnt, q, mo)
            if not abs(w - w0) <= rel * abs(w0):
                return False
            if ev.phi.size and np.any(np.abs(ev.phi - phi0) > sc.phi_tol):
                return False
    return True


def certify(model, state, settings, cnt, dq) -> str:
    """A message proving that no equilibrium exists, from the candidate tangent ``dq`` (nq,),
    or "" (not proved: the caller goes on). See the module docstring."""
    mo = _snap(model, state, np.asarray(dq, float))
    if mo is None:
        return ""
    for motion in [mo, mo.translation_only(), *mo.split()] if mo.turning() else (mo,):
        try:
            why = _certify(model, state, settings, cnt, motion)
        except (EvaluationError, SingularMatrix, FloatingPointError):
            why = ""
        if why:
            return why
    return ""


def _certify(model, state, settings, cnt, mo) -> str:
    if _acting(model, mo):
        return ""
    sc = Scales(model, settings)
    w0, ev0 = _load(model, cnt, state, mo)
    v = mo.tangent(state)
    # a load every configuration meets within tolerance is no reason to fail
    if not abs(w0) > float(np.sum(np.abs(v) * sc.r_tol)):
        return ""
    if mo.turning():
        samples = tuple(a / float(np.max(np.linalg.norm(mo.w, axis=1))) for a in TURNS)
    else:
        samples = tuple(x * model.L for x in TRANSLATIONS)
    if not _along(model, cnt, state, mo, sc, w0, ev0.phi, samples):
        return ""
    # other configurations: the load must not depend on where the rest of the model stands
    rng = np.random.default_rng(12345)
    scale = np.ones(model.nq)                 # each body's own size for its translations
    scale[model.trans_idx] = np.repeat(model.body_scale, 3)
    scratch = History()
    for _ in range(OTHER_POSES):
        off = rng.standard_normal(model.nq) * OFF_SIZE * scale
        q = model.retract(state, off)
        q, _, st = assemble(model, q, settings, scratch, 0, cnt)
        if not st.ok:
            continue
        w1, ev1 = _load(model, cnt, q, mo)
        if not abs(w1 - w0) <= POSE_REL * abs(w0):
            return ""
        if not _along(model, cnt, q, mo, sc, w1, ev1.phi, samples[1:4], POSE_REL):
            return ""
    return _describe(model, state, mo, w0)


def _describe(model, state, mo, w0) -> str:
    """Names the moving bodies, the motion and the load (deck units). Several rigid groups
    (a rack falling and its pinion turning): the lead group's motion (the fastest sliding one,
    else the fastest turning one), how far each other group moves per unit of it, and the
    load as the force (moment) conjugate to the lead motion."""
    b = mo.moving
    ids = [int(model.body_id[i]) for i in b]
    who = (f"{_where(model, b[0])} is free to" if len(b) == 1 else
           f"bodies {_ranges(ids)} ({len(b)} bodies, first {_where(model, b[0])}) are free to")
    first = [int(np.nonzero(mo.group == g)[0][0]) for g in np.unique(mo.group[b])]
    slides = [g for g in first if not np.any(mo.w[g])]
    lead = (max(slides, key=lambda g: np.linalg.norm(mo.v0[g])) if slides else
            max(first, key=lambda g: np.linalg.norm(mo.w[g])))
    how, rate = _screw(model, mo.w[lead], mo.v0[lead])
    force, length = unit_name(model, "force"), unit_name(model, "length")
    if len(first) > 1:
        rest = [_follows(model, g, mo.w[g] / rate, mo.v0[g] / rate, length)
                for g in first if g != lead]
        more = f" and {len(rest) - 3} more groups" if len(rest) > 3 else ""
        per = length if slides else "radian"
        how = (f"move together, as {_name(model, lead)} {_screw(model, mo.w[lead], mo.v0[lead], 's')[0]} "
               f"and, per {per} of it, {', '.join(rest[:3])}{more}")
    if slides:
        load = f"a constant load of {w0 / rate:.6g} {force} pushes it"
    else:
        load = f"a constant moment of {w0 / rate:.6g} {force}*{length} turns it"
    return (f"{who} {how}: no constraint or force resists that motion anywhere along it, and "
            f"{load}: add the joint, spring or stop that should hold it, or balance the load")


def _where(model, body) -> str:
    """The body's located name (``FILE:LINE: <Body_Rigid id=2>``)."""
    return model.coord_info[int(model.body_off[body])].rsplit(" ", 1)[0]


def _name(model, body) -> str:
    """The body's name without its location (``<Body_Rigid id=2>``, ``PART/2``)."""
    return _where(model, body).rsplit(": ", 1)[-1]


def _screw(model, w, v0, s=""):
    """``(words, rate)``: the motion of one rigid group with twist ``(w, v0)`` (verbs in the
    infinitive, or the third person with ``s="s"``) and its rate (speed of a slide, angular
    speed of a turn)."""
    n = float(np.linalg.norm(w))
    if n == 0:
        rate = float(np.linalg.norm(v0))
        return f"translate{s} along ({_v(v0 / rate)})", rate
    return f"turn{s} about {_axis(model, w, v0)}", n


def _follows(model, g, w, v0, length) -> str:
    """How far the group of body ``g`` moves with twist ``(w, v0)`` per unit of the lead's."""
    n = float(np.linalg.norm(w))
    if n == 0:
        d = float(np.linalg.norm(v0))
        return f"{_name(model, g)} moves {d:.6g} {length} along ({_v(v0 / d)})"
    return f"{_name(model, g)} turns {n:.6g} rad about {_axis(model, w, v0)}"


def _axis(model, w, v0) -> str:
    n = float(np.linalg.norm(w))
    p = np.cross(w, v0) / (n * n)
    pitch = float(w @ v0) / (n * n)
    how = f"the axis ({_v(w / n)}) through ({_v(p)})"
    if abs(pitch) > 1e-9 * model.L:
        how += f", advancing {pitch:.6g} per radian"
    return how


def _v(x) -> str:
    return ", ".join(f"{float(c):.6g}" for c in np.where(np.abs(x) < 1e-12, 0.0, x))


def _ranges(ids) -> str:
    ids = sorted(ids)
    out, start, prev = [], ids[0], ids[0]
    for i in ids[1:] + [None]:
        if i is not None and i == prev + 1:
            prev = i
            continue
        out.append(str(start) if start == prev else f"{start}-{prev}")
        if i is not None:
            start = prev = i
    return ", ".join(out) if len(out) <= 4 else ", ".join(out[:4]) + ", ..."
