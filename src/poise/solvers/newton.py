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

from dataclasses import dataclass, field

import numpy as np

from poise.core.errors import EvaluationError
from poise.elements.context import row_where
from poise.solvers.data import SolveData
from poise.solvers.history import History, Row
from poise.solvers.iterate import Iterative, Step, iterate
from poise.solvers.linalg import SingularMatrix
from poise.solvers.status import MESSAGES, Status

ASSEMBLY_MAX_ITER = 50
ASSEMBLY_TOL = 1e-10          # relative constraint violation after assembly
LINE_SEARCH_MAX = 8
NEUTRAL_SHARE = 0.1           # S dx above this share of a limited step dx: neutral directions
TAIL_SHARE = 1e-6             # eps M dx above this share of the residual: filter the step
ARMIJO = 1e-4


@dataclass
class FrameOutcome:
    """One frame's solve. ``iterations`` counts all the work of the frame (every strategy);
    ``counts``: iterations per strategy (history.STRATEGIES) when the recovery ran;
    ``strategy``: the one that produced the frame (``plain``: no recovery needed)."""
    status: Status
    iterations: int
    imbalance: float
    error: float
    message: str = ""
    counts: dict = field(default_factory=dict)
    strategy: str = "plain"

    @property
    def ok(self):
        return self.status.ok


#: The per-solve data doubles as the counters every solver function receives (``cnt``): its
#: ``evaluate`` / ``jacobian`` / ``factor`` are the counted evaluations and factorisations.
Counters = SolveData


class Scales:
    """Tolerances per equation from the settings and the model size L."""

    def __init__(self, model, settings):
        L = model.L
        self.L = L
        self.r_tol = np.where(model.q_kind == 1, settings.max_imbalance * L, settings.max_imbalance)
        self.phi_tol = np.where(model.row_kind == 1, settings.max_error, settings.max_error * L)
        self.q_len = np.where(model.q_kind == 0, L, 1.0)     # update scale: trans / L, rad, scalars
        self.max_error = settings.max_error


def measures(model, ev, sc: Scales):
    """(imbalance, constraint error (relative), scaled infinity norm, worst-equation name)."""
    imb = float(np.max(np.abs(ev.r))) if ev.r.size else 0.0
    zr = np.abs(ev.r) / sc.r_tol
    zp = np.abs(ev.phi) / sc.phi_tol if ev.phi.size else np.zeros(0)
    cerr = float(np.max(zp) * sc.max_error) if zp.size else 0.0
    z = np.concatenate([zr, zp])
    k = int(np.argmax(z)) if z.size else 0
    worst = ""
    if z.size:
        if k < model.nq:
            worst = model.coord_info[k]
        else:
            ri = model.row_info[k - model.nq]
            worst = f"{row_where(ri)} {ri['equation']}"
    return imb, cerr, float(z.max()) if z.size else 0.0, worst


def merit(ev, sc):
    z = np.concatenate([ev.r / sc.r_tol, ev.phi / sc.phi_tol])
    with np.errstate(over="ignore", invalid="ignore"):     # inf: a residual beyond any scale
        return 0.5 * float(z @ z)


def _weighted_kkt(model, ev, W):
    """KKT matrix with ``diag(W)`` in the coordinate block and the constraint Jacobian."""
    nq = model.nq
    J = ev.J
    if hasattr(J, "tocsc"):
        import scipy.sparse as sp
        B = J[:nq, nq:]
        Cm = J[nq:, :nq]
        D = J[nq:, nq:]
        return sp.bmat([[sp.diags(W), B], [Cm, D]], format="csc")
    K = np.array(J, copy=True)
    K[:nq, :nq] = np.diag(W)
    return K


def _coord_weights(model):
    return model.q_scale ** 2


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


