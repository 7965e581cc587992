"""FIM_S: Newton-Raphson on the force imbalance ``F(q, lam) = [Phi_q^T lam - Q; Phi] = 0``.

* Complete analytic Jacobian (element stiffness, constraint Jacobian, geometric stiffness of
  reactions); ``sqrt(stability) * M`` is added to the coordinate block of the Jacobian only.
* Convergence (scale-aware, in the deck's units): every force row ``< max_imbalance``, every
  moment row ``< max_imbalance * L``; every constraint row ``< max_error * L`` (translational)
  or ``< max_error`` (rotational); and the last update ``< max_error`` (translations relative to
  L, rotations in radians). ``imbalance`` reported = infinity norm of the force/moment residual,
  never including the regularisation.
* Step control: the Newton step is scaled down uniformly if a body translates more than
  ``max_translation_step * L`` or rotates more than ``max_rotation_step``; then a backtracking
  line search on the tolerance-scaled residual norm.
* Before Newton: least-change assembly onto the constraints when the input violates them, and
  least-squares initial multipliers (so the first Jacobian already has the reaction stiffness).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from poise.core import per_object
from poise.core.errors import EvaluationError
from poise.core.lean import all_finite
from poise.elements.context import row_equation, row_where
from poise.solvers.data import SolveData
from poise.solvers.downhill import Runaway, downhill_step
from poise.solvers.gram import least_squares
from poise.solvers.history import History, Row
from poise.solvers.iterate import Next, Solver, evolve, iterate
from poise.solvers.linalg import SingularMatrix
from poise.solvers.reach import PROJECT_ABOVE, project, violation
from poise.solvers.reach import coord_weights as _coord_weights
from poise.solvers.reach import weighted_kkt as _weighted_kkt
from poise.solvers.redundancy import inconsistent_redundant
from poise.solvers.status import MESSAGES, Status
from poise.solvers import steps as _steps

ARMIJO = 1e-4
ALPHA_STALL = 1.0 / 32        # a line search cut below this has stalled (see downhill_step)


def stalled(merits, best: float, alpha: float, crawl_window: int) -> bool:
    """Whether Newton's line search has stalled (then it walks down the potential; the batched
    sweep path solves the case alone): the merit, ``merits`` at each iteration up to this one,
    did not halve in ``crawl_window`` iterations, the step was cut below ``ALPHA_STALL``, or
    the best trial's merit ``best`` (at ``alpha``) is no Armijo decrease."""
    m0 = merits[-1]
    crawl = len(merits) > crawl_window and not m0 <= 0.5 * merits[-1 - crawl_window]
    return crawl or alpha < ALPHA_STALL or not best <= (1 - ARMIJO * alpha) * m0


@dataclass(frozen=True)
class FrameOutcome:
    """One frame's solve (frozen: ``dataclasses.replace`` makes a changed one). ``iterations`` counts all the work of the frame (every strategy);
    ``counts``: iterations per strategy (history.STRATEGIES) when the recovery ran;
    ``strategy``: the one that produced the frame (``plain``: no recovery needed); ``final``:
    the fallback chain is not tried (Newton's steps down the potential ran away: continuation
    and MKEAM descend the same way)."""
    status: Status
    iterations: int
    imbalance: float
    error: float
    message: str = ""
    counts: dict = field(default_factory=dict)
    strategy: str = "plain"
    final: bool = False           # nothing the fallback chain does can change it (a runaway)

    @property
    def ok(self):
        return self.status.ok


#: The per-solve data doubles as the counters every solver function receives (``cnt``): its
#: ``evaluate`` / ``jacobian`` / ``factor`` are the counted evaluations and factorisations.
Counters = SolveData


class Scales:
    """Tolerances per equation from the settings and the model size L. The arrays depend on
    the model and two settings only: made once per model and pair (read-only, shared by the
    solves and the written state's measures; a small model's solve made them three times)."""

    _made = per_object.table()         # model -> {(max_imbalance, max_error): arrays}

    def __init__(self, model, settings):
        L = model.L
        self.L = L
        self.max_error = me = settings.max_error
        mi = settings.max_imbalance
        per = per_object.once_per(Scales._made, model, dict)
        got = per.get((mi, me))
        if got is None:
            got = (np.where(model.q_kind == 1, mi * L, mi),
                   np.where(model.row_kind == 1, me, me * L),
                   np.where(model.q_kind == 0, L, 1.0))   # update scale: trans / L, rad, scalars
            for a in got:
                a.setflags(write=False)
            if len(per) < 8:
                per[(mi, me)] = got
        self.r_tol, self.phi_tol, self.q_len = got


