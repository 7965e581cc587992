"""MKEAM as an analysis method: relaxation (solvers/relaxation.py), then a Newton polish.

The polished point is reported if it is a stable equilibrium (projected stiffness positive
semi-definite) reached within ``POLISH_MAX_DQ`` of the MKEAM point or downhill from it;
otherwise the MKEAM point itself. Either way the result is converged only if it meets
``max_imbalance`` / ``max_error``. Details: docs/mkeam.md.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from poise.core.errors import EvaluationError
from poise.core.wording import plural
from poise.solvers.context import AnalysisSolver, Finished, begin
from poise.solvers.history import History
from poise.solvers.linalg import SingularMatrix
from poise.solvers.newton import FrameOutcome, Scales, initial_multipliers, merit, newton
from poise.solvers.reach import assemble
from poise.solvers.relaxation import Relaxation, mkeam_run
from poise.solvers.status import Status

POLISH_MAX_DQ = 0.05         # polished point must stay this close (x L / rad)


@dataclass(frozen=True)
class MkeamRunState:
    """The MKEAM method's own state in its :class:`~poise.solvers.context.Analysis`: when it
    started (wall clock), the MKEAM point, the relaxation's restart points and the potential
    energy it started from (its record, :func:`~poise.solvers.relaxation.mkeam_run`)."""

    t_start: float
    mk_state: Any
    iterates: tuple = ()
    pe_start: float = np.nan


class MkeamMethod(AnalysisSolver):
    """A static analysis by MKEAM: one frame, relaxed downhill then polished by Newton."""

    name = "MKEAM"
    stage_totals = False

    def __init__(self, env):
        super().__init__(env)
        self.model, self.settings = env.model, env.settings
        self.history, self.counters = env.history, env.data

    def start(self, a, state):
        t0 = time.perf_counter()
        at = [a, None]           # the analysis and the Relaxation as far as they got
        try:
            out, st, mk_state = self._solve(at, state)
        except EvaluationError as e:   # nonfinite, with what the prologue found
            return replace(at[0].nonfinite(state, str(e)),
                           method=self._run_state(t0, state, at[1]))
        return replace(at[0].added(st, out), method=self._run_state(t0, mk_state, at[1]))

    @staticmethod
    def _run_state(t0, mk_state, rx):
        if rx is None:
            return MkeamRunState(t0, mk_state)
        return MkeamRunState(t0, mk_state, tuple(rx.iterates), rx.pe_start)

    def finish(self, a, status, used):
        m = a.method
        attrs = {"mkeam_wall_time": time.perf_counter() - m.t_start}
        return Finished(a, mkeam_run(m.iterates, m.mk_state, m.pe_start), attrs)

    def _solve(self, at, state):
        """Redundancy, assembly, MKEAM iterations, Newton polish (``at``: ``[analysis,
        relaxation]``, updated as they are made). Returns ``(outcome, reported state, MKEAM
        point)``; the outcome is certified at output, at the reported state."""
        model, env = self.model, self.env
        if not np.isfinite(model.L):
            if at[0].redundancy is None:
                at[0] = replace(at[0], redundancy=np.zeros(0, int))
            return FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan,
                                "the model size L is not finite (a marker or body lies too far "
                                "out): MKEAM's step and tolerance scales are undefined"), state, state
        at[0], state, failed = begin(env, at[0], state, multipliers=False)
        if failed is not None:
            return failed, state, state
        try:
            rx = at[1] = Relaxation(model, self.settings, self.history, self.counters)
        except ValueError as e:
            return FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, str(e)), state, state
        state = initial_multipliers(model, state, self.counters)
        rx.report = env.report
        try:
            mk_state, status, msg, n_it = rx.run(state)
        except EvaluationError as e:
            mk_state, status, msg, n_it = state, Status.NONFINITE, str(e), len(rx.iterates)
        except SingularMatrix as e:     # constraints that cannot be solved for the momenta
            mk_state, status, n_it = state, Status.SINGULAR_JACOBIAN, len(rx.iterates)
            msg = (f"MKEAM: the constraint matrix G M^-1 G^T is singular ({e}): the constraints "
                   "lock a direction, or masses and inertias span too many decades")
        finally:
            env.report("MKEAM", None, self.settings.max_num_iter)
        if not status.ok:
            return FrameOutcome(status, n_it, np.nan, np.nan, msg), mk_state, mk_state
        state, out, note = self._polish(rx, mk_state, n_it)
        at[0] = at[0].noted(note)
        return out, state, mk_state

    def _polish(self, rx, mk_state, n_it):
        """Newton polish of the MKEAM point. Returns ``(state, outcome, note)``.

        Newton with the deck's settings first. If it fails, once more without the ``stability``
        term, without line search and with an equilibrated factorisation: a mode many decades
        softer than the others (1e-9 N/mm next to 1e12) is invisible to the integration's step
        and kinetic-energy scales, its stiffness drowns under ``sqrt(stability) M`` (Newton
        crawls) and the unequilibrated matrix looks singular. The polished point is reported if
        it is a stable equilibrium (projected stiffness positive semi-definite) and either stays
        within ``POLISH_MAX_DQ`` of the MKEAM point or is reached downhill (potential energy
        non-increasing along the path, :meth:`_downhill`: MKEAM's own guarantee); its outcome is
        Newton's. Otherwise the MKEAM point is reported (outcome certified at output)."""
        m, s = self.model, self.settings
        st = initial_multipliers(m, mk_state, self.counters)
        mk_out = FrameOutcome(Status.CONVERGED, n_it, np.nan, np.nan, "converged")
        trial, out = newton(m, st, s, self.history, 0, self.counters, event="polish")
        if not out.ok and out.status not in (Status.NONFINITE, Status.INCONSISTENT_CONSTRAINTS):
            s0 = replace(s, stability=0.0, line_search=False)
            t2, o2 = newton(m, st, s0, self.history, 0, self.counters, event="polish-soft",
                            equilibrate=True)
            if o2.ok or (o2.status is not Status.NONFINITE and self._lower(rx, t2, trial)):
                trial, out = t2, o2
        if out.status is Status.INCONSISTENT_CONSTRAINTS:
            return trial, replace(out, iterations=n_it), "Newton polish of the MKEAM point"
        if out.status is Status.NONFINITE:
            return st, mk_out, f"Newton polish failed ({out.message}); MKEAM point reported"
        if not out.ok and not self._lower(rx, trial, st):
            return st, mk_out, (f"Newton polish did not converge ({out.message}); MKEAM point "
                                "reported")
        d = rx.max_dq(st, trial)
        far = d > POLISH_MAX_DQ and not (rx.extras_free or rx.dyn.extras_free)
        if far:
            why = self._downhill(rx, st, trial)
            if why:
                return st, mk_out, (f"Newton polish moved {d:.3g} (> {POLISH_MAX_DQ}) {why}; "
                                    "MKEAM point reported")
        wmin, _ = rx.projected_stiffness_min(trial)
        if wmin is not None and wmin < -1e-6:
            return st, mk_out, "Newton polish reached an unstable point; MKEAM point reported"
        note = "Newton-polished MKEAM point reported"
        if far:
            note += (f" (the polish moved {d:.3g} downhill from the MKEAM point: a mode too soft "
                     "for the integration)")
        if out.ok:
            return trial, FrameOutcome(Status.CONVERGED, n_it, out.imbalance, out.error,
                                       "converged"), note
        worst = out.message.partition("; worst equation: ")[2]
        return trial, FrameOutcome(out.status, n_it, out.imbalance, out.error, (
            f"the Newton polish of the MKEAM point stopped ({out.status.value}, "
            f"{plural(out.iterations, 'iteration')}) at imbalance {out.imbalance:.3g}, error "
            f"{out.error:.3g} (max_imbalance {s.max_imbalance:g}, max_error {s.max_error:g})"
            + (f"; worst equation: {worst}" if worst else ""))), note

    def _lower(self, rx, a, b):
        """Is state ``a`` closer to equilibrium than ``b``: lower potential energy when the model
        has one, else a smaller tolerance-scaled residual."""
        pa, pb = rx.potential_energy(a), rx.potential_energy(b)
        if np.isfinite(pa) and np.isfinite(pb):
            return pa < pb
        sc = Scales(self.model, self.settings)
        act = self.counters.active
        ma = merit(self.model.evaluate(a, need_jac=False, active=act), sc)
        mb = merit(self.model.evaluate(b, need_jac=False, active=act), sc)
        return ma < mb

    def _downhill(self, rx, a, b):
        """"" if the potential energy does not increase along the path from ``a`` to ``b`` (the
        tangent line at ``a``, ``limits.polish_path_samples`` samples, each assembled onto the
        constraints), else why."""
        m, s = self.model, self.settings
        n = s.limits.polish_path_samples
        dq = m.local_difference(a, b)
        pes = [rx.potential_energy(a)]
        scratch = History()
        for k in range(1, n):
            x = m.retract(a, (k / n) * dq)
            x, _, ast = assemble(m, x, s, scratch, 0, self.counters)
            if not ast.ok:
                return "along a path that leaves the constraints"
            pes.append(rx.potential_energy(x))
        pes.append(rx.potential_energy(b))
        pes = np.asarray(pes)
        if not np.all(np.isfinite(pes)):
            return "and the model has no potential energy to check that the path is downhill"
        tol = 1e-10 * float(np.max(np.abs(pes)))
        if np.any(np.diff(pes) > tol):
            return "over a potential-energy barrier"
        return ""
