"""The caps of the method-internal loops (MKEAM, the stable descent, FIM_D's start and
corrector), declared in one frozen record: no loop has a literal cap.

Each field bounds one loop run by :func:`~poise.solvers.iterate.iterate` (its budget) or one
bounded search inside a step (a line search, a shift search). Kept together so they move as
one block into the solve's declared limits (issue 24).
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MethodLimits:
    # MKEAM (solvers/relaxation.py, solvers/ke_peak.py, solvers/rattle.py)
    rattle_constraint_iter: int = 30   # multiplier corrections of one RATTLE position solve
    algebraic_iter: int = 20           # Newton steps on the massless scalar unknowns
    mkeam_steps_per_iter: int = 1000   # integrator steps of one KE iteration (then restart)
    mkeam_total_steps: int = 5000      # integrator steps of one MKEAM run (all iterations)
    peak_search_steps: int = 12        # RATTLE steps of the kinetic-energy peak search
    mkeam_perturbs: int = 3            # kicks off an unstable MKEAM point
    handover_cap: int = 20             # steps of a large model's first KE iterations
    handover_steps: int = 2            # the hand-over descent: this many x max_num_iter steps
    polish_path_samples: int = 16      # samples of the polish's downhill path check
    # the stable descent and its escapes (solvers/stable.py, solvers/trials.py)
    stable_steps_per_iter: int = 2     # descent budget: this many x max_num_iter steps
    stable_escapes: int = 20           # escapes from unstable equilibria
    stable_backtrack: int = 12         # Armijo halvings of one descent step
    stable_extend: int = 3             # extensions of a shifted step accepted at once
    stable_shift_tries: int = 40       # stiffness shifts tried for a positive definite pencil
    stable_polish_tries: int = 3       # Newton polishes tried inside the descent
    stable_polish_iter: int = 20       # Newton iterations of one polish (at most)
    project_iter: int = 30             # projection iterations of one line-search trial ...
    project_refresh: int = 4           # ... and its factorisations
    # Newton's step down the potential (solvers/downhill.py)
    downhill_backtrack: int = 8        # energy line-search halvings
    downhill_shifts: int = 6           # mass shifts tried, each x 10
    # FIM_D (solvers/chart.py)
    ida_start_newton: int = 3          # chord-Newton corrections of a (re)start point
    correct_iter: int = 4              # simplified-Newton corrections of an output frame


#: The limits every method-internal loop uses.
METHOD_LIMITS = MethodLimits()
