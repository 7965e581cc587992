"""Reaction channels: element forces and resultants read by expressions, evaluated exactly.

A channel (registered by :class:`poise.elements.resolver.ModelResolver`) is an element-force
function ``KIND(id, jflag, comp, RM)`` or a resultant ``FX(I, J, RM)``...; its value comes from
the element loads (:func:`poise.elements.loads.element_loads`: force and torque on I at the I
origin, global) resolved in RM's axes. :class:`ChannelPlan` evaluates many channels at once;
:class:`ExprInfo` keeps element marker indices and plans per model.
"""
from __future__ import annotations

import numpy as np

from poise.elements.base import GLOBAL
from poise.elements.loads import element_loads
from poise.core.errors import EvaluationError

def channel_values(model, state, plan, loads=None, P=None, A=None):
    """Values of the reaction channels of ``plan`` (a :class:`ChannelPlan`) at ``state``
    (exact, from ``state.lam``).

    Loads come from :func:`poise.elements.loads.element_loads` (force/torque on I at the I
    origin, global); ``jflag=1`` gives the equal and opposite action on J about the J origin;
    components are resolved in marker RM's axes (0 = global). ``loads``/``P``/``A`` given:
    used instead of evaluating the model at ``state``.
    """
    if not plan.n:
        return np.zeros(0)
    if loads is None:
        loads = element_loads(model, state)
    if P is None:
        P, A, _ = model.marker_kinematics(state)
    return plan.evaluate(loads, P, A)


def _component_picks(comps):
    """Split channel components 1..8 into picks of the stacked ``(F, T)`` 6-vector (2-4 Fx Fy Fz,
    6-8 Tx Ty Tz) and magnitudes (1 |F|, 5 |T|). Returns ``(pick rows, pick index,
    magnitude rows, magnitude (rows, 3) columns)``."""
    c = np.asarray(comps, np.intp).reshape(-1)
    mag = (c == 1) | (c == 5)
    ck = np.nonzero(~mag)[0]
    mk = np.nonzero(mag)[0]
    crow = np.where(c[ck] <= 4, c[ck] - 2, c[ck] - 3)
    mcols = np.where(c[mk] == 1, 0, 3)[:, None] + np.arange(3)
    return ck, crow, mk, mcols


def resultant_side(mi, mj, ei, ej):
    """Whether the element with markers ``(ei, ej)`` is in the resultant FX..TM at marker ``mi``
    (towards ``mj``, < 0: any): 0 taken on its I, 1 on its J (flipped), None if not in it."""
    if ei == mi and (mj < 0 or ej == mj):
        return 0
    if ej == mi and (mj < 0 or ei == mj):
        return 1
    return None


