"""Motion constraints: ``measure(I, J) - target(t) = 0`` (Motion_Joint, Motion_Marker).

The measures X, Y, Z, AZ and B1..B3 between the markers I and J (slots and exact derivatives:
:mod:`poise.elements.measures`). The time-dependent target is supplied by a
:class:`MotionTargets` object (values and d/dt of all motions at a time).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poise.core.errors import DeckError, Problem
from poise.deck.spec import Expr
from poise.elements.base import ConstraintFamily
from poise.elements.measures import N_SLOTS, SLOT_KIND, SLOT_ML, measure
from poise.elements.registry import ElementType, OutputGroup, workless
from poise.expr import EvalContext, compile_batch


MEASURES = ("X", "Y", "Z", "AZ", "B1", "B2", "B3")
ROTATIONAL = ("AZ", "B1", "B2", "B3")


@dataclass(frozen=True, eq=False, kw_only=True)
class MotionConstraint(ConstraintFamily):
    """``measure(I, J) - target_k(t) = 0`` for one measure kind.

    Attributes
    ----------
    measure : str
        One of :data:`MEASURES`.
    targets : MotionTargets
        Shared target provider; ``tidx`` (n,) selects this family's motions.
    angle_index : (n,) int or None
        Continuous-angle table entries for ``AZ``.

    Tileable across frames (:mod:`poise.model.frame_batch`): the per-instance arrays tiled by
    the generic tiler suffice; :meth:`constraints` then reads one time per frame.
    """

    measure: str
    targets: "MotionTargets"
    tidx: np.ndarray
    angle_index: np.ndarray | None = None

    @classmethod
    def build(cls, name, I, J, measure_name, targets, tidx, owner, **layout):
        n = len(I)
        return cls(name=name, markers=np.stack([I, J], 1).astype(int), slot_ml=SLOT_ML,
                   slot_kind=np.broadcast_to(SLOT_KIND, (n, N_SLOTS)).copy(),
                   owner=np.asarray(owner, int), m=1, measure=measure_name, targets=targets,
                   tidx=np.asarray(tidx, int), **layout)

    def _values(self, t, ctx):
        memo = None if ctx.workspace is None else ctx.workspace.scratch(self.targets, TargetMemo)
        return self.targets.values(t, memo)

    def _targets(self, ctx):
        """Target of each instance at time ``ctx.t`` (scalar), or at one time per frame (array
        of F times; instances frame-major)."""
        tt = ctx.t
        if np.ndim(tt) == 0:
            return self._values(tt, ctx)[0][self.tidx]
        vals = np.stack([self._values(float(x), ctx)[0] for x in tt])     # (F, n_targets)
        return vals[np.arange(self.n) // (self.n // len(tt)), self.tidx]

    def constraints(self, kin, lam, ctx):
        need_hess = True
        v, g, H = measure(kin.Y, self.measure, need_hess)
        if self.measure == "AZ" and self.angle_index is not None:
            v = ctx.angle[self.angle_index]
        phi = (v - self._targets(ctx))[:, None]
        phi_y = g[:, None, :]
        G = lam[:, 0][:, None, None] * H
        return phi, phi_y, G

    def phi_t(self, kin, ctx):
        _, df = self._values(ctx.t, ctx)
        return -df[self.tidx][:, None]


# ----------------------------------- compile
INTEGRATION_PANEL = 1e-2
_GAUSS: list = []     # 8-point Gauss-Legendre nodes and weights, computed on first use


def _gauss_legendre():
    """(nodes, weights) of ``np.polynomial.legendre.leggauss(8)``: imported lazily (numpy.polynomial
    costs a few ms of start-up and only velocity/acceleration motions integrate)."""
    if not _GAUSS:
        _GAUSS.extend(np.polynomial.legendre.leggauss(8))
    return _GAUSS


class _Resolver:
    """Minimal resolver: markers and explicit variables; anything state-like is flagged later."""

    def __init__(self, spec, marker_index):
        self.spec = spec
        self.index = marker_index
        self._angles = 0

    def marker_index(self, id):
        if id == 0:
            raise KeyError(id)
        return self.index[id]

    def variable(self, id):
        for e in self.spec.elements("Reference_Variable"):
            if e.id == id:
                v = e.attrs.get("expr", e.attrs.get("value", 0.0))
                return ("explicit", v)
        raise KeyError(id)

    def diff_state(self, id):
        raise NotImplementedError("state-dependent motion not supported yet (DIF)")

    def diff_derivative(self, id):
        raise NotImplementedError("state-dependent motion not supported yet (DIF1)")

    def spline(self, id):
        raise KeyError(id)

    def array(self, id):
        for e in self.spec.elements("Reference_Array"):
            if e.id == id:
                return np.array([float(x) for x in (e.text or "").replace(",", " ").split()])
        raise KeyError(id)

    def reaction(self, kind, id, jflag, comp, rm):
        raise NotImplementedError("state-dependent motion not supported yet (element force)")

    def angle_key(self, i_idx, j_idx, axis):
        self._angles += 1
        return self._angles - 1


class TargetMemo:
    """What evaluating motion targets keeps within one solve (the solve's workspace): values
    per time and the cumulative integrals of V/A motions at ``t0 + k * INTEGRATION_PANEL``."""

    __slots__ = ("values", "grid")

    def __init__(self):
        self.values: dict = {}
        self.grid: list = []


class MotionTargets:
    """Target displacements of all motions of a model and their time derivatives.

    Parameters
    ----------
    batch : poise.expr.Batch or None
        Compiled motion expressions (one per motion).
    val_type : list[str]; ic_disp, ic_vel : (n,) float
    t0 : float
        Start of the numerical integration of V/A motions.
    """

    __slots__ = ("batch", "consts", "val_type", "ic_disp", "ic_vel", "t0", "n", "time_dep")

    def __init__(self, batch, consts, val_type, ic_disp, ic_vel, t0=0.0):
        self.batch = batch
        self.consts = np.asarray(consts, float)
        self.val_type = np.array(val_type)
        self.ic_disp = np.asarray(ic_disp, float)
        self.ic_vel = np.asarray(ic_vel, float)
        self.t0 = float(t0)
        self.n = len(self.val_type)
        self.time_dep = self._compute_time_dep()

    def _compute_time_dep(self):
        dep = np.zeros(self.n, bool)
        if self.batch is not None:
            dep |= np.asarray(self.batch.time_mask, bool)
        dep |= self.val_type != "D"
        # V/A with a zero integrand is still constant: keep it simple (time dependent)
        return dep

    def time_dependent(self, idx) -> np.ndarray:
        """(len(idx),) bool: the targets ``idx`` that move with time (an expression of TIME, or
        a velocity / acceleration motion, integrated from the start time)."""
        return self.time_dep[np.asarray(idx, int)]

    def f(self, t):
        """Expression values and d/dTIME, (n,) each."""
        if self.batch is None:
            return self.consts.copy(), np.zeros(self.n)
        out = self.batch.evaluate(EvalContext(t=float(t)))
        return out.value, out.d_time

    def _panel(self, a, b):
        """(int_a^b f, int_a^b tau f) with 8-point Gauss-Legendre, (2, n)."""
        if b == a:
            return np.zeros((2, self.n))
        h = 0.5 * (b - a)
        m = 0.5 * (a + b)
        acc = np.zeros((2, self.n))
        for x, w in zip(*_gauss_legendre()):
            tau = m + h * x
            fv, _ = self.f(tau)
            acc[0] += w * h * fv
            acc[1] += w * h * tau * fv
        return acc

    def _integrals(self, t, memo):
        t0, P = self.t0, INTEGRATION_PANEL
        if t < t0:
            acc = np.zeros((2, self.n))
            k = int(np.ceil((t0 - t) / P))
            edges = np.linspace(t, t0, k + 1)
            for a, b in zip(edges[:-1], edges[1:]):
                acc -= self._panel(a, b)
            return acc
        k = int(np.floor((t - t0) / P))
        grid = memo.grid
        if not grid:
            grid.append(np.zeros((2, self.n)))   # cumulative (int f, int tau f) at t0 + k*panel
        while len(grid) <= k:
            j = len(grid) - 1
            grid.append(grid[-1] + self._panel(t0 + j * P, t0 + (j + 1) * P))
        return grid[k] + self._panel(t0 + k * P, t)

    def values(self, t, memo: TargetMemo | None = None):
        """Targets and their time derivatives at ``t``, (n,) each; ``memo`` (the solve's,
        else a fresh one) keeps them per t and the integrals of V/A motions."""
        memo = TargetMemo() if memo is None else memo
        t = float(t)
        hit = memo.values.get(t)
        if hit is not None:
            return hit
        fv, df = self.f(t)
        if np.all(self.val_type == "D"):
            res = (fv, df)
        else:
            tgt = fv.copy()
            dtg = df.copy()
            isv = self.val_type == "V"
            isa = self.val_type == "A"
            I = self._integrals(t, memo)
            tgt[isv] = self.ic_disp[isv] + I[0, isv]
            dtg[isv] = fv[isv]
            dt = t - self.t0
            tgt[isa] = (self.ic_disp[isa] + self.ic_vel[isa] * dt + t * I[0, isa] - I[1, isa])
            dtg[isa] = self.ic_vel[isa] + I[0, isa]
            res = (tgt, dtg)
        if len(memo.values) > 256:
            memo.values.clear()
        memo.values[t] = res
        return res


def compile_motions(spec, ctx):
    """Compile ``Motion_Joint`` and ``Motion_Marker`` into motion constraint families.

    * ``Motion_Joint`` on a REVOLUTE (``joint_type`` R: ``AZ(I,J) - f(t)``, continuous angle), a
      TRANSLATIONAL (T: ``DZ(I,J,J) - f(t)``) or a CYLINDRICAL joint (R or T, required); I and J are
      the joint's markers. Without ``joint_type``/``motion_type`` a revolute is driven in R and a
      translational in T.
    * ``Motion_Marker`` ``direction`` X/Y/Z: ``DX/DY/DZ(I,J,J) - f``; B1/B2/B3: body-fixed 1-2-3
      angles of I relative to J (see :mod:`poise.elements.motions`).

    Targets (:class:`MotionTargets`): ``val_type`` D: ``f(t)``; V: ``ic_disp + int_{t0}^t f``;
    A: ``ic_disp + ic_vel (t - t0) + int int f``, integrated numerically (8-point Gauss-Legendre on
    panels of ``INTEGRATION_PANEL`` time units, cumulative values cached) from ``t0 = 0``, the
    model's initial time (the start of the first Simulate). Expressions are compiled with
    :func:`poise.expr.compile_batch`; an expression that reads the state (markers, reactions,
    variables with unknowns) is rejected ("state-dependent motion not supported yet").
    """
    mk = ctx.marker
    pc = ctx.pc
    els = spec.elements("Motion_Joint") + spec.elements("Motion_Marker")
    if not els:
        return
    joints = {e.id: e for e in spec.elements("Constraint_Joint")}
    items = []          # (el, I, J, measure)
    for el in els:
        if el.tag == "Motion_Joint":
            jel = joints.get(el.attrs.get("joint_id"))
            if jel is None:
                pc.error(el.loc, f"joint {el.attrs.get('joint_id')} does not exist; expected the "
                         "id of a Constraint_Joint", "joint_id")
                continue
            jt = str(jel.attrs.get("type", "")).upper()
            fr = el.attrs.get("joint_type") or el.attrs.get("motion_type")
            fr = str(fr).upper() if fr else {"REVOLUTE": "R", "TRANSLATIONAL": "T"}.get(jt)
            ok = {"REVOLUTE": ("R",), "TRANSLATIONAL": ("T",), "CYLINDRICAL": ("R", "T")}.get(jt, ())
            if fr not in ok:
                pc.error(el.loc, f"a motion in freedom {fr} is not possible on a {jt} joint; "
                         "expected R on REVOLUTE/CYLINDRICAL, T on TRANSLATIONAL/CYLINDRICAL",
                         "joint_type")
                continue
            I, J = mk(jel, "i_marker_id"), mk(jel, "j_marker_id")
            items.append((el, I, J, "AZ" if fr == "R" else "Z"))
        else:
            d = str(el.attrs.get("direction", "")).upper()
            if d not in ("X", "Y", "Z", "B1", "B2", "B3"):
                pc.error(el.loc, f"direction {d} is not supported; expected X, Y, Z, B1, B2, B3",
                         "direction")
                continue
            items.append((el, mk(el, "i_marker_id"), mk(el, "j_marker_id"), d))
    exprs, vt, icd, icv = [], [], [], []
    for el, *_ in items:
        if str(el.attrs.get("type", "EXPRESSION")).upper() == "USERSUB":
            pc.error(el.loc, "USERSUB motions are not supported; expected type=\"EXPRESSION\"",
                     "type")
        e = el.attrs.get("expr", 0.0)
        exprs.append(e if isinstance(e, Expr) else float(e or 0.0))
        v = str(el.attrs.get("val_type", "D")).upper()
        vt.append(v)
        icd.append(float(el.attrs.get("ic_disp") or 0.0))
        icv.append(float(el.attrs.get("ic_vel") or 0.0))
        if v in ("V", "A") and el.attrs.get("ic_disp") is None:
            pc.warn(el.loc, f"val_type {v} without ic_disp; using ic_disp = 0", "ic_disp")
    pc.raise_if_any()
    batch = None
    if any(isinstance(e, Expr) for e in exprs):
        try:
            batch = compile_batch(exprs, _Resolver(spec, ctx.geometry.marker_index))
        except DeckError as err:
            if "state-dependent" in str(err):
                raise
            raise
        if batch.depends_on_state:
            sm = np.asarray(batch.state_mask, bool)
            probs = [Problem(items[k][0].loc, "state-dependent motion not supported yet; expected "
                             "an expression of TIME only", "expr") for k in np.nonzero(sm)[0]]
            raise DeckError(probs)
    targets = MotionTargets(batch, [e if not isinstance(e, Expr) else 0.0 for e in exprs],
                            vt, icd, icv)
    group = "motions"
    by_measure: dict[str, list] = {}
    for k, (el, I, J, meas) in enumerate(items):
        kind = "rot" if meas in ROTATIONAL else "trans"
        row = ctx.add_row(el, f"{meas}-f(t)", kind, group, k)
        by_measure.setdefault(meas, []).append((k, I, J, row))
        ctx.effect(f"{el.tag}:{meas}")
    for meas, lst in by_measure.items():
        ang = (np.array([ctx.angle(x[1], x[2], 2) for x in lst], int) if meas == "AZ"
               else None)
        ctx.add_family(MotionConstraint.build(
            f"motions:{meas}", np.array([x[1] for x in lst]), np.array([x[2] for x in lst]),
            meas, targets, [x[0] for x in lst], [x[0] for x in lst], angle_index=ang,
            crow=np.array([[x[3]] for x in lst], int), group=group,
            element_locs=tuple(items[x[0]][0].loc for x in lst)))
    ctx.output(group, np.array([it[0].tag for it in items]), [it[0].id for it in items])


def motion_time_sources(fam) -> list:
    """``time_dependent`` of motions: each motion whose target moves with time, named by its
    expression (TIME read directly or through variables, splines, ...) or its ``val_type``."""
    out = []
    dep = fam.targets.time_dependent(fam.tidx)
    for k in np.flatnonzero(dep).tolist():
        i = int(fam.tidx[k])
        reads = fam.targets.batch is not None and bool(fam.targets.batch.time_mask[i])
        out.append(fam.element_locs[k].prefix("expr" if reads else "val_type").rstrip(":"))
    return out


ELEMENTS = (ElementType(
    "motions", ("Motion_Joint", "Motion_Marker"), compile_motions,
    rank=30,                    # motion rows after the joint rows, families after forces
    kernels=lambda: (MotionConstraint,), tileable=lambda: (MotionConstraint,),
    potential_energy=workless,
    time_dependent=motion_time_sources,
    outputs=(OutputGroup("motions", "Mo", "motion", "motion", "`Motion_Joint` / `Motion_Marker`",
                         ("Motion_Joint", "Motion_Marker"),
                         load="driving force the motion applies to the body of its I marker, "
                         "at the I origin, global axes"),),
    reactions={"MOTION": ("motions", ("Motion_Joint", "Motion_Marker"))},
    reaction_aliases={"MOTION_JOINT": "MOTION"},
    fd_tests="tests/reference/test_motions.py"),)
