"""Solver outcome codes (a status, never an exception, for non-convergence)."""
from __future__ import annotations

from enum import Enum


class Status(str, Enum):
    CONVERGED = "converged"
    MAX_ITERATIONS = "max_iterations"
    DIVERGED = "diverged"
    SINGULAR_JACOBIAN = "singular_jacobian"
    NONFINITE = "nonfinite"
    ASSEMBLY_FAILED = "assembly_failed"
    STEP_TOO_SMALL = "step_too_small"
    INCONSISTENT_CONSTRAINTS = "inconsistent_constraints"
    TOLERANCE_NOT_MET = "tolerance_not_met"
    NO_EQUILIBRIUM = "no_equilibrium"
    UNSTABLE = "unstable"
    SINGULAR_CONFIGURATION = "singular_configuration"

    @property
    def ok(self) -> bool:
        return self is Status.CONVERGED


MESSAGES = {
    Status.CONVERGED: "converged",
    Status.MAX_ITERATIONS: "did not converge within max_num_iter iterations (raise max_num_iter, "
                           "start closer to equilibrium, or try MKEAM)",
    Status.DIVERGED: "Newton iterations diverged (start closer to equilibrium or try MKEAM)",
    Status.SINGULAR_JACOBIAN: "singular Jacobian (a direction without stiffness or mass: "
                              "increase stability, or check for an unrestrained body)",
    Status.NONFINITE: "an element produced NaN or Inf",
    Status.ASSEMBLY_FAILED: "could not bring the input configuration onto the constraints",
    Status.STEP_TOO_SMALL: "quasi-static step became smaller than the minimum",
    Status.INCONSISTENT_CONSTRAINTS: "redundant constraint equations contradict the others (the "
                                     "joints cannot all be satisfied: align their markers or "
                                     "remove the redundant joint)",
    Status.TOLERANCE_NOT_MET: "the result does not meet the Param_Static tolerances",
    Status.NO_EQUILIBRIUM: "no equilibrium exists (a direction without stiffness carries a "
                           "load); the fallback chain was not tried",
    Status.UNSTABLE: "no stable equilibrium reached (--require-stable)",
    Status.SINGULAR_CONFIGURATION: "the path reaches a singular configuration (the constraints "
                                   "lose rank or the reduced stiffness reaches zero): no "
                                   "equilibrium continues the branch beyond it",
}