class ChannelPlan:
    """Reaction channels as index arrays (compile time, O(channels + contributions)): per
    output group the ``(channel, owner row)`` contributions in the order of the per-channel sums
    (an element-force function: its element; a resultant FX..TM: every element whose marker
    pair matches) with the contributions taken on J (``-F`` and ``-T - (P_I - P_J) x F``: jflag 1,
    or a resultant at the element's J marker), the RM markers and the component picks.
    :meth:`evaluate` does O(groups) Python work."""

    def __init__(self, model, channels, info):
        owners = info.owners
        self.channels = list(channels)
        n = self.n = len(self.channels)
        elems, by_mk = [], {}                         # every output element, group order
        for group, omap in owners.items():
            for key, o in omap.items():
                ei, ej = info.markers[key]
                by_mk.setdefault(ei, []).append(len(elems))
                if ej != ei:
                    by_mk.setdefault(ej, []).append(len(elems))
                elems.append((group, o, ei, ej))
        con = {g: [] for g in owners}                 # group -> [(k, o, flip, ei, ej)]
        self.el_first = {}       # group -> first element-force channel reading it
        self.missing = None      # first element-force channel without an output row
        rm, comp = np.zeros(n, np.intp), np.zeros(n, np.intp)
        for k, ch in enumerate(self.channels):
            if ch[0] == "EL":
                _, group, tag, id, jflag, comp[k], rm[k] = ch
                o = owners.get(group, {}).get((tag, id))
                if o is None:
                    self.missing = k if self.missing is None else self.missing
                    continue
                self.el_first.setdefault(group, k)
                ei, ej = info.markers[(tag, id)]
                con[group].append((k, o, bool(jflag), ei, ej))
            else:
                _, mi, mj, comp[k], rm[k], _ = ch
                for e in by_mk.get(mi, ()):
                    group, o, ei, ej = elems[e]
                    side = resultant_side(mi, mj, ei, ej)
                    if side is not None:
                        con[group].append((k, o, side, ei, ej))
        self.groups = []
        for group, lst in con.items():
            if not lst:
                continue
            # a channel's contributions stay in element order: np.add.at sums them in the
            # order of the former per-element loop
            a = np.array(lst, np.intp)
            fl = np.nonzero(a[:, 2])[0]
            self.groups.append((group, a[:, 0], a[:, 1], fl, a[fl, 3], a[fl, 4]))
        self.rk = np.nonzero(rm != GLOBAL)[0]
        self.rm = rm[self.rk]
        self.ck, self.crow, self.mk, self.mcols = _component_picks(comp)

    def evaluate(self, loads, P, A):
        """Channel values (n,) from ``element_loads``-style ``loads`` and marker ``P``, ``A``."""
        return self.pick(self.vectors(loads, P, A))

    def pick(self, D):
        """Channel values (n,) from their :meth:`vectors` ``D``."""
        out = np.empty(self.n)
        out[self.ck] = D[self.ck, self.crow]
        if len(self.mk):
            out[self.mk] = np.linalg.norm(D[self.mk[:, None], self.mcols], axis=1)
        return out

    def vectors(self, loads, P, A, glob=False):
        """(n, 6): each channel's force and torque ``(F, T)`` in its RM's axes; ``glob``: also
        the same vectors in global axes (before the RM resolution)."""
        bad = [k for g, k in self.el_first.items() if g not in loads]
        if self.missing is not None:
            bad.append(self.missing)
        if bad:
            _, group, tag, id = self.channels[min(bad)][:4]
            raise EvaluationError(f"no reaction output for <{tag} id={id}> "
                                  f"(group {group!r} not compiled)")
        Fs = np.zeros((self.n, 3))
        Ts = np.zeros((self.n, 3))
        for group, k, o, fl, ei, ej in self.groups:
            if group not in loads:
                continue
            F = loads[group][0][o]
            T = loads[group][1][o]
            if len(fl):
                Ff = F[fl]
                T[fl] = -T[fl] - np.cross(P[ei] - P[ej], Ff)
                F[fl] = -Ff
            np.add.at(Fs, k, F)
            np.add.at(Ts, k, T)
        Dg = np.concatenate([Fs, Ts], axis=1) if glob else None
        if len(self.rk):                              # components along RM's axes
            Ar = A[self.rm]
            Fs[self.rk] = np.matmul(Fs[self.rk][:, None, :], Ar)[:, 0]
            Ts[self.rk] = np.matmul(Ts[self.rk][:, None, :], Ar)[:, 0]
        D = np.concatenate([Fs, Ts], axis=1)
        return (D, Dg) if glob else D


class ExprInfo:
    """Per output group the owner row of every element, ``owners[group][(tag, id)]``, and the
    compiled (I, J) markers of every output element, ``markers[(tag, id)]``: built once with
    the model from its output groups and ``element_markers(tag, id)``."""

    __slots__ = ("owners", "markers")

    def __init__(self, outputs, element_markers):
        om, markers = {}, {}
        for group, o in outputs.items():
            ids = np.asarray(o["ids"])
            tags = o.get("tag")
            if tags is None or np.ndim(tags) == 0:
                tags = [str(tags) if tags is not None else ""] * len(ids)
            om[group] = {}
            for k, (t, i) in enumerate(zip(tags, ids)):
                key = (str(t), int(i))
                om[group][key] = k
                if key not in markers:
                    markers[key] = element_markers(*key)
        self.owners, self.markers = om, markers

    def plan(self, model, channels) -> ChannelPlan:
        """The :class:`ChannelPlan` of ``channels`` (build it once and keep it)."""
        return ChannelPlan(model, tuple(channels), self)
