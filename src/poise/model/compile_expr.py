"""Expressions in the model: the resolver of ``poise.expr`` (CONTRACT.md), expression forces,
time-dependent gravity and ``Post_Request`` outputs.

* :class:`ModelResolver` maps deck ids to compiled indices: marker id -> compiled marker index
  (id 0 -> index 0, the model's global frame), explicit ``Reference_Variable`` -> shared (DAG)
  expression, ``Reference_Spline`` / ``Reference_Array`` -> data parsed from the element text,
  ``AX/AY/AZ`` -> the model's continuous-angle table (``CompileContext.angle``), element-force
  functions (JOINT, JPRIM, MOTION, SFORCE, VFORCE, VTORQ, GFORCE, BUSH, SPDP) and resultants
  (FM, FX, ..., TZ) -> *reaction channels* evaluated by :func:`channel_values`.
* Reaction channels in ``Post_Request`` expressions are evaluated after convergence, exactly,
  from the converged multipliers. Inside expression forces they are evaluated at every
  ``Model.evaluate`` from the constraint families (current ``phi_y`` and multipliers) and the
  force families that do not read reactions, all evaluated first (:class:`ReactionFeed`); the
  Newton Jacobian carries their exact derivatives w.r.t. the multipliers and w.r.t. the
  coordinates at fixed multipliers (docs/DESIGN.md, "Reactions inside forces"), so Newton
  converges quadratically. A force reading an expression force that itself reads reactions
  (order-dependent / cyclic) is a located DeckError; gravity and Control_Diff expressions
  still reject reaction functions.
* Implicit and user ``Reference_Variable`` and ``Control_Diff`` states are scalar unknowns
  (``model/compile_diff_vars.py``): ``VARVAL``/``DIF`` read them, ``DIF1`` is 0 in statics.
"""
from __future__ import annotations

import re

import numpy as np

from poise.deck.spec import Expr
from poise.core.errors import DeckError, EvaluationError, Problem
from poise.families.base import _cross
from poise.model.compile import GLOBAL
from poise.model.rotation import skew

#: element-force function -> (output group, deck tags or None for "any tag of the group")
REACTION_KINDS = {
    "JOINT": ("joints", ("Constraint_Joint",)),
    "JPRIM": ("jprims", ("Constraint_Jprim",)),
    "MOTION": ("motions", ("Motion_Joint", "Motion_Marker")),
    "SFORCE": ("forces", ("Force_Scalar_TwoBody",)),
    "VFORCE": ("forces", ("Force_Vector_TwoBody", "Force_Vector_OneBody")),
    "VTORQ": ("forces", ("Force_Vector_TwoBody", "Force_Vector_OneBody")),
    "GFORCE": ("forces", ("Force_Vector_TwoBody", "Force_Vector_OneBody")),
    "BUSH": ("forces", ("Force_Bushing",)),
    "SPDP": ("forces", ("Force_SpringDamper",)),
}
RESULTANTS = ("FM", "FX", "FY", "FZ", "TM", "TX", "TY", "TZ")
#: ELEMENTAL_FORCE elem_type spellings -> element-force function
ELEM_TYPES = {"JOINT": "JOINT", "CONSTRAINT_JOINT": "JOINT", "JPRIM": "JPRIM",
              "CONSTRAINT_JPRIM": "JPRIM", "MOTION": "MOTION", "MOTION_JOINT": "MOTION",
              "SFORCE": "SFORCE", "FORCE_SCALAR_TWOBODY": "SFORCE", "VFORCE": "VFORCE",
              "VTORQ": "VTORQ", "GFORCE": "GFORCE", "FORCE_VECTOR_TWOBODY": "GFORCE",
              "FORCE_VECTOR_ONEBODY": "GFORCE", "BUSH": "BUSH", "FORCE_BUSHING": "BUSH",
              "BUSHING": "BUSH", "SPDP": "SPDP", "FORCE_SPRINGDAMPER": "SPDP",
              "SPRINGDAMPER": "SPDP"}

_SPLIT = re.compile(r"[\s,;]+")


def _numbers(el):
    txt = (el.text or "").strip()
    if not txt:
        return np.zeros(0)
    try:
        return np.array([float(t.replace("D", "E").replace("d", "e"))
                         for t in _SPLIT.split(txt) if t], float)
    except ValueError as e:
        raise DeckError(Problem(el.loc, f"element text is not a list of numbers ({e})")) from None


