"""Batch compiler: many expressions -> grouped vectorised programs (see CONTRACT.md)."""
from __future__ import annotations

import copy
import gc
from dataclasses import dataclass

import numpy as np

from poise.core.errors import DeckError, EvaluationError

from .functions import DomainError
from .lower import Lowering
from .tape import extract
from .hessian import build_hessian
from .program import GroupEnv, build

__all__ = ["compile_batch", "Batch", "EvalContext", "EvalResult"]


@dataclass
class EvalContext:
    """What is evaluated at: the one evaluation context of expressions and element kernels
    (global components, deck units, radians).

    Attributes
    ----------
    t : float, or (n,) ndarray
        Analysis time; one per instance when frames are evaluated together
        (:meth:`Batch.tiled`).
    P : (n_markers, 3) ndarray
        Marker origins.
    A : (n_markers, 3, 3) ndarray
        Marker axes as columns.
    angle : (n_angles,) ndarray or None
        Continuous value of each registered AX/AY/AZ angle (the model's angle table; None:
        principal values).
    extra : (n_scalars,) ndarray
        Scalar unknowns (implicit variables, Control_Diff states, curve parameters).
    reactions : (n_channels,) ndarray
        Reaction channel values.
    static : bool
        Static / quasi-static analysis: velocity measures and IMPACT/BISTOP velocities are 0.
    workspace : object or None
        The solve's scratch (``poise.model.workspace.Workspace``): caches an evaluation may
        fill (motion targets, tiled curve programs); None: nothing is kept.
    """

    t: float = 0.0
    P: np.ndarray | None = None
    A: np.ndarray | None = None
    angle: np.ndarray | None = None
    extra: np.ndarray | None = None
    reactions: np.ndarray | None = None
    static: bool = True
    workspace: object = None


@dataclass
class EvalResult:
    """Values and derivatives of all n instances of a batch.

    Attributes
    ----------
    value : (n,) ndarray
    d_slot : (n, S, 3) ndarray
        d value / d slot vector (zero for padding and global-frame slots).
    slot_marker, slot_kind : (n, S) int ndarray
        Marker index (-1 unused) and kind (0 origin, 1/2/3 x/y/z axis column) of each slot.
    d_time : (n,) ndarray
    d_scalar : (n, U) ndarray
    scalar_index : (n, U) int ndarray
        Scalar unknown of each column, -1 unused.
    d_reaction : (n, C) ndarray
    reaction_index : (n, C) int ndarray
        Reaction channel of each column, -1 unused.
    """

    value: np.ndarray
    d_slot: np.ndarray
    slot_marker: np.ndarray
    slot_kind: np.ndarray
    d_time: np.ndarray
    d_scalar: np.ndarray
    scalar_index: np.ndarray
    d_reaction: np.ndarray
    reaction_index: np.ndarray