def inconsistent_redundant(model, state, sc: Scales, data: SolveData) -> str:
    """Removed (redundant) constraint rows violated at ``state`` beyond their tolerance.

    Redundant rows are pinned inactive (``data.active``), so Newton never sees them; when the
    joints contradict each other (e.g. two hinges of one door on parallel but offset axes) the
    active rows can be met while a removed one is not. Returns a message naming the worst such
    row, or "".
    """
    active = data.active
    if model.nc == 0 or active is None or active.all():
        return ""
    try:
        phi = model.evaluate(state, need_jac=False).phi      # every row
    except EvaluationError:
        return ""
    z = np.where(active, 0.0, np.abs(phi) / sc.phi_tol)
    k = int(np.argmax(z))
    if not z[k] > 1.0:
        return ""
    ri = model.row_info[k]
    return (f"{row_where(ri)} equation {ri['equation']} "
            f"(removed as redundant) is violated by {abs(phi[k]):.6g} "
            f"(tolerance {sc.phi_tol[k]:.3g})")


def assemble(model, state, settings, history: History, frame: int, cnt: Counters):
    """Least-change projection onto the constraints (Gauss-Newton on the KKT system,
    :class:`Assembly` run by :func:`~poise.solvers.iterate.iterate`).

    Returns ``(state, assembled: bool, status)``; ``assembled`` says whether anything moved.
    """
    if model.nc == 0:
        return state, False, Status.CONVERGED
    return iterate(Assembly(model, settings, frame, cnt), ASSEMBLY_MAX_ITER, history, state)


class Assembly(Iterative):
    """:func:`assemble` as an :class:`~poise.solvers.iterate.Iterative` strategy: ``step`` is
    one weighted least-change Gauss-Newton step and its ``assembly`` history row."""

    def __init__(self, model, settings, frame, cnt):
        self.model, self.frame, self.cnt = model, frame, cnt
        self.sc = Scales(model, settings)
        self.W = _coord_weights(model)

    def init(self, state):
        return {"state": state, "moved": False, "status": None, "ev": None, "v": np.nan}

    def terminate(self, s, used):
        if s["status"] is not None:
            return True
        model = self.model
        ev = self.cnt.evaluate(model, s["state"], "defer")   # Jacobian only if violated
        viol = np.abs(ev.phi) / np.where(model.row_kind == 1, 1.0, model.L)
        s["ev"], s["v"] = ev, float(viol.max())
        if s["v"] <= ASSEMBLY_TOL:
            s["status"] = Status.CONVERGED
        return s["status"] is not None

    def exhausted(self, s, used):
        s["status"] = Status.ASSEMBLY_FAILED

    def postprocess(self, s, used):
        return s["state"], s["moved"], s["status"]

    def step(self, s, used, left):
        model, ev = self.model, s["ev"]
        self.cnt.jacobian(model, ev)
        K = _weighted_kkt(model, ev, self.W)
        try:
            x = self.cnt.factor(K).solve(np.concatenate([np.zeros(model.nq), -ev.phi]))
        except SingularMatrix:
            s["status"] = Status.ASSEMBLY_FAILED
            return Step(0)
        dq = x[:model.nq]
        prev = s["state"]                 # the row's pose: the configuration it measured
        s["state"] = model.retract(prev, dq)
        s["moved"] = True
        sn = float(np.max(np.abs(dq) / self.sc.q_len))
        return Step(1, (Row(self.frame, used, float(np.max(np.abs(ev.r))) if ev.r.size else 0.0,
                            s["v"], sn, 1.0, "", "assembly", pos=prev.pos, rot=prev.rot),))


def initial_multipliers(model, state, cnt: Counters):
    """Least-squares multipliers ``argmin ||Phi_q^T lam - Q||_{W^-1}`` at the current state."""
    if model.nc == 0:
        return state
    st = state.copy()
    st.lam[:] = 0.0
    ev = cnt.evaluate(model, st, "jacobian")
    W = _coord_weights(model)
    K = _weighted_kkt(model, ev, W)
    try:
        f = cnt.factor(K)
    except SingularMatrix:
        return state
    Q = -ev.r                     # with lam = 0, r = -Q
    try:
        x = f.solve(np.concatenate([Q, np.zeros(model.nc)]))
    except SingularMatrix:
        return state
    st.lam = np.where(cnt.mask(model), x[model.nq:], 0.0)
    return st