class ModelResolver:
    """Model-side resolver for :func:`poise.expr.compile_batch` (see ``poise/expr/CONTRACT.md``).

    ``allow_reactions`` False makes element-force functions a located DeckError (forces,
    gravity); True registers reaction channels (requests).
    """

    def __init__(self, spec, ctx):
        self.spec = spec
        self.ctx = ctx
        self.b = ctx.b
        self.allow_reactions = False
        self.where = "forces"
        self.channels: list[tuple] = []
        self._chan_index: dict = {}
        self.vars = {e.id: e for e in spec.elements("Reference_Variable")}
        self.splines = {e.id: e for e in spec.elements("Reference_Spline")}
        self.arrays = {e.id: e for e in spec.elements("Reference_Array")}
        self._spline_cache: dict = {}
        self._elements_d: dict | None = None

    @property
    def _elements(self) -> dict:
        """(tag, id) -> first model element; built on first use (expressions reading element
        functions), not for every deck."""
        if self._elements_d is None:
            d: dict = {}
            for e in self.spec.model:
                eid = e.attrs.get("id")
                if eid is not None:
                    d.setdefault((e.tag, eid), e)
            self._elements_d = d
        return self._elements_d

    # ------------------------------------------------------------------ contract
    def marker_index(self, id: int) -> int:
        return self.b.marker_index[int(id)]          # 0 -> 0: the global frame; KeyError else

    def variable(self, id: int):
        el = self.vars[int(id)]
        if el.attrs.get("is_implicit") or \
                str(el.attrs.get("type", "EXPRESSION")).upper() == "USERSUB":
            # scalar unknown (model/compile_diff_vars.py); held: the constant ic
            from poise.model.compile_diff_vars import scalar_unknown
            k = scalar_unknown(self.ctx, "var", int(id))
            return ("explicit", k[1]) if isinstance(k, tuple) else ("implicit", k)
        return ("explicit", el.attrs.get("expr", 0.0))

    def diff_state(self, id: int):
        """Scalar index of Control_Diff ``id`` or ``("const", ic)`` when statically held."""
        from poise.model.compile_diff_vars import scalar_unknown
        return scalar_unknown(self.ctx, "diff", int(id))

    def diff_derivative(self, id: int):
        from poise.model.compile_diff_vars import _els
        _els(self.ctx, "Control_Diff")[int(id)]     # KeyError for unknown ids
        return None                                  # DIF1 = 0 in statics

    def spline(self, id: int):
        id = int(id)
        if id in self._spline_cache:
            return self._spline_cache[id]
        el = self.splines[id]
        v = _numbers(el)
        a = el.attrs
        lin = bool(a.get("linear_extrap", False))
        nx, nz = a.get("num_x"), a.get("num_z")
        if nz and nx and int(nz) > 1:
            nx, nz = int(nx), int(nz)
            if len(v) != nz + nx * (nz + 1):
                raise DeckError(Problem(el.loc, f"surface spline text has {len(v)} numbers; "
                                        f"expected num_z + num_x*(num_z+1) = "
                                        f"{nz + nx * (nz + 1)}"))
            z = v[:nz]
            rows = v[nz:].reshape(nx, nz + 1)
            out = (rows[:, 0], rows[:, 1:].T.copy(), z, lin)
        else:
            n = a.get("num_xy_pair")
            if len(v) % 2:
                raise DeckError(Problem(el.loc, f"spline text has {len(v)} numbers; expected "
                                        "x y pairs"))
            if n is not None and int(n) != len(v) // 2:
                raise DeckError(Problem(el.loc, f"num_xy_pair={n} but the text has "
                                        f"{len(v) // 2} x y pairs", "num_xy_pair"))
            xy = v.reshape(-1, 2)
            out = (xy[:, 0], xy[:, 1], None, lin)
        self._spline_cache[id] = out
        return out

    def array(self, id: int):
        el = self.arrays[int(id)]
        v = _numbers(el)
        n = el.attrs.get("num_element")
        if n is not None and int(n) != len(v):
            raise DeckError(Problem(el.loc, f"num_element={n} but the text has {len(v)} values",
                                    "num_element"))
        return v

    def reaction(self, kind: str, id: int, jflag: int, comp: int, rm: int) -> int:
        kind = kind.upper()
        if not self.allow_reactions:
            raise NotImplementedError(
                f"{kind}() is not supported in {self.where} yet (reaction and element-force "
                "functions are available in Post_Request and force expressions)")
        if kind in RESULTANTS:
            if not 1 <= comp <= 8:
                raise NotImplementedError(f"{kind}: component {comp} outside 1..8")
            key = ("RES", self.marker_index(id), self.marker_index(jflag) if jflag else -1,
                   comp, self.marker_index(rm), int(jflag) != 0)
        elif kind in REACTION_KINDS:
            if not 1 <= comp <= 8:
                raise NotImplementedError(f"{kind}: component {comp} outside 1..8; expected "
                                          "1 |F|, 2-4 Fx Fy Fz, 5 |T|, 6-8 Tx Ty Tz")
            if jflag not in (0, 1):
                raise NotImplementedError(f"{kind}: jflag {jflag}; expected 0 or 1")
            group, tags = REACTION_KINDS[kind]
            el = next((self._elements[(t, id)] for t in tags if (t, id) in self._elements), None)
            if el is None:
                raise KeyError(id)
            key = ("EL", group, el.tag, int(id), int(jflag), int(comp),
                   self.marker_index(rm))
        else:
            raise NotImplementedError(f"{kind}() is not supported yet")
        if key not in self._chan_index:
            self._chan_index[key] = len(self.channels)
            self.channels.append(key)
        return self._chan_index[key]

    def angle_key(self, i_idx: int, j_idx: int, axis: int) -> int:
        return self.ctx.angle(int(i_idx) if i_idx >= 0 else GLOBAL,
                              int(j_idx) if j_idx >= 0 else GLOBAL, int(axis))

    # ------------------------------------------------------------------ element markers
    def element_markers(self, tag, id):
        """(I, J) compiled marker indices of a deck element (J = global frame when absent)."""
        el = self._elements.get((tag, id))
        if el is None:
            return GLOBAL, GLOBAL
        a = el.attrs
        if "joint_id" in a and "i_marker_id" not in a:
            return self.element_markers("Constraint_Joint", a["joint_id"])
        i = a.get("i_marker_id", a.get("marker_id"))
        j = a.get("j_marker_id", a.get("j_floating_marker_id"))
        mi = self.b.marker_index.get(i, GLOBAL) if i is not None else GLOBAL
        mj = self.b.marker_index.get(j, GLOBAL) if j is not None else GLOBAL
        return mi, mj