class _Group:
    """Instances sharing one structural key."""

    def __init__(self, key, rows, insts, splines, n_total):
        self.key = key
        self.rows_idx = np.asarray(rows, dtype=np.intp)
        m = len(rows)
        self.m = m
        self.rows = slice(None) if m == n_total and np.all(self.rows_idx == np.arange(m)) \
            else self.rows_idx
        i0 = insts[0]
        self.params = np.array([it.params for it in insts], dtype=float).reshape(m, -1).T.copy()
        self.S = len(i0.slots)
        self.kinds = [k for _, k in i0.slots]
        self.slot_marker = np.array([[s[0] for s in it.slots] for it in insts],
                                    dtype=np.intp).reshape(m, self.S)
        self.U = len(i0.scalars)
        self.scalars = np.array([it.scalars for it in insts], dtype=np.intp).reshape(m, self.U)
        self.C = len(i0.reactions)
        self.reactions = np.array([it.reactions for it in insts],
                                  dtype=np.intp).reshape(m, self.C)
        self.angles = np.array([it.angles for it in insts], dtype=np.intp).reshape(m, -1)
        self.spl = []
        for k in range(len(i0.splines)):
            ids = np.array([it.splines[k] for it in insts], dtype=np.intp)
            uniq = np.unique(ids)
            if len(uniq) == 1:
                self.spl.append([(splines[uniq[0]], slice(None))])
            else:
                self.spl.append([(splines[u], np.nonzero(ids == u)[0]) for u in uniq])
        self.uses_time = "time" in repr(key)
        self.fn = build(key)
        self.hfn = None           # second-order program (:meth:`second_order`, hessian.py)

    def evaluate(self, ctx, P_ext, A_ext):
        v, g = self.fn(self.env(ctx, P_ext, A_ext))
        if np.ndim(v) == 0 or v.shape[0] != self.m:
            v = np.broadcast_to(v, (self.m,))
        return v, g

    def hessian(self, ctx, P_ext, A_ext):
        """``(m, D, D)`` second derivatives over the group's ``D = 3 S + U`` local variables
        (the second-order program built now when the batch was compiled without it)."""
        hfn = self.hfn if self.hfn is not None else build_hessian(self.key, self.S, self.U)
        return hfn(self.env(ctx, P_ext, A_ext))[2]

    def second_order(self) -> "_Group":
        """A copy of this group with its second-order program built."""
        h = copy.copy(self)
        h.hfn = build_hessian(self.key, self.S, self.U)
        return h

    def env(self, ctx, P_ext, A_ext):
        env = GroupEnv()
        m = self.m
        env.params = self.params
        env.ones = np.ones(m)
        tm = ctx.t
        # one time for all instances, or one per batch instance (frames evaluated together)
        env.t = np.full(m, float(tm)) if np.ndim(tm) == 0 else np.asarray(tm, float)[self.rows_idx]
        env.vecs = [np.take(P_ext, self.slot_marker[:, s], axis=0) if kind == 0
                    else np.take(A_ext[kind - 1], self.slot_marker[:, s], axis=0)
                    for s, kind in enumerate(self.kinds)]
        env.sc = np.asarray(ctx.extra, dtype=float)[self.scalars] if self.U else None
        env.rx = np.asarray(ctx.reactions, dtype=float)[self.reactions] if self.C else None
        if self.angles.shape[1] and ctx.angle is not None and len(ctx.angle):
            env.ang = np.asarray(ctx.angle, dtype=float)[self.angles]
        else:
            env.ang = None
        env.spl = self.spl
        env.static = bool(ctx.static)
        return env


def compile_batch(exprs, resolver) -> "Batch":
    """Compile expressions into a :class:`Batch`.

    Parameters
    ----------
    exprs : list of poise.deck.spec.Expr or float
        One expression per instance.
    resolver : Resolver
        Model-side resolution of marker, variable, spline, array and reaction ids.

    Returns
    -------
    Batch

    Raises
    ------
    poise.core.errors.DeckError
        All syntax / name / argument problems of the batch, located
        (``FILE:LINE: <Tag id=N> attr col C: message``).
    """
    gc_was_enabled = gc.isenabled()
    gc.disable()              # many small objects: the cyclic GC would dominate compile time
    try:
        batch = _compile(exprs, resolver)
    finally:
        if gc_was_enabled:
            gc.enable()
    return batch


def _compile(exprs, resolver):
    low = Lowering(resolver)
    keys: dict = {}
    order: list = []
    text_cache: dict = {}
    for i, e in enumerate(exprs):
        ir = None
        if hasattr(e, "text"):
            ck = e.text
            hit = text_cache.get(ck)
            # lowering is context free except for error locations: reuse when error-free
            if hit is not None:
                ir = hit
            else:
                ir = low.lower_expr(e)
                if ir is not None:
                    text_cache[ck] = ir
        else:
            ir = low.lower_expr(e)
        if ir is None:
            continue
        key, inst = extract(ir)
        if key not in keys:
            keys[key] = ([], [])
            order.append(key)
        keys[key][0].append(i)
        keys[key][1].append(inst)
    if low.problems or low.var_problems:
        seen, probs = set(), []
        for p in low.var_problems + low.problems:
            if str(p) not in seen:
                seen.add(str(p))
                probs.append(p)
        raise DeckError(probs)
    n = len(exprs)
    groups = [_Group(k, keys[k][0], keys[k][1], low.splines, n) for k in order]
    return Batch(list(exprs), groups)


