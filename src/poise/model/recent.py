"""The evaluations a solve keeps for reuse: the family outputs of its last states.

A solve evaluates some states more than once: Newton's last iterate again for the redundant-row
check and the output measures (only the active-row mask, the mass shift and the assembly
differ), Newton's first iterate at the start's configuration with new multipliers (the forces
and slot kinematics are the same), the static prologue's start. For models with no reaction
feed the solve's workspace keeps the kernel outputs of the last states (two for a model
assembled dense, one for a sparse one: its outputs are large, and Newton holds that one anyway
while it is its iterate or trial; once its Jacobian is assembled only its constraint values
stay, except after a constraint-Jacobian-only ``"phi_q"`` assembly: the static prologue's
start, whose forces and slot kinematics Newton's first iterate reuses), keyed by the bytes of
everything a kernel reads (time, positions, axes, multipliers, angles, scalar unknowns): a hit
is bitwise the evaluation it skips.
"""
from __future__ import annotations


class RecentEvaluations:
    """The family outputs of a model's last evaluated states (a solve's workspace keeps
    one, :func:`poise.model.evaluate.evaluate` fills and reads it; see the module doc)."""

    __slots__ = ("entries", "model", "size")
    SIZE = 2           # states kept for a dense model (one for a sparse one)

    def __init__(self):
        self.entries = []
        self.model = None
        self.size = self.SIZE

    def of(self, model):
        """This memo for ``model`` (emptied when the workspace evaluates another model)."""
        if self.model is not model:
            self.model, self.entries = model, []
            self.size = self.SIZE if model.assembler.dense else 1
        return self

    def phi(self, state):
        """The all-row constraint values kept for ``state`` (a copy), or None."""
        if not self.entries:
            return None
        key = self.key(state)
        for k, _, out in self.entries:
            if k == key:
                return out[1].copy()
        return None

    def release(self):
        """Keep only the constraint values of a sparse model's entries (its Jacobian has been
        assembled: the kernel outputs would sit beside the factorisation, ~100 MB at 10^5
        links, where a solve without this memo has freed them)."""
        if self.size == 1:
            self.entries = [(k, None, (None, out[1])) for k, _, out in self.entries]

    def outputs(self, fr, need_jac, kernel, compute):
        """``(r, phi, pend, items)`` at the one state of ``fr`` (``pend`` with the Jacobian's
        kernel outputs when ``need_jac``): kept ones (``r``, ``phi`` copied), else
        ``compute(call)`` (:func:`poise.model.evaluate._family_outputs` with :meth:`caller`),
        kept."""
        key = self.key(fr.states[0])
        hit = self.get(key, need_jac)
        if hit is not None:
            r, phi, pend, last = hit[:4]
            return r.copy(), phi.copy(), pend, last
        calls = {}
        out = compute(self.caller(fr, kernel, self.same_pose(key, need_jac), calls))
        self.put(key, need_jac, *out, calls)
        return out

    def caller(self, fr, kernel, reuse, calls):
        """``fr.call`` that takes ``(t, kin, lam, out)`` from ``reuse`` (an evaluation at the
        same pose, only the multipliers differ: forces as they are, constraint kernels run
        again on the same slot kinematics) and records every call in ``calls``."""
        def call(fi, need_jac):
            hit = None if reuse is None else reuse.get(fi)
            if hit is None:
                got = fr.call(fi, need_jac)
            elif self.model.families[fi].is_constraint:
                t, kin = hit[0], hit[1]
                lam = fr.lam[t.crow]
                got = (t, kin, lam, kernel(t, kin, lam, fr.ctx, need_jac))
            else:
                got = hit
            calls[fi] = got
            return got
        return call

    @staticmethod
    def key(s):
        return (float(s.t), s.pos.tobytes(), s.rot.tobytes(), s.lam.tobytes(),
                s.angle.tobytes(), None if s.extra is None else s.extra.tobytes())

    def get(self, key, need_jac):
        for k, jac, out in self.entries:       # jac None: released (constraint values only)
            if jac is not None and (jac or not need_jac) and k == key:
                return out
        return None

    def same_pose(self, key, need_jac):
        """The kernel calls (``fi -> (t, kin, lam, out)``) of an entry that differs from
        ``key`` only in the multipliers (Newton's first iterate after the initial multipliers:
        forces and slot kinematics are the same), or None."""
        pose = key[:3] + key[4:]
        for k, jac, out in self.entries:
            if jac is not None and (jac or not need_jac) and k[:3] + k[4:] == pose:
                return out[4]
        return None

    def put(self, key, need_jac, *out):
        kept = [e for e in self.entries if e[0] != key]
        self.entries = kept[max(0, len(kept) + 1 - self.size):]
        self.entries.append((key, need_jac, out))