def compile_batch_located(exprs, resolver, pc):
    """``compile_batch`` whose DeckError problems are added to the collector (None on error)."""
    from poise.expr import compile_batch
    try:
        return compile_batch(exprs, resolver)
    except DeckError as e:
        for p in e.problems:
            if isinstance(p, Problem):
                pc.problems.append(p)
            else:
                pc.error(exprs[0].loc if hasattr(exprs[0], "loc") else None, str(p))
        return None


# ====================================================================================== channels
def channel_values(model, state, channels, info, loads=None, P=None, A=None):
    """Values of reaction channels at ``state`` (exact, from ``state.lam``).

    ``info`` is the :class:`ExprInfo` holding element marker indices. Loads come from
    :func:`poise.solvers.outputs.element_loads` (force/torque on I at the I origin, global);
    ``jflag=1`` gives the equal and opposite action on J about the J origin; components are
    resolved in marker RM's axes (0 = global). ``loads``/``P``/``A`` given (inside
    ``Model.evaluate``): used instead of evaluating the model at ``state``. Evaluated by the
    :class:`ChannelPlan` of ``channels`` (built once, kept by ``info``).
    """
    if not channels:
        return np.zeros(0)
    if loads is None:
        from poise.solvers.outputs import element_loads
        loads = element_loads(model, state)
    if P is None:
        P, A, _ = model.marker_kinematics(state)
    return info.plan(model, channels).evaluate(loads, P, A)


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


def _resultant_side(mi, mj, ei, ej):
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
        owners = info.owner_maps(model)
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
                    side = _resultant_side(mi, mj, ei, ej)
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


class _Weights:
    """How the derivative of E entries' contributions becomes the derivative of their channels:
    a channel is ``w_F . F' + w_T . T'`` to first order, ``(F', T')`` the contribution in global
    axes (taken on J when flipped), ``w`` the RM axis of the picked component (a unit axis for
    the global frame) or the unit vector ``V / |V|`` of the channel's whole global F or T (``|F|``,
    ``|T|``; zero at ``V = 0``). On J (``F' = -F``, ``T' = -T - d x F``, ``d = P_I - P_J``):
    ``w_F . F' + w_T . T' = (-w_F - w_T x d) . F + (-w_T) . T``. :meth:`weights` returns the
    ``(E, 6)`` weights of the unflipped ``(F, T)``, so every derivative of a channel is one
    contraction with the contributing instance's ``d(F, T)``."""

    __slots__ = ("isT", "W0", "rk", "rm", "rax", "mk", "mch", "moff", "fl", "fei", "fej")

    def __init__(self, ch, flip, ei, ej, rm, comp):
        c = comp[ch]
        mag = (c == 1) | (c == 5)
        self.isT = c >= 5
        ax = np.where(c <= 4, c - 2, c - 6)
        r = rm[ch]
        self.W0 = np.zeros((len(ch), 3))
        g = np.nonzero(~mag & (r == GLOBAL))[0]
        self.W0[g, ax[g]] = 1.0
        self.rk = np.nonzero(~mag & (r != GLOBAL))[0]
        self.rm, self.rax = r[self.rk], ax[self.rk]
        self.mk = np.nonzero(mag)[0]
        self.mch = ch[self.mk]
        self.moff = np.where(c[self.mk] == 1, 0, 3)
        self.fl = np.nonzero(flip)[0]
        self.fei, self.fej = ei[self.fl], ej[self.fl]

    def weights(self, P, A, Dg):
        W = self.W0.copy()
        if len(self.rk):
            W[self.rk] = A[self.rm, :, self.rax]
        if len(self.mk):
            v = Dg[self.mch[:, None], self.moff[:, None] + np.arange(3)]
            nv = np.linalg.norm(v, axis=1)[:, None]
            W[self.mk] = np.divide(v, nv, out=np.zeros_like(v), where=nv > 0)
        w = np.zeros((len(W), 6))
        w[:, :3] = np.where(self.isT[:, None], 0.0, W)
        w[:, 3:] = np.where(self.isT[:, None], W, 0.0)
        if len(self.fl):
            d = P[self.fei] - P[self.fej]
            b = w[self.fl, 3:]
            w[self.fl, :3] = -w[self.fl, :3] - _cross(b, d)
            w[self.fl, 3:] = -b
        return w


class _CouplingGroup:
    """The :class:`ReactionFeed` entries of one (reader family ``ri``, contributing family
    ``fi``) pair as index arrays (E entries): reader pair ``p`` (instance, local column) of
    ``ri``, contributing instance position ``pos`` among the read instances of ``fi``, its
    multiplier rows ``crows`` (E, m; constraint families, ``lam``) and the channel weights
    ``wt`` (:class:`_Weights`). ``q``: the block also has the contributing instance's local
    coordinate columns that its action on I depends on (empty: e.g. Coincident). ``ft``: the
    flipped torque entries (the lever ``P_I - P_J`` of the transfer moves) with their element
    markers ``ftei``/``ftej``; None when there are none (or both markers are on ground)."""

    __slots__ = ("ri", "fi", "p", "pos", "crows", "lam", "q", "wt", "ft", "ftei", "ftej")