def scaled(ev, sc: Scales) -> np.ndarray:
    """``[|r| / r_tol; |phi| / phi_tol]`` of an evaluation, made once per evaluation and
    tolerances (kept on ``ev``): the merit of a line-search trial and the measures of the one
    taken read the same array."""
    got = ev.scaled
    if got is not None and got[0] is sc.r_tol and got[1] is sc.phi_tol:
        return got[2]
    z = np.concatenate([np.abs(ev.r) / sc.r_tol, np.abs(ev.phi) / sc.phi_tol])
    ev.scaled = (sc.r_tol, sc.phi_tol, z)
    return z


def measures(model, ev, sc: Scales):
    """(imbalance, constraint error (relative), scaled infinity norm, worst-equation name)."""
    mx = np.maximum.reduce              # (np.max without its Python wrapper)
    imb = float(mx(np.abs(ev.r))) if ev.r.size else 0.0
    z = scaled(ev, sc)
    zp = z[len(ev.r):]
    cerr = float(mx(zp) * sc.max_error) if zp.size else 0.0
    if not z.size:
        return imb, cerr, 0.0, ""
    k = int(z.argmax())                 # its entry is the largest (the first NaN, if any)
    return imb, cerr, float(z[k]), equation_name(model, k)


#: a small model's equation names (coordinates, then constraint rows), made once per model
_NAMES = per_object.table()
_NAMES_MAX = 600                # KKT unknowns up to which the names are kept (the dense range)


def equation_name(model, k) -> str:
    """The name of equation ``k`` of the KKT system (a coordinate's, or a constraint row's
    ``FILE:LINE: <Tag id=N> equation``): Newton names its worst equation every iteration."""
    if getattr(model, "N", _NAMES_MAX + 1) <= _NAMES_MAX:
        return per_object.once_per(_NAMES, model, lambda: tuple(
            _equation_name(model, i) for i in range(model.N)))[k]
    return _equation_name(model, k)


def _equation_name(model, k) -> str:
    if k < model.nq:
        return model.coord_info[k]
    return "%s %s" % row_equation(model.row_info, k - model.nq)


def merit(ev, sc):
    """Half the squared norm of the residual by tolerance (:func:`scaled`)."""
    z = scaled(ev, sc)
    with np.errstate(over="ignore", invalid="ignore"):     # inf: a residual beyond any scale
        return 0.5 * float(z @ z)


def singular_message(model, row):
    if row is None:
        return ""
    if model.extra_off <= row < model.nq:      # a scalar unknown (curve parameter, state, ...)
        return f"; nothing determines {model.coord_info[row]}"
    if row < model.nq:
        b = int(np.searchsorted(model.body_off, row, side="right") - 1)
        comp = row - model.body_off[b]
        what = ("translation along " + "XYZ"[comp]) if comp < 3 else ("rotation about " + "XYZ"[comp - 3])
        if model.body_mass[b] == 0.0:
            return (f"; body {int(model.body_id[b])} has zero mass and nothing restrains its "
                    f"{what} ({model.coord_info[row]}): add mass, a constraint or a force, or "
                    "increase stability")
        return f"; no stiffness or mass in {model.coord_info[row]} ({what})"
    ri = model.row_info[row - model.nq]
    return f"; at {row_where(ri)} equation {ri['equation']}"


def initial_multipliers(model, state, cnt: Counters, weights=None, ev=None):
    """Least-squares multipliers ``argmin ||Phi_q^T lam - Q||_{W^-1}`` at the current state
    (``weights``: ``W``, default the squared coordinate scales). ``ev``: the Jacobian
    evaluation at ``state`` with zero multipliers and the solve's active rows, if the caller
    has it (the static prologue's). Sparse models whose Gram matrix is banded solve the normal
    equations (:func:`~poise.solvers.gram.least_squares`), others the weighted KKT system."""
    if model.nc == 0:
        return state
    st = state.copy()
    st.lam[:] = 0.0
    if ev is None:                # only Phi_q and r are read (the weighted KKT matrix)
        ev = cnt.evaluate(model, st, "phi_q")
    W = _coord_weights(model) if weights is None else weights
    Q = -ev.r                     # with lam = 0, r = -Q
    if model.reaction_feed is None and hasattr(ev.J, "indptr"):   # Phi_q^T is the KKT's B block
        lam = least_squares(ev.J[model.nq:, :model.nq], 1.0 / np.sqrt(W), Q, cnt.mask(model),
                            cnt.factor)
        if lam is not None:
            st.lam = np.where(cnt.mask(model), lam, 0.0)
            return st
    K = _weighted_kkt(model, ev, W)
    ev = None                     # its Jacobian goes before the factorisation
    try:
        f = cnt.factor(K)
    except SingularMatrix:
        return state
    try:
        x = f.solve(np.concatenate([Q, np.zeros(model.nc)]))
    except SingularMatrix:
        return state
    st.lam = np.where(cnt.mask(model), x[model.nq:], 0.0)
    return st


