"""Expressions in the model: the resolver of ``poise.expr`` (CONTRACT.md), expression forces,
time-dependent gravity and ``Post_Request`` outputs.

* :class:`ModelResolver` maps deck ids to compiled indices: marker id -> compiled marker index
  (id 0 -> index 0, the model's global frame), explicit ``Reference_Variable`` -> inlined
  expression, ``Reference_Spline`` / ``Reference_Array`` -> data parsed from the element text,
  ``AX/AY/AZ`` -> the model's continuous-angle table (``CompileContext.angle``), element-force
  functions (JOINT, JPRIM, MOTION, SFORCE, VFORCE, VTORQ, GFORCE, BUSH, SPDP) and resultants
  (FM, FX, ..., TZ) -> *reaction channels* evaluated by :func:`channel_values`.
* Reaction channels in ``Post_Request`` expressions are evaluated after convergence, exactly,
  from the converged multipliers. Inside expression forces they are evaluated at every
  ``Model.evaluate`` from the constraint families (current ``phi_y`` and multipliers) and the
  force families that do not read reactions, all evaluated first (:class:`ReactionFeed`); the
  Newton Jacobian carries the exact derivative w.r.t. the multipliers of the constraint
  channels, not the derivative w.r.t. the coordinates through the reaction (docs/DESIGN.md,
  "Reactions inside forces"). A force reading an expression force that itself reads reactions
  (order-dependent / cyclic) is a located DeckError; gravity and Control_Diff expressions
  still reject reaction functions.
* Implicit and user ``Reference_Variable`` and ``Control_Diff`` states are scalar unknowns
  (``model/compile_diff_vars.py``): ``VARVAL``/``DIF`` read them, ``DIF1`` is 0 in statics.
"""
from __future__ import annotations

import re

import numpy as np

from poise.deck.spec import Expr
from poise.errors import DeckError, EvaluationError, Problem
from poise.model.compile import GLOBAL

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
def _resolve(v, A, rm):
    return v if rm == GLOBAL else v @ A[rm]          # components along RM's axes


def _pick(F, T, comp):
    c = int(comp)
    if c == 1:
        return float(np.linalg.norm(F))
    if c <= 4:
        return float(F[c - 2])
    if c == 5:
        return float(np.linalg.norm(T))
    return float(T[c - 6])


def channel_values(model, state, channels, info, loads=None, P=None, A=None):
    """Values of reaction channels at ``state`` (exact, from ``state.lam``).

    ``info`` is the :class:`ExprInfo` holding element marker indices. Loads come from
    :func:`poise.solvers.outputs.element_loads` (force/torque on I at the I origin, global);
    ``jflag=1`` gives the equal and opposite action on J about the J origin; components are
    resolved in marker RM's axes (0 = global). ``loads``/``P``/``A`` given (inside
    ``Model.evaluate``): used instead of evaluating the model at ``state``.
    """
    if not channels:
        return np.zeros(0)
    if loads is None:
        from poise.solvers.outputs import element_loads
        loads = element_loads(model, state)
    if P is None:
        P, A, _ = model.marker_kinematics(state)
    out = np.zeros(len(channels))
    owners = info.owner_maps(model)
    for k, ch in enumerate(channels):
        if ch[0] == "EL":
            _, group, tag, id, jflag, comp, rm = ch
            if group not in loads or (tag, id) not in owners.get(group, {}):
                raise EvaluationError(f"no reaction output for <{tag} id={id}> "
                                      f"(group {group!r} not compiled)")
            o = owners[group][(tag, id)]
            F, T = loads[group][0][o], loads[group][1][o]
            if jflag:
                mi, mj = info.markers[(tag, id)]
                F, T = -F, -T - np.cross(P[mi] - P[mj], F)
                T = T  # about the J origin
            out[k] = _pick(_resolve(F, A, rm), _resolve(T, A, rm), comp)
        else:
            _, mi, mj, comp, rm, _ = ch
            Fs, Ts = np.zeros(3), np.zeros(3)
            for group, omap in owners.items():
                if group not in loads:
                    continue
                for (tag, id), o in omap.items():
                    ei, ej = info.markers[(tag, id)]
                    F, T = loads[group][0][o], loads[group][1][o]
                    if ei == mi and (mj < 0 or ej == mj):
                        Fs += F
                        Ts += T
                    elif ej == mi and (mj < 0 or ei == mj):
                        Fs -= F
                        Ts += -T - np.cross(P[ei] - P[ej], F)
            out[k] = _pick(_resolve(Fs, A, rm), _resolve(Ts, A, rm), comp)
    return out