class _RMBlock:
    """Coordinate derivative of components read in a moving RM marker's axes, for reader family
    ``ri``: its pairs ``sel`` (positions among the reader's read pairs), channels ``ch``, RM
    markers ``rm``, the RM axis ``axis`` and the offset ``off`` (0 F, 3 T) of the component."""

    __slots__ = ("ri", "sel", "ch", "rm", "axis", "off")


class ReactionFeed:
    """Reaction channels read by expression forces, evaluated inside ``Model.evaluate``.

    ``Model.evaluate`` evaluates every family not in :attr:`readers` first (constraints with the
    current multipliers, forces that read no reaction), then calls :meth:`values` with their
    kept ``(fam, kin, rho, phi_y)`` tuples and passes the result as ``EvalContext.reactions`` to
    the reader families. The values are exact at the current iterate (no lag), and so is the
    Jacobian of the readers through them (:meth:`coupling`): the derivative of every channel
    w.r.t. the multipliers and w.r.t. the coordinates (and scalar unknowns) at fixed
    multipliers.

    Both :meth:`values` and :meth:`coupling` are vectorised over channels and entries: their
    index arrays are built once (:class:`ChannelPlan`, :meth:`setup`), the per-evaluation Python
    work is O(groups), not O(channels) or O(entries).
    """

    def __init__(self, channels, info, readers):
        self.channels = list(channels)
        self.info = info
        self.readers = list(readers)
        self.plan = None
        self.groups = []
        self.rm_blocks = []
        self._last = None

    def values(self, model, items, P, A):
        D, Dg = self._vectors(model, items, P, A)
        self._last = (P, D, Dg)
        return self.plan.pick(D)

    def _vectors(self, model, items, P, A):
        from poise.solvers.outputs import loads_of
        if self.plan is None:
            self.plan = self.info.plan(model, self.channels)
        return self.plan.vectors(loads_of(model, items), P, A, glob=True)

    # ------------------------------------------------------------------ Jacobian blocks
    def setup(self, model):
        """Coupling pattern (called by ``Model.finalize``). Per (reader instance, channel,
        contributing instance the channel sums: a constraint-family instance of a joint, jprim
        or motion, or a force-family instance of a force element) one ``(12, m + Lq)`` block
        of the KKT Jacobian: the reader's I and J coordinates x the contributor's multipliers (m,
        constraints) and the Lq local coordinates (markers' bodies, scalar unknowns) its action
        on I can depend on, grouped per (reader family, contributing family) into one
        ``(E, 12, m + Lq)`` block; per group also the flipped torque entries x the
        coordinates of the element's I and J markers (the transfer lever), and per reader
        family the components read in a moving RM marker x that marker's rotation. Returns the
        blocks.

        :attr:`entries` (E, 9) lists the entries in reader order: ``(reader family, instance,
        local column u, channel, contributing family, instance j, flip, I, J)``."""
        fams = model.families
        owners = self.info.owner_maps(model)
        inv = {g: {o: key for key, o in om.items()} for g, om in owners.items()}
        by_key, by_mk = {}, {}              # contributing instances with a reaction output
        for fi, f in enumerate(fams):
            if getattr(f, "reads_reactions", False) or getattr(f, "group", None) not in inv:
                continue
            for j, o in enumerate(np.asarray(f.owner).ravel().tolist()):
                key = inv[f.group].get(o)
                if key is None:
                    continue
                ei, ej = self.info.markers[key]
                rec = (fi, j, ei, ej)
                by_key.setdefault((f.group,) + key, []).append(rec)
                by_mk.setdefault(ei, []).append(rec)
                if ej != ei:
                    by_mk.setdefault(ej, []).append(rec)
        contrib = []                        # per channel: [(fi, j, flip, ei, ej)]
        for ch in self.channels:
            if ch[0] == "EL":
                contrib.append([(fi, j, int(bool(ch[4])), ei, ej)
                                for fi, j, ei, ej in by_key.get(tuple(ch[1:4]), ())])
                continue
            mi, mj = ch[1], ch[2]
            sides = [(r, _resultant_side(mi, mj, r[2], r[3])) for r in by_mk.get(mi, ())]
            contrib.append([(fi, j, side, ei, ej) for (fi, j, ei, ej), side in sides
                            if side is not None])
        rows = []
        for ri, f in enumerate(fams):
            if not getattr(f, "reads_reactions", False):
                continue
            _reader_layout(f)
            for i, cs in enumerate(f.rcols.tolist()):
                for u, c in enumerate(cs):
                    if c >= 0:
                        rows += [(ri, i, u, c) + t for t in contrib[c]]
        E = np.array(rows, np.intp).reshape(-1, 9)
        self.entries = E
        # stable: same-(row, col) entries keep their order (identical assembly sums)
        E = E[np.lexsort((E[:, 4], E[:, 0]))]
        rm = np.array([ch[6] if ch[0] == "EL" else ch[4] for ch in self.channels], np.intp)
        comp = np.array([ch[5] if ch[0] == "EL" else ch[3] for ch in self.channels], np.intp)
        mcols = _marker_columns(model)
        # body origin -> marker origin in the marker's axes: lever = A_marker @ _mlever
        self._mlever = np.einsum("nji,nj->ni", model.marker_A0, model.marker_s0)
        self._pairs = {}                    # reader family -> (instances, local columns) read
        self._inst = {}                     # contributing family -> instances read
        self._qcols = {}                    # contributing family -> local columns of d(F, T)
        self._need_f = {}                   # contributing family -> F needed (lever blocks)
        for ri in np.unique(E[:, 0]).tolist():
            pr = np.unique(E[E[:, 0] == ri][:, 1:3], axis=0)
            self._pairs[ri] = (pr[:, 0], pr[:, 1])
        for fi in np.unique(E[:, 4]).tolist():
            self._inst[fi] = np.unique(E[E[:, 4] == fi, 5])
            self._qcols[fi] = _action_columns(fams[fi])
            self._need_f[fi] = False
        self.groups = []
        blocks = []
        key = E[:, 0] * len(fams) + E[:, 4]
        for s in np.split(np.arange(len(E)), np.nonzero(np.diff(key))[0] + 1):
            if not len(s):
                continue
            e = E[s]
            ri, fi = int(e[0, 0]), int(e[0, 4])
            f, g = fams[ri], fams[fi]
            gp = _CouplingGroup()
            gp.ri, gp.fi = ri, fi
            pi, pu = self._pairs[ri]
            gp.p = _pair_index(pi, pu, f.rcols.shape[1], e[:, 1], e[:, 2])
            gp.pos = np.searchsorted(self._inst[fi], e[:, 5])
            gp.lam = g.is_constraint
            gp.q = len(self._qcols[fi]) > 0
            gp.crows = g.crow[e[:, 5]] if gp.lam else None
            gp.wt = _Weights(e[:, 3], e[:, 6], e[:, 7], e[:, 8], rm, comp)
            ft = np.nonzero(e[:, 6] & (comp[e[:, 3]] >= 5))[0]
            ftc = np.concatenate([mcols[e[ft, 7]], mcols[e[ft, 8]]], axis=1)
            gp.ft = ft if (ftc >= 0).any() else None
            nr = _READER_ROWS
            rrow = f.gcol[e[:, 1], :nr]
            cols = []
            if gp.lam:
                cols.append(model.nq + gp.crows)
            if gp.q:
                cols.append(g.gcol[e[:, 5]][:, self._qcols[fi]])
            if cols:
                c = np.concatenate(cols, axis=1)
                shape = (len(e), nr, c.shape[1])
                blocks.append((np.broadcast_to(rrow[:, :, None], shape),
                               np.broadcast_to(c[:, None, :], shape)))
            if gp.ft is not None:
                self._need_f[fi] = True
                gp.ftei, gp.ftej = e[ft, 7], e[ft, 8]
                shape = (len(ft), nr, 12)
                blocks.append((np.broadcast_to(rrow[ft][:, :, None], shape),
                               np.broadcast_to(ftc[:, None, :], shape)))
            self.groups.append(gp)
        # components in a moving RM's axes: d (a_c . V) / d theta_RM = a_c x V
        self.rm_blocks = []
        for ri, (pi, pu) in self._pairs.items():
            f = fams[ri]
            ch = f.rcols[pi, pu]
            c, r = comp[ch], rm[ch]
            sel = np.nonzero((c != 1) & (c != 5) & (r != GLOBAL) &
                             (mcols[r, 3:] >= 0).any(axis=1))[0]
            if not len(sel):
                continue
            rb = _RMBlock()
            rb.ri, rb.sel, rb.ch, rb.rm = ri, sel, ch[sel], r[sel]
            cs = c[sel]
            rb.axis = np.where(cs <= 4, cs - 2, cs - 6)
            rb.off = np.where(cs <= 4, 0, 3)
            self.rm_blocks.append(rb)
            nr = _READER_ROWS
            shape = (len(sel), nr, 3)
            blocks.append((np.broadcast_to(f.gcol[pi[sel], :nr][:, :, None], shape),
                           np.broadcast_to(mcols[rb.rm, 3:][:, None, :], shape)))
        return blocks

    def coupling(self, model, kept, P, A, row_active, tangents):
        """Values of the :meth:`setup` blocks, exact: ``d r_reader / d (lambda, q)`` through
        the channels. A channel sums, per contributing instance, its action on I (``F = -sum
        rho_s`` over I's point slots, ``T = -sum y_s x rho_s`` over I's axis slots; ``rho =
        phi_y^T lam`` for constraints), optionally taken on J (``-F``, ``-T - (P_I - P_J) x F``)
        and resolved in RM's axes (``A_RM^T``); ``|F|``, ``|T|`` chain through the unit vector
        of the channel's whole F or T (:class:`_Weights`). Per instance: ``d/d lambda`` from
        ``phi_y``; ``d/d q`` at fixed multipliers from the family's own ``G = d rho / d y`` (for
        constraints the multiplier-weighted Hessian: the geometric stiffness) through the slot
        maps ``B``, plus the turning axes ``rho_s x dy_s`` and ``G_ys`` for scalar columns
        (:func:`_action_derivatives`); the transfer lever ``F x (dP_I - dP_J)``; a moving RM's
        ``a_c x V``.

        ``kept``: ``{family index: (fam, kin, rho, phi_y)}`` of the families evaluated before
        the readers; ``tangents``: per family index ``Model.evaluate``'s pending tuple ``(fam,
        kin, rho, G, phi_y, ext)`` (``G``, ``ext`` used). One batched kernel per group."""
        fams = model.families
        if self._last is not None and self._last[0] is P:               # same iterate
            Dg = self._last[2]
        else:
            Dg = self._vectors(model, kept.values(), P, A)[1]
        rl = {ri: _reader_dreaction(fams[ri], kept[ri][1], pi, pu)
              for ri, (pi, pu) in self._pairs.items()}
        base = {}
        for fi, js in self._inst.items():
            _, kin, rho, phy = kept[fi]
            t = tangents[fi]
            base[fi] = _action_derivatives(fams[fi], kin, rho, phy, t[3], t[5], js,
                                           self._qcols[fi], self._need_f[fi])
        out = []
        for gp in self.groups:
            dl, dq, F = base[gp.fi]
            w = gp.wt.weights(P, A, Dg)[:, None, :]                      # (E, 1, 6)
            parts = []
            if gp.lam:
                parts.append(np.matmul(w, dl[gp.pos])[:, 0] * row_active[gp.crows])
            if gp.q:
                parts.append(np.matmul(w, dq[gp.pos])[:, 0])
            r = rl[gp.ri][gp.p]
            if parts:
                dch = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
                out.append(np.einsum("ei,el->eil", r, dch))
            if gp.ft is not None:
                # w_T . (F x dP) = dP . z, z = w_T x F, w_T = -w[3:] (flipped entries);
                # dP = dr + dtheta x v: columns [z, v x z] on I, [-z, -v x z] on J
                z = _cross(-w[gp.ft, 0, 3:], F[gp.pos[gp.ft]])
                dch = np.empty((len(gp.ft), 12))
                dch[:, 0:3] = z
                dch[:, 3:6] = _cross(self._lever(gp.ftei, A), z)
                dch[:, 6:9] = -z
                dch[:, 9:12] = -_cross(self._lever(gp.ftej, A), z)
                out.append(np.einsum("ei,el->eil", r[gp.ft], dch))
        for rb in self.rm_blocks:
            a = A[rb.rm, :, rb.axis]                                         # (Np, 3)
            V = Dg[rb.ch[:, None], rb.off[:, None] + np.arange(3)]
            out.append(np.einsum("ei,el->eil", rl[rb.ri][rb.sel], _cross(a, V)))
        return out

    def _lever(self, mk, A):
        """(n, 3) marker origin minus its body's origin (CG), global."""
        return np.einsum("nij,nj->ni", A[mk], self._mlever[mk])