def _limit_step_trial(model, state, dq, settings):
    """Uniform step factor so that no body moves (actual screw displacement of its CG) more than
    ``max_translation_step * L`` nor rotates more than ``max_rotation_step``, and the
    configuration it accepted: ``(factor, retract(state, factor * dq))``, or ``(factor, None)``
    when the last retraction tried another factor. The line search starts from that
    configuration instead of retracting again."""
    fac = 1.0
    if len(model.rot_idx):
        r = dq[model.rot_idx].reshape(-1, 3)
        mr = float(np.max(np.linalg.norm(r, axis=1)))
        if mr > settings.max_rotation_step:
            fac = settings.max_rotation_step / mr
    lim = settings.max_translation_step * model.L
    for _ in range(4):
        trial = model.retract(state, fac * dq)
        disp = float(np.max(np.linalg.norm(trial.pos - state.pos, axis=1))) if model.nb else 0.0
        if disp <= lim * 1.0001:
            return fac, trial
        fac *= 0.9 * lim / disp
    return fac, None


def _mass_times(model, state, v):
    """``M v`` for a tangent vector ``v`` (nq,): body masses on translations, world inertia on
    rotations, zero on scalar unknowns."""
    out = np.zeros(model.nq)
    out[model.trans_idx] = np.repeat(model.body_mass, 3) * v[model.trans_idx]
    if len(model.rot_idx):
        _, Jg = model.mass_blocks(state)
        out[model.rot_idx] = np.einsum("nij,nj->ni", Jg,
                                       v[model.rot_idx].reshape(-1, 3)).ravel()
    return out


def _neutral_filtered(model, state, f, x, eps, sc, zinf, limited):
    """The Newton step ``x = A^-1 (-F)`` (``A = K + eps M``) with near-neutral directions filtered
    out, or None when the regularisation does not dominate it.

    Along a direction of zero stiffness (the spin of a slender rod about its axis) a residual
    that is consistent only to second order still has a component ``O(e^2)`` there, which ``A``
    divides by ``eps`` times that direction's (possibly tiny) inertia: a huge spurious step that
    the step limits then cut down to nothing, so Newton stalls. With ``S = eps A^-1 M``
    (eigenvalues ``eps / (lambda + eps)`` for the generalised stiffness ``lambda``), the step
    ``(I - S)(I + 2 S) x`` scales each direction by ``lambda (lambda + 3 eps) / (lambda + eps)^3``:
    zero along neutral directions (the minimum-norm step) and ``1/lambda (1 - 3 (eps/lambda)^2)``
    along stiff ones (Newton's step, quadratic convergence for ``eps << lambda``). Two extra
    solves with the same factorisation, only when ``eps M x`` carries more than ``TAIL_SHARE``
    of the residual (then the regularisation would slow Newton down to a linear rate
    ``eps/lambda``), or when the step limits cut ``x`` (``limited``) and ``S x`` is more than
    ``NEUTRAL_SHARE`` of ``x`` (scaled).
    """
    if not eps > 0 or model.nq == 0:
        return None
    nq = model.nq
    reg = eps * _mass_times(model, state, x[:nq])
    share = float(np.max(np.abs(reg) / sc.r_tol)) / max(zinf, 1e-300)
    if not (limited or share > TAIL_SHARE):
        return None
    pad = np.zeros(len(x) - nq)
    try:
        Sx = f.solve(np.concatenate([reg, pad]))
        size = np.max(np.abs(x[:nq]) / sc.q_len)
        if share <= TAIL_SHARE and \
                not float(np.max(np.abs(Sx[:nq]) / sc.q_len)) > NEUTRAL_SHARE * size:
            return None
        z = x + 2.0 * Sx
        Sz = f.solve(np.concatenate([eps * _mass_times(model, state, z[:nq]), pad]))
    except SingularMatrix:
        return None
    xf = z - Sz
    return xf if np.all(np.isfinite(xf)) else None