@dataclass(frozen=True)
class _Newtoning:
    """Newton's iteration state: the iterate ``state``, its evaluation and measures (made where
    the iterate is, so ``terminate`` only reads ``outcome``), the last step, the closing row."""

    state: object
    ev: object = None
    it: int = 0
    outcome: FrameOutcome | None = None
    last_step: float = np.inf
    imb: float = np.nan
    cerr: float = np.nan
    zinf: float = np.nan
    err: float = np.nan
    worst: str = ""
    res_ok: bool = False
    last_row: Row | None = None       # the closing row (converged or why not)
    stall: float | None = None        # merit where the line search stalled (downhill steps)
    robust: bool = False              # it stalled once: trials kept on the constraints
    runaway: Runaway | None = None    # the steps down since the stall (downhill.Runaway)
    feasible: tuple | None = None     # (state, evaluation) of the last iterate on them
    merits: tuple = ()                # merit at each iteration (progress)
    merit: float | None = None        # the merit of ``ev`` when the line search measured it


class NewtonIteration(Solver[_Newtoning]):
    """Frame-level Newton as a :class:`~poise.solvers.iterate.Solver`: ``step`` is one Newton
    iteration (factorise, solve, limit, line search) and returns its history row, the next
    iterate evaluated and measured (converged or not); ``close`` gives the row of the last
    measured point (converged or why not). ``equilibrate``: factorise the row/column-equilibrated
    Jacobian (:class:`~poise.solvers.linalg.Factor`). ``walks_down``: a stalled line search goes
    on down the potential energy (:class:`BranchNewton`, a continuation's corrector, does not)."""

    walks_down = True

    def __init__(self, model, settings, frame: int, cnt: Counters, event: str = "newton",
                 equilibrate: bool = False, probe=None):
        self.model, self.settings = model, settings
        self.frame, self.cnt, self.event, self.equilibrate = frame, cnt, event, equilibrate
        self.probe = probe
        self.sc = Scales(model, settings)
        self.eps = float(np.sqrt(settings.stability))
        self._kept = None      # (factorisation, step since): a cache for steps.chord_step

    def _ev_at(self, st):
        # Jacobian deferred: line-search trials pay for the residual only, the accepted point
        # assembles its Jacobian when it is factorised (never at the converged point)
        return self.cnt.evaluate(self.model, st, "defer", eps=self.eps)

    def _measure(self, trial, reach=True):
        """``(trial, evaluation, merit)`` of a line-search trial. With ``reach`` (after a
        stall), a trial Newton's linearised constraints left by more than ``PROJECT_ABOVE`` is
        first projected back onto them (:func:`~poise.solvers.reach.project`; beyond the
        assembly's reach ``(None, None, inf)``: the line search shortens the step), and its
        multipliers are those that minimise the merit there (the linearised step's do not fit
        a point off its line), so the merit measures the imbalance itself."""
        if reach and self.model.nc:
            ev = self._ev_at(trial)
            if violation(self.model, ev.phi) > PROJECT_ABOVE:
                trial = project(self.model, trial, self.cnt, ev, self.settings.limits)
                if trial is None:
                    return None, None, np.inf
            trial = initial_multipliers(self.model, trial, self.cnt, self._merit_weights())
        ev = self._ev_at(trial)
        return trial, ev, merit(ev, self.sc)

    def _merit_weights(self):
        """Least-squares weights whose multipliers minimise the merit (squared tolerances,
        scaled to a unit force row so the weighted KKT matrix keeps the usual scale)."""
        rt = self.sc.r_tol
        return (rt / float(np.min(rt))) ** 2 if rt.size else rt

    def _row(self, s, it, step=np.nan, alpha=np.nan, worst=None, pose=None, event=None):
        pose = s.state if pose is None else pose
        ev = self.event if event is None else f"{self.event}-{event}"
        return Row(self.frame, it, s.imb, s.err, step, alpha,
                   s.worst if worst is None else worst, ev, pos=pose.pos, rot=pose.rot)

    def _converged(self, s, err):
        # within tolerance: unless a removed redundant equation contradicts the others
        bad = inconsistent_redundant(self.model, s.state, self.sc, self.cnt)
        s = evolve(s, err=err)
        s = evolve(s, last_row=self._row(s, s.it, worst=bad or s.worst))
        if bad:
            return evolve(s, outcome=FrameOutcome(
                Status.INCONSISTENT_CONSTRAINTS, s.it, s.imb, err,
                MESSAGES[Status.INCONSISTENT_CONSTRAINTS] + "; " + bad))
        return evolve(s, outcome=FrameOutcome(Status.CONVERGED, s.it, s.imb, err, "converged"))

    def _fail(self, s, status, message):
        return Next(evolve(s, last_row=self._row(s, s.it),
                           outcome=FrameOutcome(status, s.it, s.imb, s.err, message)), 0)

    def _measured(self, s):
        """``s`` with the measures of its iterate, converged when they are within tolerance."""
        imb, cerr, zinf, worst = measures(self.model, s.ev, self.sc)
        err = max(cerr, s.last_step if np.isfinite(s.last_step) else 0.0)
        s = evolve(s, imb=imb, cerr=cerr, zinf=zinf, worst=worst, err=err, res_ok=zinf <= 1.0)
        # converged needs an error estimate: a Newton step measured at (or taken to) the point;
        # a residual within tolerance alone says nothing about the distance to the solution
        if s.res_ok and np.isfinite(s.last_step) and s.last_step <= self.settings.max_error:
            return self._converged(s, err)
        return s

    def init(self, state):
        try:
            ev = self._ev_at(state)
        except EvaluationError as e:
            return _Newtoning(state, outcome=FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan,
                                                          str(e)))
        feasible = (state, ev) if violation(self.model, ev.phi) <= PROJECT_ABOVE else None
        return self._measured(_Newtoning(state, ev, feasible=feasible))

    def terminate(self, s):
        return s.outcome is not None, None if s.outcome is None else s.outcome.status

    def close(self, s, status, used):
        if s.outcome is None:               # the budget ran out
            return (self._row(s, used),)
        return () if s.last_row is None else (s.last_row,)

    def postprocess(self, s, status, used):
        ws = getattr(self.cnt, "workspace", None)
        self._kept = None
        if ws is not None:
            self.model.assembler.release(ws)       # its iterations' matrix buffers
        if s.outcome is None:
            return s.state, FrameOutcome(Status.MAX_ITERATIONS, used, s.imb, s.err,
                                         MESSAGES[Status.MAX_ITERATIONS]
                                         + f"; worst equation: {s.worst}")
        return s.state, s.outcome

    def step(self, s, left):
        nxt = self._iteration(s)
        if not nxt.spent:
            return nxt
        s2 = evolve(nxt.state, it=s.it + nxt.spent)
        return Next(s2 if s2.outcome is not None else self._measured(s2), nxt.spent, nxt.rows)

    def _iteration(self, s):
        model, settings, sc, eps, state, ev = (self.model, self.settings, self.sc, self.eps,
                                               s.state, s.ev)
        b = -np.concatenate([ev.r, ev.phi])
        kept, self._kept = self._kept, None
        # in Newton's last, quadratic phase a step by a kept factorisation (steps.chord_step)
        x = _steps.chord_step(kept, b, sc, s.zinf) if not s.robust else None
        chord, f, kept = x is not None, kept[0] if x is not None else None, None
        try:
            if not chord:
                f = self.cnt.factor(self.cnt.jacobian(model, ev), equilibrate=self.equilibrate)
                x = f.solve(b)
        except SingularMatrix as e:
            return self._fail(s, Status.SINGULAR_JACOBIAN,
                              MESSAGES[Status.SINGULAR_JACOBIAN] + singular_message(model, e.row))
        if not all_finite(x):
            return self._fail(s, Status.SINGULAR_JACOBIAN, MESSAGES[Status.SINGULAR_JACOBIAN])
        if s.it == 0 and self.probe is not None:
            # before Newton spends its budget: a free direction a constant load pushes along
            why = self.probe(model, state, settings, self.cnt, f, x, eps, s.zinf)
            if why:
                return self._fail(s, Status.NO_EQUILIBRIUM,
                                  MESSAGES[Status.NO_EQUILIBRIUM] + "; " + why)
        dq, dl = x[:model.nq], x[model.nq:]
        m0 = merit(ev, sc) if s.merit is None else s.merit
        if s.stall is not None and not m0 < s.stall:
            # still above the merit where it stalled: on down the potential energy
            down = self._downhill(state, ev, dq)
            if down is not None:
                return self._down(s, state, down)
        s = evolve(s, stall=None)
        best = None
        eval_error = ""
        # the limited full step is retracted only when asked: by the filter's test, or by the
        # line search when the filtered step is not taken (otherwise a retraction per iteration
        # for nothing)
        limited = []

        def limit():          # once, when first asked
            if not limited:
                limited.append(_steps.limit_step(model, state, x[:model.nq], settings))
            return limited[0]
        # a step longer than the last one taken may carry neutral content that the tail share
        # does not see (a tiny inertia along it): the filter examines it too (both asked only
        # when the tail share does not decide); its solves are plain ones with the factors that
        # just gave x (checked, or a chord step's already plain): S x is a correction to x
        xf = _steps.neutral_filtered(
            model, state, f.unchecked, x, eps, sc, s.zinf,
            lambda: _steps.grew(dq, s.last_step, sc) or limit()[0] < 1.0, Jg=ev.inertia)
        # the factorisation is not needed by the trials (memory at 10^5) unless kept for a chord
        keep = _steps.keep_factor(model, f, x, sc, getattr(self.cnt, "workspace", None))
        del f
        if xf is not None:
            # the regularisation dominates the step (near-neutral directions): try the step with
            # those directions filtered out first, keep it if it decreases the merit
            af, tf = _steps.limit_step(model, state, xf[:model.nq], settings)
            if tf is None:
                tf = model.retract(state, af * xf[:model.nq])
            tf.lam = tf.lam + af * xf[model.nq:]
            try:
                tf, ev_f, mf = self._measure(tf, s.robust)
                if mf <= (1.0 - ARMIJO * af) * m0:
                    best = (mf, af, tf, ev_f)
                    dq = xf[:model.nq]
            except EvaluationError:
                pass
            ev_f = None      # not kept beside the line search's trials unless it is ``best``
        if best is None:
            alpha, first = limit()
        for _ in range(settings.limits.line_search_max + 1 if best is None else 0):
            if first is not None:      # the full (limited) step: already retracted
                trial, first = first, None
                trial.lam = trial.lam + alpha * dl
            else:
                trial = model.retract(state, alpha * dq, alpha * dl)
            ev_t = None      # the last trial's evaluation goes (unless it is ``best``)
            try:
                trial, ev_t, m1 = self._measure(trial, s.robust)
            except EvaluationError as e:
                ev_t, m1 = None, np.inf
                eval_error = str(e)
            if ev_t is not None and (best is None or m1 < best[0]):
                best = (m1, alpha, trial, ev_t)
            if ev_t is None and not eval_error:
                eval_error = "every trial left the reach of the constraints"
            if (not settings.line_search and ev_t is not None) \
                    or m1 <= (1.0 - ARMIJO * alpha) * m0:
                break
            alpha *= 0.5
        if best is None:
            return self._fail(s, Status.NONFINITE, MESSAGES[Status.NONFINITE]
                              + "; every trial step failed: " + eval_error)
        if s.res_ok and not best[0] < m0:
            # every equation within tolerance and no step along Newton's direction improves
            # them: the residual is at its round-off floor, the step is noise. The error is the
            # step not taken (the distance Newton still sees), not the last one taken; the
            # filtered step when there is one: along neutral directions every point is an
            # equilibrium, so their round-off share of the step is no distance to one
            nxt = _steps.step_size(xf[:model.nq] if xf is not None else dq, sc)
            return Next(self._converged(s, max(s.cerr, nxt)), 0)
        s = evolve(s, merits=s.merits + (m0,))
        if settings.line_search and self.walks_down and not s.res_ok and stalled(
                s.merits, best[0], best[1], settings.limits.crawl_window):
            # the merit stalls: from now on every trial is kept on the constraints (the
            # iterate first, if Newton's linearisation left them), and where the merit has a
            # valley that is no equilibrium, steps go down the potential energy instead until
            # the merit is below this one (docs/solvers.md, "Newton on mechanisms")
            if not s.robust:
                s = evolve(s, robust=True)
                if violation(model, ev.phi) > PROJECT_ABOVE:
                    return self._onto(s, state)
            down = self._downhill(state, ev, dq)
            if down is not None:
                return self._down(evolve(s, stall=m0, runaway=Runaway(model, ev.r)), state,
                                  down)
        if keep is not None and best[1] == 1.0 and not s.robust:      # a full step: kept
            self._kept = (keep, _steps.step_size(dq, sc))
        # a chord step's row says so (``newton-chord``: no Jacobian, no factorisation)
        return self._take(s, state, (best[2], best[3], best[0], best[1]), dq,
                          "chord" if chord else None, merit=best[0])

    def _onto(self, s, state):
        """The iterate projected back onto its constraints or, beyond their reach, the last
        iterate that was on them: the iteration's row (``reach``)."""
        p = project(self.model, state, self.cnt, s.ev, self.settings.limits)
        if p is not None:
            p = initial_multipliers(self.model, p, self.cnt, self._merit_weights())
            s = evolve(s, state=p, ev=self._ev_at(p), merit=None)
        elif s.feasible is not None:
            s = evolve(s, state=s.feasible[0], ev=s.feasible[1], merit=None)
        s = evolve(s, last_step=np.inf)
        return Next(s, 1, (self._row(s, s.it, np.nan, np.nan, pose=state, event="reach"),))

    def _downhill(self, state, ev, dq):
        """:func:`~poise.solvers.downhill.downhill_step` with Newton's step limits and
        trials."""
        model, settings = self.model, self.settings
        return downhill_step(model, state, ev, dq, self.cnt,
                             lambda st, d: _steps.limit_step(model, st, d, settings),
                             self._measure, lambda st, v: _steps.mass_times(model, st, v), self.eps)

    def _down(self, s, state, down):
        """Accept the downhill step ``down`` (:func:`~poise.solvers.downhill.downhill_step`),
        or end Newton when the steps down have gone beyond reach (:class:`Runaway`)."""
        nxt = self._take(s, state, down[:4], down[4], "downhill")
        runaway = copy.copy(s.runaway)           # the state's stays as it was
        runaway.turn = runaway.turn.copy()
        why = runaway.add(down[3] * down[4], down[5])
        s2 = evolve(nxt.state, runaway=runaway)
        if why:
            s2 = evolve(s2, outcome=FrameOutcome(Status.DIVERGED, s.it + 1, s.imb, s.err, why,
                                                  final=True))
        return Next(s2, nxt.spent, nxt.rows)

    def _take(self, s, state, trial, dq, event=None, merit=None):
        """Accept ``trial`` = ``(state, evaluation, merit, alpha)`` reached from ``state`` by
        ``alpha * dq``: the iteration's history row. ``merit``: the trial's merit when the
        line search measured it (kept: the next iteration's starting merit)."""
        st, ev, _, alpha = trial
        last_step = _steps.step_size(alpha * dq, self.sc)
        s2 = evolve(s, state=st, ev=ev, last_step=last_step, merit=merit,
                    feasible=(st, ev) if violation(self.model, ev.phi) <= PROJECT_ABOVE
                    else s.feasible)
        # the row of the iterate it measured (``state``: its measures), with the step taken
        return Next(s2, 1, (self._row(s2, s.it, last_step, alpha, pose=state, event=event),))