def _marker_columns(model):
    """(nm, 6) global coordinate columns (translation, rotation) of each marker's body; -1 on
    ground and for the rotation of point bodies (as the compiler's ``gcol``)."""
    nb = model.nb
    mb = np.asarray(model.marker_body)
    out = np.full((len(mb), 6), -1, np.intp)
    if not nb:
        return out
    mov = mb < nb
    b = mb[mov]
    c = model.body_off[b][:, None] + np.arange(6)
    c[model.body_kind[b] == 1, 3:] = -1
    out[mov] = c
    return out


def _action_columns(g):
    """Local columns (of ``6K + U``) on which family ``g``'s action on its I marker can depend
    at fixed multipliers, from its slot structure and declared ``G`` blocks (``g_blocks``):
    for an I slot ``s``, the columns of every slot ``t`` with a ``G_st`` block (rotation; also
    translation for point slots), I's rotation when ``s`` is an axis, every scalar column.
    Empty for e.g. Coincident (``F = -lam``)."""
    K, S = g.K, len(g.slot_ml)
    ml = np.asarray(g.slot_ml)
    kind = np.asarray(g.slot_kind).reshape(-1, S)
    pt_any = (kind == 0).any(axis=0)
    ax_any = (kind != 0).any(axis=0)
    gb = g.g_blocks()
    gb = np.ones((S, S), bool) if gb is None else np.asarray(gb, bool)
    cols = np.zeros(6 * K + g.U, bool)
    for s in np.nonzero(ml == 0)[0]:
        if ax_any[s]:
            cols[3:6] = True
        for t in np.nonzero(gb[s])[0]:
            k = ml[t]
            cols[6 * k + 3:6 * k + 6] = True
            if pt_any[t]:
                cols[6 * k:6 * k + 3] = True
    cols[6 * K:] = True
    return np.nonzero(cols)[0]