class NewtonIteration(Iterative):
    """Frame-level Newton as an :class:`~poise.solvers.iterate.Iterative` strategy: ``step``
    is one Newton iteration (factorise, solve, limit, line search) and returns its history
    row; ``terminate`` checks convergence; ``close`` gives the row of the last measured point
    (converged or why not). ``equilibrate``: factorise the row/column-equilibrated Jacobian
    (:class:`~poise.solvers.linalg.Factor`)."""

    def __init__(self, model, settings, frame: int, cnt: Counters, event: str = "newton",
                 equilibrate: bool = False):
        self.model, self.settings = model, settings
        self.frame, self.cnt, self.event, self.equilibrate = frame, cnt, event, equilibrate
        self.sc = Scales(model, settings)
        self.eps = float(np.sqrt(settings.stability))

    def _ev_at(self, st):
        # Jacobian deferred: line-search trials pay for the residual only, the accepted point
        # assembles its Jacobian when it is factorised (never at the converged point)
        return self.cnt.evaluate(self.model, st, "defer", eps=self.eps)

    def _row(self, s, it, step=np.nan, alpha=np.nan, worst=None, pose=None):
        pose = s.state if pose is None else pose
        return Row(self.frame, it, s.imb, s.err, step, alpha,
                   s.worst if worst is None else worst, self.event, pos=pose.pos, rot=pose.rot)

    def _converged(self, s, it, err):
        # within tolerance: unless a removed redundant equation contradicts the others
        bad = inconsistent_redundant(self.model, s.state, self.sc, self.cnt)
        s.err = err
        s.last_row = self._row(s, it, worst=bad or s.worst)
        if bad:
            return FrameOutcome(Status.INCONSISTENT_CONSTRAINTS, it, s.imb, err,
                                MESSAGES[Status.INCONSISTENT_CONSTRAINTS] + "; " + bad)
        return FrameOutcome(Status.CONVERGED, it, s.imb, err, "converged")

    def _fail(self, s, it, status, message):
        s.last_row = self._row(s, it)
        s.outcome = FrameOutcome(status, it, s.imb, s.err, message)
        return Step(0)

    def init(self, state):
        s = _NewtonState(state)
        try:
            s.ev = self._ev_at(state)
        except EvaluationError as e:
            s.outcome = FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, str(e))
        return s

    def terminate(self, s, used):
        if s.outcome is not None:
            return True
        s.imb, s.cerr, s.zinf, s.worst = measures(self.model, s.ev, self.sc)
        s.err = max(s.cerr, s.last_step if np.isfinite(s.last_step) else 0.0)
        s.res_ok = s.zinf <= 1.0
        step_ok = (not np.isfinite(s.last_step)) or s.last_step <= self.settings.max_error
        if s.res_ok and step_ok:
            s.outcome = self._converged(s, used, s.err)
            return True
        return False

    def exhausted(self, s, used):
        self._fail(s, used, Status.MAX_ITERATIONS,
                   MESSAGES[Status.MAX_ITERATIONS] + f"; worst equation: {s.worst}")

    def close(self, s, used):
        return () if s.last_row is None else (s.last_row,)

    def postprocess(self, s, used):
        return s.state, s.outcome

    def step(self, s, it, left):
        model, settings, sc, eps, state, ev = (self.model, self.settings, self.sc, self.eps,
                                               s.state, s.ev)
        try:
            f = self.cnt.factor(self.cnt.jacobian(model, ev), equilibrate=self.equilibrate)
            x = f.solve(-np.concatenate([ev.r, ev.phi]))
        except SingularMatrix as e:
            return self._fail(s, it, Status.SINGULAR_JACOBIAN,
                              MESSAGES[Status.SINGULAR_JACOBIAN] + singular_message(model, e.row))
        if not np.all(np.isfinite(x)):
            return self._fail(s, it, Status.SINGULAR_JACOBIAN, MESSAGES[Status.SINGULAR_JACOBIAN])
        dq, dl = x[:model.nq], x[model.nq:]
        m0 = merit(ev, sc)
        best = None
        eval_error = ""
        alpha, first = _limit_step_trial(model, state, dq, settings)
        xf = _neutral_filtered(model, state, f, x, eps, sc, s.zinf, alpha < 1.0)
        if xf is not None:
            # the regularisation dominates the step (near-neutral directions): try the step with
            # those directions filtered out first, keep it if it decreases the merit
            af, tf = _limit_step_trial(model, state, xf[:model.nq], settings)
            if tf is None:
                tf = model.retract(state, af * xf[:model.nq])
            tf.lam = tf.lam + af * xf[model.nq:]
            try:
                ev_f = self._ev_at(tf)
                mf = merit(ev_f, sc)
                if mf <= (1.0 - ARMIJO * af) * m0:
                    best = (mf, af, tf, ev_f)
                    dq = xf[:model.nq]
            except EvaluationError:
                pass
        for _ in range(LINE_SEARCH_MAX + 1 if best is None else 0):
            if first is not None:      # the full (limited) step: already retracted
                trial, first = first, None
                trial.lam = trial.lam + alpha * dl
            else:
                trial = model.retract(state, alpha * dq, alpha * dl)
            try:
                ev_t = self._ev_at(trial)
                m1 = merit(ev_t, sc)
            except EvaluationError as e:
                ev_t, m1 = None, np.inf
                eval_error = str(e)
            if ev_t is not None and (best is None or m1 < best[0]):
                best = (m1, alpha, trial, ev_t)
            if not settings.line_search or m1 <= (1.0 - ARMIJO * alpha) * m0:
                break
            alpha *= 0.5
        if best is None:
            return self._fail(s, it, Status.NONFINITE, MESSAGES[Status.NONFINITE]
                              + "; every trial step failed: " + eval_error)
        if s.res_ok and not best[0] < m0:
            # every equation within tolerance and no step along Newton's direction improves
            # them: the residual is at its round-off floor, the step is noise. The error is the
            # step not taken (the distance Newton still sees), not the last one taken
            nxt = float(np.max(np.abs(dq) / sc.q_len)) if dq.size else 0.0
            s.outcome = self._converged(s, it, max(s.cerr, nxt))
            return Step(0)
        m1, alpha, s.state, s.ev = best
        s.last_step = float(np.max(np.abs(alpha * dq) / sc.q_len)) if dq.size else 0.0
        # the row of the iterate it measured (``state``), with the step taken from it
        return Step(1, (self._row(s, it, s.last_step, alpha, pose=state),))


class _NewtonState:
    """Newton's iteration state: the iterate, its evaluation and measures, the last step."""

    def __init__(self, state):
        self.state = state
        self.ev = None
        self.outcome = None
        self.last_step = np.inf
        self.imb = self.cerr = self.zinf = self.err = np.nan
        self.worst = ""
        self.res_ok = False
        self.last_row = None          # the closing row (converged or why not)


def newton(model, state, settings, history: History, frame: int, cnt: Counters,
           max_iter: int | None = None, event: str = "newton", equilibrate: bool = False):
    """Newton iterations from ``state`` (:class:`NewtonIteration` run by
    :func:`~poise.solvers.iterate.iterate`, ``max_iter`` default ``max_num_iter``). Returns
    ``(state, FrameOutcome)``. ``history``: where the loop appends the rows (a
    :class:`~poise.solvers.history.History`, a stage view of one, or a list)."""
    max_iter = settings.max_num_iter if max_iter is None else max_iter
    return iterate(NewtonIteration(model, settings, frame, cnt, event, equilibrate),
                   max_iter, history, state)