class BranchNewton(NewtonIteration):
    """Newton as a continuation's corrector: it wants the root next to its prediction, so a
    stalled line search ends it (no projection, no steps down the potential to another one)."""

    walks_down = False


def newton(model, state, settings, history: History, frame: int, cnt: Counters,
           max_iter: int | None = None, event: str = "newton", equilibrate: bool = False,
           probe=None):
    """Newton iterations from ``state`` (:class:`NewtonIteration` run by
    :func:`~poise.solvers.iterate.iterate`, ``max_iter`` default ``max_num_iter``). Returns
    ``(state, FrameOutcome)``. ``history``: where the loop appends the rows (a
    :class:`~poise.solvers.history.History`, a stage view of one, or a list). ``probe``:
    ``probe(model, state, settings, cnt, f, x, eps, zinf) -> message`` called with the first
    step (factorisation ``f``, step ``x``); a message ends Newton as ``no_equilibrium``."""
    max_iter = settings.max_num_iter if max_iter is None else max_iter
    return iterate(NewtonIteration(model, settings, frame, cnt, event, equilibrate, probe),
                   max_iter, history, state)


def branch_newton(model, state, settings, history: History, frame: int, cnt: Counters,
                  max_iter: int, event: str):
    """:func:`newton` as a continuation's corrector (:class:`BranchNewton`)."""
    return iterate(BranchNewton(model, settings, frame, cnt, event), max_iter, history, state)