def _pair_index(pi, pu, C, i, u):
    """Positions of the (instance, column) pairs ``(i, u)`` in the sorted unique ``(pi, pu)``."""
    return np.searchsorted(pi * C + pu, np.asarray(i) * C + np.asarray(u))


#: local rows of a reader's residual that a channel can move: its I and J markers (the force
#: acts on their bodies only; R and the further markers its expressions read carry no force)
_READER_ROWS = 12


def _reader_dreaction(f, kin, pi, pu):
    """(P, 12) local residual (I and J rows, :data:`_READER_ROWS`) of reader family ``f``'s
    instance ``pi[p]`` per unit change of the reaction channel in its local column ``pu[p]``
    (the force law is linear in (F, T) at fixed slots: rho(dF/dc, dT/dc))."""
    from poise.families.base import SlotKinematics, local_residual_tangent
    from poise.families.expr_forces import apply_two_body_w
    dFs, dTs = f.scalar_chain(kin.Y, f._rgrads)                     # (n, 3, C) each
    sub = SlotKinematics(kin.Y[pi], kin.V[pi], kin.pt[pi], kin.slot_ml, kin.K)
    drho = apply_two_body_w(sub.Y, dFs[pi, :, pu], dTs[pi, :, pu], None, None,
                            f.action_only[pi], False)[0]
    r = local_residual_tangent(sub, drho, None, f.slot_ml, f.K, False, None, 0)[0]
    return r[:, :_READER_ROWS]


