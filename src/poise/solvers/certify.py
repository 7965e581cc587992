"""One convergence rule for every method's frames (FIM_S, FIM_D, MKEAM, fallbacks).

A frame is reported converged only if the state written for it meets the ``Param_Static``
tolerances, measured at that state (the output evaluation that also feeds reactions and loads):
every force row ``<= max_imbalance``, every moment row ``<= max_imbalance * L``, every
constraint row ``<= max_error`` (rotational) or ``max_error * L`` (translational) — the scales
of FIM_S's Newton test (:class:`~poise.solvers.newton.Scales`) — and the method's own error
estimate (e.g. Newton's last step), where it defines one, ``<= max_error``. Whatever a method's
internal test said (MKEAM's kinetic energy, IDA's local error test), a frame that fails this is
demoted to ``Status.TOLERANCE_NOT_MET`` and the message says which tolerance it missed.
"""
from __future__ import annotations

import numpy as np

from poise.model.evaluate import Evaluation
from poise.solvers.iterate import evolve
from poise.solvers.newton import Scales, measures
from poise.solvers.status import Status


def certify(model, settings, outcome, r, phi, sc=None) -> tuple:
    """Measure ``outcome``'s frame from its residual ``r`` (nq,) and constraint values ``phi``
    (nc,, inactive rows zeroed) and apply the rule above. Returns ``(certified outcome,
    measures)``: a new outcome whose ``imbalance`` is the measured infinity norm of ``r`` and
    ``error`` the larger of the measured constraint error and the method's own estimate (if
    finite), demoted if it misses a tolerance; the measures are ``(imbalance, constraint
    error, worst equation)``."""
    sc = sc if sc is not None else Scales(model, settings)
    imb, cerr, zinf, worst = measures(model, Evaluation(r=r, phi=phi, J=None), sc)
    own = outcome.error
    outcome = evolve(outcome, imbalance=imb,
                     error=max(cerr, float(own)) if np.isfinite(own) else cerr)
    measured = (imb, cerr, worst)
    if not outcome.ok:
        return outcome, measured
    zr = np.abs(r) / sc.r_tol if len(r) else np.zeros(1)
    k = int(np.argmax(zr))
    if not (np.all(np.isfinite(zr)) and zr[k] <= 1.0):
        if model.q_kind[k] == 1:
            what = (f"moment imbalance {abs(r[k]):.3g} > max_imbalance * L = {sc.r_tol[k]:.3g} "
                    f"(max_imbalance {settings.max_imbalance:g})")
        else:
            what = f"imbalance {abs(r[k]):.3g} > max_imbalance {settings.max_imbalance:g}"
    elif not (np.isfinite(zinf) and zinf <= 1.0):
        what = f"constraint error {cerr:.3g} > max_error {settings.max_error:g}"
    elif not outcome.error <= settings.max_error:
        what = f"error {outcome.error:.3g} > max_error {settings.max_error:g}"
    else:
        return outcome, measured
    return evolve(outcome, status=Status.TOLERANCE_NOT_MET,
                  message=(f"not converged: {what} at the reported state"
                           + (f"; worst equation: {worst}" if worst else ""))), measured