class ReactionFeed:
    """Reaction channels read by expression forces, evaluated inside ``Model.evaluate``.

    ``Model.evaluate`` evaluates every family not in :attr:`readers` first (constraints with the
    current multipliers, forces that read no reaction), then calls :meth:`values` with their
    kept ``(fam, kin, rho, phi_y)`` tuples and passes the result as ``EvalContext.reactions`` to
    the reader families. The values are exact at the current iterate (no lag).
    """

    def __init__(self, channels, info, readers):
        self.channels = list(channels)
        self.info = info
        self.readers = list(readers)

    def values(self, model, items, P, A):
        from poise.solvers.outputs import loads_of
        loads = loads_of(model, items)
        return channel_values(model, None, self.channels, self.info, loads, P, A)

    # ------------------------------------------------------------------ d / d lambda
    def setup(self, model):
        """Coupling pattern (called by ``Model.finalize``): per (reader instance, channel,
        constraint-family instance the channel reads) one ``(6K_r, m)`` block of the KKT
        Jacobian (reader's coordinates x the constraint's multipliers). Returns the blocks."""
        fams = model.families
        owners = self.info.owner_maps(model)
        inv = {g: {o: key for key, o in om.items()} for g, om in owners.items()}
        cons = [(fi, f) for fi, f in enumerate(fams) if f.is_constraint
                and getattr(f, "group", None) in inv]
        contrib = []                                 # per channel: [(fi, j, flip, ei, ej)]
        for ch in self.channels:
            lst = []
            for fi, f in cons:
                for j, o in enumerate(np.asarray(f.owner).ravel()):
                    key = inv[f.group].get(int(o))
                    if key is None:
                        continue
                    ei, ej = self.info.markers[key]
                    if ch[0] == "EL":
                        if (f.group, key[0], key[1]) == (ch[1], ch[2], ch[3]):
                            lst.append((fi, j, bool(ch[4]), ei, ej))
                    else:
                        mi, mj = ch[1], ch[2]
                        if ei == mi and (mj < 0 or ej == mj):
                            lst.append((fi, j, False, ei, ej))
                        elif ej == mi and (mj < 0 or ei == mj):
                            lst.append((fi, j, True, ei, ej))
            contrib.append(lst)
        self.entries = []            # (reader fi, reader instance i, local col u, channel c, ...)
        blocks = []
        for ri, f in enumerate(fams):
            if not getattr(f, "reads_reactions", False):
                continue
            _reader_layout(f)
            K6 = 6 * f.K
            for i in range(f.n):
                for u, c in enumerate(f.rcols[i]):
                    if c < 0:
                        continue
                    for fi, j, flip, ei, ej in contrib[int(c)]:
                        g = fams[fi]
                        rows = np.repeat(f.gcol[i, :K6][:, None], g.m, 1)
                        cols = np.repeat((model.nq + g.crow[j])[None, :], K6, 0)
                        self.entries.append((ri, i, u, int(c), fi, j, flip, ei, ej))
                        blocks.append((rows, cols))
        return blocks

    def coupling(self, model, kept, P, A, lam, row_active):
        """Values of the :meth:`setup` blocks: ``d r_reader / d lambda`` (exact: every channel is
        linear in its element's multipliers at fixed coordinates)."""
        from poise.families.base import local_residual_tangent
        from poise.families.expr_forces import apply_two_body_w
        out = []
        cache = {}
        for ri, i, u, c, fi, j, flip, ei, ej in self.entries:
            f = model.families[ri]
            if (ri, u) not in cache:
                kin = kept[ri][1]
                dFs, dTs = f.scalar_chain(kin.Y, f._rgrads)
                drho = apply_two_body_w(kin.Y, dFs[:, :, u], dTs[:, :, u], None, None,
                                        f.action_only, False)[0]
                cache[(ri, u)] = local_residual_tangent(kin, drho, None, f.slot_ml, f.K,
                                                        False, None, 0)[0]
            rl = cache[(ri, u)][i]                                   # (6K,)
            g, kin_g, _, phy = kept[fi]
            dch = _channel_dlam(g, kin_g, phy, j, self.channels[c], flip, ei, ej, P, A,
                                lam[g.crow[j]])
            dch = dch * row_active[g.crow[j]]
            out.append(rl[:, None] * dch[None, :])
        return out