def _action_derivatives(g, kin, rho, phy, G, ext, js, qc, need_f):
    """The action on I of family ``g``'s instances ``js`` (F at the I origin, T) and its
    derivatives, stacked ``(F, T)``: ``d/d lambda`` (len(js), 6, m) (constraints, else None),
    ``d/d x`` (len(js), 6, len(qc)) at fixed multipliers w.r.t. the instance's local
    coordinates ``qc`` (of 6K + U; None when empty) and ``F`` (len(js), 3) (``need_f``, else
    None).

    ``F = -sum rho_s`` over I's point slots, ``T = -sum y_s x rho_s`` over I's axis slots. With
    ``d rho = G dy + G_ys ds`` (``G`` the family's ``d rho / d y``: for constraints the
    multiplier-weighted Hessian) and ``dy = B dx`` (the slot map): ``dF = -(G B)_s``,
    ``dT = rho_s x (B_s dx) - y_s x (G B)_s``."""
    from poise.families.base import SlotKinematics
    n, S = len(js), len(g.slot_ml)
    ml = np.asarray(g.slot_ml)
    on_i = np.nonzero(ml == 0)[0]
    pt = kin.pt[js]
    dl = dq = F = None
    if phy is not None:
        dl = np.concatenate(_constraint_dlam(g, kin, phy, js), axis=1)
    if need_f or len(qc):
        rho3 = rho[js].reshape(n, S, 3)
    if need_f:
        F = np.zeros((n, 3))
        for s in on_i:
            F -= rho3[:, s] * pt[:, s, None]
    if len(qc):
        Y = kin.Y[js]
        K6 = 6 * g.K
        L = K6 + g.U
        sub = SlotKinematics(Y, kin.V[js], pt, kin.slot_ml, kin.K)
        B = sub.B                                                        # (n, 3S, 6K)
        rows = (3 * on_i[:, None] + np.arange(3)).ravel()
        GB = np.zeros((n, len(rows), L))                                 # (G B)_s, s on I
        if G is not None:
            GB[:, :, :K6] = np.matmul(G[js[:, None], rows], B)
        gys = None if ext is None else ext.get("G_ys")
        if gys is not None and g.U:
            GB[:, :, K6:] = gys[js[:, None], rows]
        dq = np.zeros((n, 6, L))
        for k, s in enumerate(on_i):
            blk = GB[:, 3 * k:3 * k + 3]                                 # (n, 3, L)
            p = pt[:, s]
            if p.any():
                dq[p, :3] -= blk[p]
            a = ~p
            if a.any():
                dq[a, 3:, :K6] += np.matmul(skew(rho3[a, s]), B[a, 3 * s:3 * s + 3])
                dq[a, 3:] -= np.matmul(skew(Y[a, s]), blk[a])
        dq = dq[:, :, qc]
    return dl, dq, F


def _constraint_dlam(g, kin, phy, js):
    """``d F / d lambda``, ``d T / d lambda`` (len(js), 3, m) of constraint family ``g``'s
    instances ``js``: the action on I (at the I origin) is linear in the multipliers,
    F = -sum phi_y^T lam over I's point slots, T = -sum y x (phi_y^T lam) over I's axis slots."""
    Y = kin.Y[js]
    ph = phy[js]
    n, m = len(js), phy.shape[1]
    dF = np.zeros((n, 3, m))
    dT = np.zeros((n, 3, m))
    for s in range(len(g.slot_ml)):
        if g.slot_ml[s] != 0:
            continue
        blk = np.swapaxes(ph[:, :, 3 * s:3 * s + 3], 1, 2)              # (n, 3, m)
        pt = g.slot_kind[js, s] == 0
        if pt.any():
            dF[pt] -= blk[pt]
        ax = ~pt
        if ax.any():
            dT[ax] -= np.cross(Y[ax, s][:, :, None], blk[ax], axis=1)
    return dF, dT


def _reader_layout(fam):
    """``fam.rcols`` (n, Cr): reaction channels each instance reads; per batch the map
    (rows, batch_col, local_col) used to gather ``d_reaction`` (compile time)."""
    from poise.families.base import column_map, columns_array
    cols = [dict() for _ in range(fam.n)]
    empty = (np.zeros(0, np.intp),) * 3
    fam.reaction_maps = [column_map(b.reaction_index, cols) if b.C else empty
                         for b in fam.batches]
    fam.rcols = columns_array(cols)


class ExprInfo:
    """Element marker indices for reaction channels (built at compile time)."""

    def __init__(self, resolver, outputs):
        self.markers = {}
        self._outputs = outputs
        self._res = resolver
        self._owners = None
        self._plans = {}

    def plan(self, model, channels) -> ChannelPlan:
        """The :class:`ChannelPlan` of ``channels`` (built on first use, then kept)."""
        key = tuple(channels)
        if key not in self._plans:
            self._plans[key] = ChannelPlan(model, key, self)
        return self._plans[key]

    def owner_maps(self, model):
        if self._owners is None:
            om = {}
            for group, o in model.outputs.items():
                ids = np.asarray(o["ids"])
                tags = o.get("tag")
                if tags is None or np.ndim(tags) == 0:
                    tags = [str(tags) if tags is not None else ""] * len(ids)
                om[group] = {}
                for k, (t, i) in enumerate(zip(tags, ids)):
                    key = (str(t), int(i))
                    om[group][key] = k
                    if key not in self.markers:
                        self.markers[key] = self._res.element_markers(*key)
            self._owners = om
        return self._owners


