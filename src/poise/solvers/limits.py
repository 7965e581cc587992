"""The internal iteration caps and budgets of the solvers, declared once.

Every loop of :mod:`poise.solvers` takes its budget from declared settings, never from a
literal: the deck's ``max_num_iter`` / ``fallback_max_num_iter``
(:class:`~poise.solvers.settings.StaticSettings`) for the user-visible work, and the
:class:`Limits` below for the internal ones (how long an inner correction, projection, search or
bisection may run before the loop that owns it gives up with its declared status). They are
poise's own (MotionSolve has no such knobs), not deck attributes, so they are not written to
the results; ``StaticSettings.limits`` reaches them (:data:`LIMITS`, one frozen instance).
Each field says what it bounds and why the default is enough; docs/solvers.md has the
measurements behind them.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Limits:
    """Internal iteration caps (counts unless said otherwise)."""

    # ---- frame level: Newton, assembly, their projections (solvers/newton.py, reach.py, steps.py)
    #: Gauss-Newton steps of the assembly onto the constraints: quadratic from any reasonable
    #: input, so 50 only runs out on a configuration the constraints cannot reach
    assembly_max_iter: int = 50
    #: halvings of Newton's backtracking line search (a step cut below 1/256 has stalled)
    line_search_max: int = 8
    #: Newton iterations whose merit must halve at least once, else it crawls (walk downhill)
    crawl_window: int = 6
    #: Gauss-Newton projections of a trial back onto its constraints (reach.project): it must
    #: halve the violation each time, so 12 cover 1e-3 -> 1e-10 with room
    project_max_iter: int = 12
    #: shrinks of a limited Newton step until no body moves beyond ``max_translation_step``
    #: (each aims at the limit; a retraction's curvature needs at most a few)
    limit_step_tries: int = 4

    # ---- analysis level: quasi-static continuation (solvers/quasistatic.py, path.py)
    #: Newton iterations of one continuation step (at most ``max_num_iter``): a step from a
    #: good prediction converges in a handful, more means halve the step
    substep_max_iter: int = 15
    #: Newton iterations of a bisection probe locating where a branch ends
    probe_max_iter: int = 8
    #: Newton iterations of the return test next to a singular point (Newton is slow there)
    return_max_iter: int = 30
    #: smallest sub-step, as a fraction of the output interval (10 halvings): below it a
    #: failing step is a jump, a singular point or a fallback case
    min_substep_fraction: float = 2.0 ** -10
    #: the same for the midpoint re-solves of the path check (solvers/path.py)
    path_min_substep: float = 2.0 ** -10
    #: bisection probes locating where a branch ends (each halves the bracket: 100 reach
    #: any ``LOCATE_REL`` in double precision, so it never cuts a bisection short)
    locate_max_probes: int = 100
    #: sub-steps of one continuation step (each forward sub-step is at least
    #: ``min_substep_fraction`` of the interval, halvings between): never reached by a path
    #: that sub-steps as designed; reached, the step fails as ``step_too_small``
    max_substeps: int = 8192
    #: inverse iterations for the smallest singular value of a large model's Jacobian
    #: (solvers/singular.py): converged to the few digits a diagnosis needs
    inverse_steps: int = 12

    # ---- fallback chain (solvers/fallback.py)
    #: pseudo-transient continuation steps, at most (also bounded by the fallback budget)
    ptc_max_iter: int = 200

    # ---- FIM_D (solvers/fim_d.py, chart.py)
    #: accepted IDA steps per run, plus ``ida_steps_per_frame`` per output frame
    ida_max_steps: int = 2000
    ida_steps_per_frame: int = 20
    #: chord-Newton corrections of an IDA (re)start point
    start_newton: int = 3
    #: simplified-Newton corrections of an output frame
    correct_max_iter: int = 4

    # ---- MKEAM (solvers/relaxation.py, rattle.py, mkeam.py)
    #: integrator steps of one kinetic-energy iteration before it restarts
    max_steps_per_iter: int = 1000
    #: integrator steps of one MKEAM run, all iterations
    max_total_steps: int = 5000
    #: steps with only noise-level energies: the iteration is at rest
    rest_steps: int = 50
    #: kicks off an unstable MKEAM point
    max_perturb: int = 3
    #: RATTLE position corrections of one integrator step (quadratic: a few suffice)
    rattle_max_iter: int = 30
    #: Newton solves of the curve parameters at fixed body poses (relaxation, rattle)
    extras_max_iter: int = 20
    #: samples of the path from the MKEAM point to its Newton polish (downhill check)
    polish_path_samples: int = 16
    #: RATTLE steps of the kinetic-energy peak search (regula falsi on the power: a few)
    peak_search_steps: int = 12
    #: integrator steps of a large model's first KE iterations before the hand-over
    handover_cap: int = 20
    #: the hand-over descent's budget: this many x max_num_iter steps
    handover_steps: int = 2

    # ---- the stable descent and its escapes (solvers/stable.py, downhill.py, trials.py)
    #: escape trials off an unstable point
    max_escapes: int = 20
    #: descent budget of --require-stable: this many x max_num_iter steps in all
    descent_steps_per_iter: int = 2
    #: stiffness shifts tried (each x 8) for a positive definite pencil of one descent step
    shift_tries: int = 40
    #: halvings of one descent step's energy line search
    descent_backtrack: int = 12
    #: lengthenings of a shifted full step accepted at once
    max_extend: int = 3
    #: failed Newton polishes of the descent before it stops trying them
    polish_fails: int = 3
    #: Newton iterations of one polish (at most ``max_num_iter``)
    polish_max_iter: int = 20
    #: halvings of the energy line search of a step down the potential (downhill.py)
    backtrack: int = 8
    #: shifts tried for a step down the potential, each x 10
    mu_tries: int = 6
    #: projection iterations of one line-search trial back onto the constraints (trials.py)
    trial_project_max_iter: int = 30
    #: ... and its factorisations
    trial_max_refresh: int = 4


#: The limits every solve uses (``StaticSettings.limits``).
LIMITS = Limits()