class Batch:
    """Compiled expressions (n instances in their original order).

    Attributes
    ----------
    n : int
    slot_marker, slot_kind : (n, S) int ndarray
    scalar_index : (n, U) int ndarray
    reaction_index : (n, C) int ndarray
    time_mask : (n,) bool ndarray
        Instances whose expression reads TIME.
    state_mask : (n,) bool ndarray
        Instances depending on any slot, scalar unknown or reaction channel.
    """

    def __init__(self, exprs, groups):
        self.exprs = exprs
        self.groups = groups
        n = self.n = len(exprs)
        S = max((g.S for g in groups), default=0)
        U = max((g.U for g in groups), default=0)
        C = max((g.C for g in groups), default=0)
        self.S, self.U, self.C = S, U, C
        self.slot_marker = np.full((n, S), -1, dtype=np.intp)
        self.slot_kind = np.zeros((n, S), dtype=np.intp)
        self.scalar_index = np.full((n, U), -1, dtype=np.intp)
        self.reaction_index = np.full((n, C), -1, dtype=np.intp)
        self.time_mask = np.zeros(n, dtype=bool)
        self.state_mask = np.zeros(n, dtype=bool)
        for g in groups:
            r = g.rows
            self.slot_marker[r, :g.S] = g.slot_marker
            self.slot_kind[r, :g.S] = np.array(g.kinds, dtype=np.intp)
            self.scalar_index[r, :g.U] = g.scalars
            self.reaction_index[r, :g.C] = g.reactions
            self.time_mask[r] = g.uses_time
            self.state_mask[r] = (g.S + g.U + g.C) > 0
        self._needs_axes = any(k > 0 for g in groups for k in g.kinds)
        self._global_slots = self.slot_marker < 0
        self._has_global = bool(self._global_slots[:, :S].any()) if S else False

    def with_second_order(self) -> "Batch":
        """This batch with the second-order programs of its groups built (:meth:`hessian`
        then evaluates without building them: batches of a compiled model never change)."""
        return Batch(self.exprs, [g.second_order() for g in self.groups])

    @property
    def depends_on_time(self) -> bool:
        """True if any instance reads TIME."""
        return bool(self.time_mask.any())

    @property
    def depends_on_state(self) -> bool:
        """True if any instance depends on a marker, scalar unknown or reaction channel."""
        return bool(self.state_mask.any())

    def _fail(self, g, message, mask):
        j = int(np.argmax(mask))
        i = int(g.rows_idx[j])
        e = self.exprs[i]
        loc, attr = (e.loc, e.attr) if hasattr(e, "loc") else (None, None)
        text = ""
        if hasattr(e, "text"):        # a 1000-term expression is quoted by its ends
            t = e.text if len(e.text) <= 160 else f"{e.text[:100]} ... {e.text[-40:]}"
            text = f" in '{t}'"
        err = EvaluationError(f"{message}{text}", loc, attr)
        err.instance = i              # failing instance (callers may name its inputs)
        raise err

    def evaluate(self, ctx: EvalContext) -> EvalResult:
        """Evaluate all instances with first derivatives.

        Raises
        ------
        poise.core.errors.EvaluationError
            Division by zero, SQRT of a negative, LOG of <= 0, ASIN/ACOS out of range, NaN/Inf
            value or derivative; names the first failing instance's element and attribute.
        """
        n, S, U, C = self.n, self.S, self.U, self.C
        value = np.empty(n)
        d_slot = np.zeros((n, S, 3))
        d_time = np.zeros(n)
        d_scalar = np.zeros((n, U))
        d_reaction = np.zeros((n, C))
        P_ext = A_ext = None
        if S:
            P = np.asarray(ctx.P if ctx.P is not None else np.zeros((0, 3)),
                           dtype=float).reshape(-1, 3)
            P_ext = np.concatenate([P, np.zeros((1, 3))])
            if self._needs_axes:
                A = np.asarray(ctx.A if ctx.A is not None else np.zeros((0, 3, 3)),
                               dtype=float).reshape(-1, 3, 3)
                # per axis column k: (n_markers + 1, 3) contiguous, last row = global frame
                A_ext = [np.concatenate([A[:, :, k], np.eye(3)[k:k + 1]]) for k in range(3)]
        with np.errstate(all="ignore"):
            for g in self.groups:
                try:
                    v, grad = g.evaluate(ctx, P_ext, A_ext)
                except DomainError as e:
                    self._fail(g, e.message, e.mask)
                except ArithmeticError as e:       # overflow in a float conversion, ...
                    self._fail(g, f"{type(e).__name__}: {e}", np.ones(g.m, dtype=bool))
                bad = ~np.isfinite(v)
                if bad.any():
                    self._fail(g, "non-finite value", bad)
                r = g.rows
                value[r] = v
                for k, d in grad.items():
                    if not np.isfinite(d).all():
                        b = ~np.isfinite(d)
                        self._fail(g, "non-finite derivative", b if b.ndim == 1 else b.any(1))
                    if k.__class__ is int:
                        d_slot[r, k] = d
                    elif k == "t":
                        d_time[r] = d
                    elif k[0] == "u":
                        d_scalar[r, k[1]] = d
                    else:
                        d_reaction[r, k[1]] = d
        if self._has_global:
            d_slot[self._global_slots] = 0.0
        return EvalResult(value, d_slot, self.slot_marker, self.slot_kind, d_time,
                          d_scalar, self.scalar_index, d_reaction, self.reaction_index)

    def hessian(self, ctx: EvalContext) -> np.ndarray:
        """Exact second derivatives ``(n, 3S + U, 3S + U)`` of every instance w.r.t. its slot
        vector components (``3 s + c``) and scalar unknowns (``3 S + k``), in the layout of
        :meth:`evaluate`'s ``d_slot``/``d_scalar`` (global-frame slots zero). TIME and reaction
        channels are not variables here; a batch reading reactions or IMPACT/BISTOP raises
        :class:`poise.expr.hessian.NoHessian`. Evaluation problems as in :meth:`evaluate`."""
        n, S, U = self.n, self.S, self.U
        D = 3 * S + U
        out = np.zeros((n, D, D))
        P_ext = A_ext = None
        if S:
            P = np.asarray(ctx.P, dtype=float).reshape(-1, 3)
            P_ext = np.concatenate([P, np.zeros((1, 3))])
            if self._needs_axes:
                A = np.asarray(ctx.A, dtype=float).reshape(-1, 3, 3)
                A_ext = [np.concatenate([A[:, :, k], np.eye(3)[k:k + 1]]) for k in range(3)]
        with np.errstate(all="ignore"):
            for g in self.groups:
                try:
                    H = g.hessian(ctx, P_ext, A_ext)
                except DomainError as e:
                    self._fail(g, e.message, e.mask)
                bad = ~np.isfinite(H).all(axis=(1, 2))
                if bad.any():
                    self._fail(g, "non-finite second derivative", bad)
                idx = np.concatenate([np.arange(3 * g.S), 3 * S + np.arange(g.U)]).astype(np.intp)
                rows = np.arange(n)[g.rows]
                out[rows[:, None, None], idx[None, :, None], idx[None, None, :]] = H
        if self._has_global:
            gl = np.repeat(self._global_slots, 3, axis=1)          # (n, 3S)
            out[:, :3 * S, :][gl] = 0.0
            out[:, :, :3 * S].transpose(0, 2, 1)[gl] = 0.0
        return out

    def tiled(self, F: int, n_markers: int, n_angles: int, n_scalars: int) -> "Batch":
        """This batch repeated for ``F`` frames (instance ``f * n + i``), for evaluating many
        frames in one call (:mod:`poise.model.frame_batch`): marker slots are shifted by
        ``n_markers`` per frame, continuous angles by ``n_angles``, scalar unknowns by
        ``n_scalars``; ``EvalContext.t`` may then be one time per tiled instance. Batches
        reading reaction channels are not tiled (their models are evaluated frame by frame)."""
        if self.C:
            raise ValueError("batches reading reaction channels are not tiled")
        n = self.n
        fo = np.arange(F)

        def shift(a, step):
            a = np.asarray(a)
            off = (step * fo).reshape((F,) + (1,) * a.ndim)
            return np.where(a[None] >= 0, a[None] + off, a[None]).reshape((F * a.shape[0],)
                                                                           + a.shape[1:])
        t = copy.copy(self)
        t.exprs = list(self.exprs) * F
        t.n = n * F
        groups = []
        for g in self.groups:
            h = copy.copy(g)
            h.rows_idx = (g.rows_idx[None] + (n * fo)[:, None]).ravel()
            h.rows = slice(None) if isinstance(g.rows, slice) else h.rows_idx
            h.m = g.m * F
            h.params = np.tile(g.params, (1, F))
            h.slot_marker = shift(g.slot_marker, n_markers)
            h.scalars = shift(g.scalars, n_scalars)
            h.angles = shift(g.angles, n_angles)
            h.spl = [[(sp, idx if isinstance(idx, slice) else
                       (idx[None] + (g.m * fo)[:, None]).ravel()) for sp, idx in lst]
                     for lst in g.spl]
            groups.append(h)
        t.groups = groups
        t.slot_marker = shift(self.slot_marker, n_markers)
        t.slot_kind = np.tile(self.slot_kind, (F, 1))
        t.scalar_index = shift(self.scalar_index, n_scalars)
        t.reaction_index = np.tile(self.reaction_index, (F, 1))
        t.time_mask = np.tile(self.time_mask, F)
        t.state_mask = np.tile(self.state_mask, F)
        t._global_slots = t.slot_marker < 0
        return t