# ====================================================================================== compiler
def _is_null(v):
    return isinstance(v, Expr) and v.text.strip().upper() == "NULL"


def compile_expressions(spec, ctx):
    """Element compiler: expression forces, gravity expressions, Post_Request hooks."""
    from poise.families import expr_forces as XF
    pc = ctx.pc
    res = ModelResolver(spec, ctx)
    ctx.expr_resolver = res
    ground = _ground_markers(ctx.b)

    # ------------------------------------------------------------ forces
    items = list(getattr(ctx, "expr_forces", []))
    res.where = "force expressions"
    res.allow_reactions = True
    vec = [(o, el) for o, el in items if el.tag.startswith("Force_Vector")]
    sca = [(o, el) for o, el in items if el.tag == "Force_Scalar_TwoBody"]
    built = []
    if vec:
        fam = XF.build_vector_family(vec, ctx, res, ground)
        if fam is not None:
            built.append((fam, vec, [f"{a}_expression" for a in XF.VEC_ATTRS]))
    if sca:
        fam = XF.build_scalar_family(sca, ctx, res, ground)
        if fam is not None:
            built.append((fam, sca, ["val_expression"]))
    for fam, _, _ in built:
        ctx.families.append(fam)
    res.allow_reactions = False
    if res.channels:
        _reaction_feed(ctx, res, built, pc)

    # ------------------------------------------------------------ gravity
    gels = spec.elements("Force_Gravity")
    if gels:
        el = gels[-1]
        comps = [el.attrs.get(k, 0.0) for k in ("grav_x", "grav_y", "grav_z")]
        if any(isinstance(c, Expr) for c in comps):
            res.where = "gravity"
            batch = compile_batch_located(comps, res, pc)
            if batch is not None:
                if batch.depends_on_state:
                    k = int(np.argmax(batch.state_mask))
                    pc.error(el.loc, "gravity may depend on TIME only; for a state-dependent "
                             "load use a Force_Vector_TwoBody", ("grav_x", "grav_y", "grav_z")[k])
                else:
                    ctx.gravity_fn = GravityFunction(batch)

    # ------------------------------------------------------------ requests
    reqs = spec.elements("Post_Request")
    if reqs:
        from poise.model.requests import build_request_hook
        res.allow_reactions = True
        res.where = "requests"
        from poise.expr.batch import record_batches
        with record_batches(None):     # outputs only: never make the solution time-dependent
            hook = build_request_hook(reqs, ctx, res)
        if hook is not None:
            ctx.frame_hooks = getattr(ctx, "frame_hooks", []) + [hook]


def _reaction_feed(ctx, res, built, pc):
    """Mark the expression families that read reaction channels, reject order-dependent reads
    (an element-force function of an expression force that itself reads reactions, or a
    resultant FX..TM that would include one) and attach the :class:`ReactionFeed`."""
    readers, reading_els, reading_mk = [], set(), set()
    for fam, its, _ in built:
        reads = any(b.C and (b.reaction_index >= 0).any() for b in fam.batches)
        fam.reads_reactions = bool(reads)
        if reads:
            readers.append(fam)
            for k, (_, el) in enumerate(its):
                reading_els.add((el.tag, el.id))
                reading_mk.add((int(fam.markers[k, 0]), int(fam.markers[k, 1])))
    if not readers:
        return
    bad = False
    for fam, its, attrs in built:
        if not fam.reads_reactions:
            continue
        for b, attr in zip(fam.batches, attrs):
            if not b.C:
                continue
            for i, row in enumerate(b.reaction_index):
                for c in row:
                    if c < 0:
                        continue
                    ch = res.channels[int(c)]
                    if ch[0] == "EL":
                        cyc = (ch[2], ch[3]) in reading_els
                        what = f"<{ch[2]} id={ch[3]}>"
                    else:
                        mi, mj = ch[1], ch[2]
                        cyc = any((a == mi and (mj < 0 or bb == mj)) or
                                  (bb == mi and (mj < 0 or a == mj)) for a, bb in reading_mk)
                        what = "a resultant that includes it"
                    if cyc:
                        bad = True
                        pc.error(its[i][1].loc, f"reads the element force of {what}, an "
                                 "expression force that itself reads reactions (order-dependent "
                                 "or cyclic); expected reactions of joints, jprims, motions or "
                                 "forces that read no reaction", attr)
    if bad:
        return
    ctx.reaction_feed = ReactionFeed(res.channels, ExprInfo(res, ctx.outputs), readers)


class GravityFunction:
    """``g(t)`` (3,) from a batch of TIME-only expressions."""

    depends_on_time = True

    def __init__(self, batch):
        self.batch = batch

    def __call__(self, t: float) -> np.ndarray:
        from poise.expr import EvalContext as XC
        return np.asarray(self.batch.evaluate(XC(time=float(t))).value, float)


def _ground_markers(b):
    """(nm,) bool: compiled marker index on ground (index 0 = global frame)."""
    return np.concatenate([[True], b.marker_on_ground])
