"""Solve one frame with recovery: plain Newton, then the documented fallback chain.

:func:`solve_frame` is the one entry point every analysis uses for a frame. Plain Newton gets
``max_num_iter`` iterations; when it fails with a failure a strategy can fix, the :data:`CHAIN`
stages (``stability``, ``continuation``, ``mkeam``) are tried in order from the frame's input
configuration within the fallback budget (``fallback_max_num_iter``), each switch a history row.
The chain and :func:`continuation` are :class:`~poise.solvers.iterate.Solver` s run by the one
loop :func:`~poise.solvers.iterate.iterate`, as is Newton. Stages,
budget and what is not tried: docs/solvers.md, "Fallback chain".
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from poise.core.errors import EvaluationError
from poise.solvers import freedom
from poise.solvers.history import Row
from poise.solvers.iterate import Next, Solver, evolve, iterate
from poise.solvers.newton import FrameOutcome, Scales, merit, newton
from poise.solvers.status import MESSAGES, Status

FALLBACK_STABILITY = 1e-2
PTC_MU_MIN = 1e-12
PTC_MU_GROWTH = 1e8       # mu above this multiple of its start: the pseudo-time flow diverges
NO_RECOVERY = (Status.NONFINITE, Status.INCONSISTENT_CONSTRAINTS, Status.NO_EQUILIBRIUM)
OVERFLOW = 1e150          # a force imbalance above this (any units) cannot be computed with
ZERO_ROW = 1e-13          # a Jacobian row below this fraction of the largest entry is empty


def solve_frame(model, state, settings, history, frame, cnt, event="newton"):
    """Newton from ``state`` and, if it fails, the fallback chain. Returns ``(state, outcome)``.

    The outcome's ``iterations`` counts every iteration of the frame, ``counts`` splits them by
    strategy, ``strategy`` names the one that converged (``plain``: no recovery needed).
    """
    start = state.copy()
    st, out = newton(model, state, settings, history, frame, cnt, event=event,
                     probe=freedom.probe)
    out = evolve(out, counts={"plain": out.iterations})
    if out.ok:
        return st, out
    return recover(model, start, st, out, settings, history, frame, cnt)


def recover(model, start, st, out, settings, history, frame, cnt):
    """The fallback chain from ``start`` after plain Newton failed with ``out`` at ``st``
    (``out.counts["plain"]``, if set, is all the plain work of the frame so far). Returns
    ``(state, outcome)`` with the frame's total iterations; the failed plain result when the
    chain does not converge or is not to be tried."""
    plain = int(out.counts.get("plain", out.iterations)) if out.counts else int(out.iterations)
    out = evolve(out, counts={"plain": plain}, iterations=plain)
    if out.ok or not settings.fallback or out.status in NO_RECOVERY:
        return st, out
    if out.final:
        return st, replace(out, message=out.message + (
            "; the fallback chain was not tried (continuation and MKEAM descend the same way)"))
    if not out.imbalance <= OVERFLOW:
        return st, FrameOutcome(Status.NONFINITE, plain, out.imbalance, out.error,
                                f"{out.message}; the force imbalance ({out.imbalance:.3g}) is "
                                "beyond any physical scale (floating-point overflow): check the "
                                "loads; the fallback chain was not tried", out.counts)
    why = (freedom.candidate(model, start, settings, cnt)
           or unrestrained_load(model, settings, (start, st), cnt))
    if why:
        return st, FrameOutcome(Status.NO_EQUILIBRIUM, plain, out.imbalance, out.error,
                                MESSAGES[Status.NO_EQUILIBRIUM] + "; " + why, out.counts)
    budget = settings.fallback_budget
    if budget <= 0:
        return st, replace(out, message=out.message + "; fallback chain not run (fallback budget 0)")
    st2, out2, used, counts = run_chain(model, start, settings, history, frame, cnt, out, budget)
    counts["plain"] = plain
    total = int(sum(counts.values()))
    if out2.ok:
        return st2, replace(out2, iterations=total, counts=counts, strategy=used, message=(
            f"converged; plain Newton failed ({out.status.value}): converged with the fallback "
            f"strategy '{used}'"))
    return st, replace(out, iterations=total, counts=counts, message=out.message + (
        f"; fallback chain (stability, continuation, mkeam) did not converge ({total - plain} "
        f"of its {budget} units of work used, raise --fallback-budget; last: {out2.message})"))


def unrestrained_load(model, settings, states, cnt) -> str:
    """A coordinate nothing restrains (its row of the unregularised Jacobian is empty: no
    element, constraint or reaction depends on any unknown through it) that carries the same
    non-zero load at every state of ``states`` and at a probe moved one model size (or one
    radian) along the load: no equilibrium exists along it, and no strategy can find one (e.g.
    a body whose joint is missing, under gravity). Returns a message naming it, or ""."""
    if model.nq == 0:
        return ""
    sc = Scales(model, settings)
    cand = None
    ref = None
    pts = list(states)
    k = 0
    while k < len(pts):
        try:
            ev = cnt.evaluate(model, pts[k], "jacobian")
        except EvaluationError:
            return ""
        J = ev.J
        if hasattr(J, "tocsr"):
            A = abs(J.tocsr()[:model.nq])
            rowmax = np.asarray(A.max(axis=1).todense()).ravel()
            big = float(abs(J).max()) if J.nnz else 0.0
        else:
            A = np.abs(np.asarray(J)[:model.nq])
            rowmax = A.max(axis=1) if A.shape[1] else np.zeros(model.nq)
            big = float(np.abs(J).max()) if J.size else 0.0
        c = (rowmax <= ZERO_ROW * big) & (np.abs(ev.r) > sc.r_tol)
        if ref is None:
            ref = ev.r.copy()
            cand = c
        else:
            cand = cand & c & (np.abs(ev.r - ref) <= 1e-9 * np.abs(ref))
        if not cand.any():
            return ""
        if k == len(pts) - 1 and len(pts) == len(states):
            dq = np.zeros(model.nq)
            dq[cand] = -np.sign(ref[cand]) * sc.q_len[cand]
            pts.append(model.retract(pts[k], dq))
        k += 1
    j = int(np.nonzero(cand)[0][0])
    return (f"nothing restrains {model.coord_info[j]} (no element or constraint acts on it) "
            f"and a constant load of {-ref[j]:.6g} pushes it: add the missing joint or force")


class StabilityStage:
    """Newton again with ``stability`` raised to ``FALLBACK_STABILITY``: at most
    ``max_num_iter`` iterations and a quarter of the budget left."""

    name = "stability"

    def event(self, settings, reason):
        return f"fallback: stability={max(settings.stability, FALLBACK_STABILITY):g}: {reason}"

    def run(self, model, start, settings, history, frame, cnt, left, prev):
        n = min(int(settings.max_num_iter), max(1, left // 4), left)
        s1 = replace(settings, stability=max(settings.stability, FALLBACK_STABILITY))
        st, out = newton(model, start.copy(), s1, history, frame, cnt, max_iter=n,
                         event="fallback-stability")
        return st, out, False, (), {self.name: out.iterations}


class ContinuationStage:
    """Pseudo-transient continuation (:func:`continuation`): two thirds of the budget left."""

    name = "continuation"

    def event(self, settings, reason):
        return f"fallback: continuation: {reason}"

    def run(self, model, start, settings, history, frame, cnt, left, prev):
        n = min(settings.limits.ptc_max_iter, max(1, (2 * left) // 3))
        st, out = continuation(model, start.copy(), settings, history, frame, cnt, max_steps=n)
        return st, out, False, (), {self.name: out.iterations}


class MkeamStage:
    """MKEAM relaxation (:meth:`poise.solvers.relaxation.Relaxation.relax`, stable equilibria
    only) within the budget left in units of work (integration steps of the dynamics, steps of
    its Newton descent), a quarter of it kept for the Newton polish of its point (stage
    ``polish``). The last stage: its outcome is final."""

    name = "mkeam"

    def event(self, settings, reason):
        return f"fallback: mkeam: {reason}"

    def run(self, model, start, settings, history, frame, cnt, left, prev):
        st, out = prev
        polish = min(int(settings.max_num_iter), max(1, left // 4))
        units = max(1, left - polish)
        rx = None
        try:
            # lazy: MKEAM needs scipy, which the small-deck path never loads
            from poise.solvers.relaxation import Relaxation
            rx = Relaxation(model, replace(settings, max_num_iter=units), history, cnt,
                            units=units)
            st2, ok, why = rx.relax(start.copy())
        except Exception as e:   # noqa: BLE001 - any MKEAM failure just ends the chain
            why = Row(frame, 0, event=f"fallback: mkeam failed: {e}", strategy=self.name)
            return (st, replace(out, message=f"MKEAM failed: {e}"), True, (why,),
                    {"mkeam": 0 if rx is None else rx.used})
        counts = {"mkeam": rx.used}
        left -= rx.used
        if not ok:
            return st, replace(out, message=f"MKEAM did not converge within its share of the "
                                            f"fallback budget ({units} units): {why}"), True, (
                                                ), counts
        if left <= 0:
            return st2, FrameOutcome(Status.MAX_ITERATIONS, 0, np.nan, np.nan,
                                     "no budget left for the Newton polish of the MKEAM point"
                                     ), True, (), counts
        st3, out3 = newton(model, st2, settings, history.stage("polish"), frame, cnt,
                           max_iter=left, event="fallback-polish")
        return st3, out3, True, (), {**counts, "polish": out3.iterations}


#: The fallback chain: tried in this order after plain Newton failed, each from the frame's
#: input configuration, sharing the frame's fallback budget.
CHAIN = (StabilityStage(), ContinuationStage(), MkeamStage())


@dataclass(frozen=True)
class _Chaining:
    """:class:`Chain`'s state: the last failed ``(st, out)`` and why (``reason``), the next
    stage, whether its switch row was given, the iterations per strategy, the result once
    decided (``(state, outcome, strategy name or "")``)."""

    st: object
    out: FrameOutcome
    reason: str
    next: int = 0
    switched: bool = False
    counts: tuple = (("stability", 0), ("continuation", 0), ("mkeam", 0), ("polish", 0))
    result: tuple | None = None


class Chain(Solver[_Chaining]):
    """The :data:`CHAIN` stages as a :class:`~poise.solvers.iterate.Solver`; the budget is the
    fallback budget. A stage takes two steps: the switch (its ``fallback:`` event row, no
    budget spent), then the stage's run from the frame's input configuration on
    ``history.stage(name)`` (its rows labelled with the stage; the stage's own loops append
    them), spending the stage's iterations; rows a stage returns (why MKEAM failed) follow.
    Two steps, so that the switch row is returned like every other row and still precedes
    the stage's rows.

    A stage: ``name``, ``event(settings, reason)`` (the switch row's text) and
    ``run(model, start, settings, history, frame, cnt, left, prev) -> (state, outcome,
    final, rows, counts)`` (``counts``: its iterations by strategy name)."""

    def __init__(self, model, start, settings, history, frame, cnt, stages=None):
        self.model, self.start, self.settings = model, start, settings
        self.history, self.frame, self.cnt = history, frame, cnt
        self.stages = CHAIN if stages is None else stages

    def init(self, first):
        return _Chaining(self.start, first, first.status.value)

    def terminate(self, s):
        if s.result is not None:
            return True, s.result[1].status
        if s.next == len(self.stages):
            return True, s.out.status
        return False, None

    def step(self, s, left):
        stage = self.stages[s.next]
        if not s.switched:
            return Next(replace(s, switched=True), 0, (
                Row(self.frame, 0, event=stage.event(self.settings, s.reason),
                    strategy=stage.name),))
        st2, out2, final, rows, got = stage.run(self.model, self.start, self.settings,
                                                self.history.stage(stage.name), self.frame,
                                                self.cnt, left, (s.st, s.out))
        s = replace(s, next=s.next + 1, switched=False,
                    counts=tuple((k, got.get(k, n)) for k, n in s.counts))
        if out2.ok:
            s = replace(s, result=(st2, out2, stage.name))
        elif final:
            s = replace(s, result=(st2, out2, ""))
        else:
            s = replace(s, st=st2, out=out2, reason=out2.status.value)
            if out2.status in NO_RECOVERY[:2]:
                s = replace(s, result=(st2, out2, ""))
        return Next(s, got.get(stage.name, 0), rows)

    def postprocess(self, s, status, used):
        st, out, name = s.result if s.result is not None else (s.st, s.out, "")
        return st, out, name, dict(s.counts)


def run_chain(model, start, settings, history, frame, cnt, first: FrameOutcome, budget: int):
    """Try the :data:`CHAIN` strategies after ``first`` failed, within ``budget`` iterations
    in total (:class:`Chain` run by :func:`~poise.solvers.iterate.iterate`). Returns
    ``(state, outcome, used, counts)``; ``counts``: iterations per strategy."""
    return iterate(Chain(model, start, settings, history, frame, cnt), int(budget), history,
                   first)


def continuation(model, state, settings, history, frame, cnt, max_steps=None):
    """Pseudo-transient continuation (PTC): Newton steps on ``(K + mu M) dx = -F``.

    ``mu`` (units 1/time^2) starts comparable to the largest stiffness/mass ratio (over the
    coordinates that have mass), so the first steps follow a damped pseudo-time flow
    ``M dx/dtau = -F`` towards a *stable* equilibrium, and is relaxed by switched evolution
    relaxation ``mu <- mu * |F_new| / |F_old|`` so the last iterations are plain Newton
    (quadratic). Only the Jacobian changes; the residual, and hence the equilibrium found, does
    not. At most ``max_steps`` steps (default ``Limits.ptc_max_iter``); a residual that keeps
    growing (``mu`` beyond ``PTC_MU_GROWTH`` times its start) or turns non-finite ends it as ``diverged``.
    """
    if max_steps is None:
        max_steps = settings.limits.ptc_max_iter
    return iterate(Continuation(model, settings, frame, cnt), int(max_steps), history, state)


@dataclass(frozen=True)
class _Flowing:
    """:class:`Continuation`'s state: the iterate, its outcome once decided, Newton iterations
    so far (``total``), the last step's outcome, ``mu`` (its start, now, bound) and the merit
    the next ``mu`` update compares with."""

    state: object
    outcome: FrameOutcome | None = None
    total: int = 0
    last: FrameOutcome | None = None
    mu0: float = 1.0
    mu: float = 1.0
    mu_max: float = np.inf
    m_old: float = np.nan


class Continuation(Solver[_Flowing]):
    """:func:`continuation` as a :class:`~poise.solvers.iterate.Solver`: ``step`` is one Newton
    step on ``(K + mu M) dx = -F`` and the ``mu`` update; the budget counts steps, the
    outcome the Newton iterations.

    A step returns the rows of its one-iteration Newton, collected and handed to the loop:
    the step row (the point it started from, the step taken) and Newton's closing row (the
    point it reached: converged, or measured and not yet converged); one row when the step
    could not be taken. Two rows, not one merged row: the second measures another point
    (the one the next step starts from), and a converged continuation then ends, like every
    Newton in ``iterations/*``, on the row of its converged point."""

    def __init__(self, model, settings, frame, cnt):
        self.model, self.settings, self.frame, self.cnt = model, settings, frame, cnt
        self.sc = Scales(model, settings)

    def init(self, state):
        model = self.model
        try:
            ev = self.cnt.evaluate(model, state, "jacobian")
        except EvaluationError as e:
            return _Flowing(state, FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, str(e)))
        kd = np.abs(np.asarray(ev.J.diagonal()).ravel()[:model.nq])  # dense or CSR, never densified
        md = model.mass_diagonal(state)
        has = (md > 0) & np.isfinite(kd)
        mu0 = float(np.max(kd[has] / md[has])) if has.any() else 0.0
        if not (np.isfinite(mu0) and mu0 > 0):
            mu0 = 1.0
        return _Flowing(state, mu0=mu0, mu=mu0, mu_max=min(mu0 * PTC_MU_GROWTH, 1e150),
                        m_old=merit(ev, self.sc))               # mu**2 stays finite

    def terminate(self, s):
        return s.outcome is not None, None if s.outcome is None else s.outcome.status

    def postprocess(self, s, status, used):
        if s.outcome is not None:
            return s.state, s.outcome
        imb = s.last.imbalance if s.last is not None else np.nan
        return s.state, FrameOutcome(Status.MAX_ITERATIONS, s.total, imb, np.nan,
                                     f"pseudo-transient continuation did not converge in "
                                     f"{s.total} steps")

    def step(self, s, left):
        mu = s.mu
        s_mu = replace(self.settings, stability=mu * mu, fallback=False, line_search=False)
        rows = []
        st, o = newton(self.model, s.state, s_mu, rows, self.frame, self.cnt, max_iter=1,
                       event=f"continuation mu={mu:.3g}")
        total = s.total + o.iterations
        s = replace(s, total=total, last=o, state=st)
        return Next(self._next(s, o, st, total), 1, tuple(rows))

    def _next(self, s, o, st, total):
        """After the step to ``st`` (Newton's outcome ``o``): the outcome, or the next ``mu``."""
        if o.ok:
            return replace(s, outcome=FrameOutcome(Status.CONVERGED, total, o.imbalance, o.error,
                                                   "converged"))
        if o.status is Status.NONFINITE:
            return replace(s, outcome=replace(o, iterations=total))
        if o.iterations == 0:          # singular even with mu M: the flow cannot move
            return replace(s, outcome=FrameOutcome(o.status, total, o.imbalance, o.error,
                                                   o.message))
        try:
            ev = self.cnt.evaluate(self.model, st, "residual")
        except EvaluationError as e:
            return replace(s, outcome=FrameOutcome(Status.NONFINITE, total, np.nan, np.nan,
                                                   str(e)))
        m_new = merit(ev, self.sc)
        mu = s.mu * np.sqrt(m_new / max(s.m_old, 1e-300)) if np.isfinite(m_new) else np.inf
        if not (np.isfinite(mu) and mu <= s.mu_max):
            return replace(s, outcome=FrameOutcome(Status.DIVERGED, total, o.imbalance, o.error,
                                                   "pseudo-transient continuation diverged "
                                                   "(the residual kept growing)"))
        if mu < PTC_MU_MIN * s.mu0:
            mu = 0.0
        return replace(s, mu=mu, m_old=m_new)