def _reader_layout(fam):
    """``fam.rcols`` (n, Cr): reaction channels each instance reads; per batch the map
    (rows, batch_col, local_col) used to gather ``d_reaction``."""
    n = fam.n
    cols = [dict() for _ in range(n)]
    maps = []
    for b in fam.batches:
        rows, bc, fc = [], [], []
        for i in range(n):
            for k, c in enumerate(b.reaction_index[i] if b.C else ()):
                c = int(c)
                if c < 0:
                    continue
                cols[i].setdefault(c, len(cols[i]))
                rows.append(i)
                bc.append(k)
                fc.append(cols[i][c])
        maps.append((np.array(rows, np.intp), np.array(bc, np.intp), np.array(fc, np.intp)))
    C = max((len(c) for c in cols), default=0)
    fam.rcols = np.full((n, C), -1, int)
    for i, c in enumerate(cols):
        for ch, k in c.items():
            fam.rcols[i, k] = ch
    fam.reaction_maps = maps


def _channel_dlam(g, kin, phy, j, ch, flip, ei, ej, P, A, lam):
    """d channel / d lambda (m,) of constraint family ``g``'s instance ``j`` (value linear in
    lambda: F = -sum phi_y^T lam over I's point slots, T = -sum y x (phi_y^T lam) over I's axes)."""
    S = len(g.slot_ml)
    m = phy.shape[1]
    dF = np.zeros((3, m))
    dT = np.zeros((3, m))
    Y = kin.Y[j]
    for s in range(S):
        if g.slot_ml[s] != 0:
            continue
        blk = phy[j, :, 3 * s:3 * s + 3].T                          # (3, m)
        if int(g.slot_kind[j, s]) == 0:
            dF -= blk
        else:
            dT -= np.cross(Y[s][:, None], blk, axis=0)
    if flip:
        dF, dT = -dF, -dT - np.cross((P[ei] - P[ej])[:, None], dF, axis=0)
    rm = ch[-1] if ch[0] == "EL" else ch[4]
    if rm != GLOBAL:
        dF, dT = A[rm].T @ dF, A[rm].T @ dT
    comp = int(ch[5] if ch[0] == "EL" else ch[3])
    if comp in (1, 5):
        M = dF if comp == 1 else dT
        v = M @ lam
        nv = float(np.linalg.norm(v))
        return (v / nv) @ M if nv > 0 else np.zeros(m)
    return dF[comp - 2] if comp <= 4 else dT[comp - 6]


class ExprInfo:
    """Element marker indices for reaction channels (built at compile time)."""

    def __init__(self, resolver, outputs):
        self.markers = {}
        self._outputs = outputs
        self._res = resolver
        self._owners = None

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
        _reaction_feed(ctx, res, built, pc, ground)

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
        hook = build_request_hook(reqs, ctx, res)
        if hook is not None:
            ctx.frame_hooks = getattr(ctx, "frame_hooks", []) + [hook]


def _reaction_feed(ctx, res, built, pc, ground):
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
    warned = set()
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
                    if _lagged_in_q(ch, ground) and (i, id(fam)) not in warned:
                        warned.add((i, id(fam)))
                        pc.warn(its[i][1].loc, "reads a reaction whose value depends on the "
                                "configuration at fixed multipliers (a torque, jflag=1, a moving "
                                "RM marker, a resultant or a force element): that coordinate "
                                "derivative is not in the Newton Jacobian (only d/d multipliers "
                                "is), so convergence is linear near the solution", attr)
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


def _lagged_in_q(ch, ground):
    """True if channel ``ch``'s coordinate dependence at fixed multipliers is certainly missing
    from the Jacobian (see :meth:`ReactionFeed.coupling`)."""
    if ch[0] == "RES" or ch[1] not in ("joints", "jprims", "motions"):
        return True
    _, _, _, _, jflag, comp, rm = ch
    return bool(jflag) or comp >= 5 or not ground[rm]


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
