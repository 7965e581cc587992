"""The documented fallback chain for FIM_S static solves that fail.

When plain Newton (with step limits and line search) does not converge, these strategies are
tried in order, each starting from the *input* configuration of the frame; every switch is
recorded in the iteration history (``iterations/event`` = ``fallback: <strategy>: <reason>``):

1. ``stability``: Newton again with ``stability`` raised to ``FALLBACK_STABILITY`` (a larger mass
   fraction in the Jacobian only: it never changes the equilibrium, it steadies the steps near
   neutral or singular directions).
2. ``continuation``: pseudo-transient continuation — Newton steps with ``mu M`` added to the
   Jacobian, ``mu`` relaxed by switched evolution relaxation (see :func:`continuation`): a damped
   pseudo-time flow far from equilibrium that turns into plain Newton near it.
3. ``mkeam``: kinetic-energy attrition (only stable equilibria) followed by a Newton polish.

``--no-fallback`` (``fallback=False`` in the overrides) turns the chain off.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from poise.errors import EvaluationError
from poise.solvers.newton import FrameOutcome, _evaluate, newton
from poise.solvers.status import Status

FALLBACK_STABILITY = 1e-2
PTC_MAX_ITER = 200
PTC_MU_MIN = 1e-12


def run_chain(model, start, settings, history, frame, cnt, first: FrameOutcome):
    """Try the fallback strategies after ``first`` failed. Returns ``(state, outcome, used)``."""
    reason = first.status.value
    # 1. larger stability
    s1 = replace(settings, stability=max(settings.stability, FALLBACK_STABILITY))
    history.add(frame, 0, np.nan, np.nan, event=f"fallback: stability={s1.stability:g}: {reason}")
    st, out = newton(model, start.copy(), s1, history, frame, cnt, event="fallback-stability")
    if out.ok:
        return st, out, "stability"
    reason = out.status.value
    # 2. pseudo-transient continuation
    history.add(frame, 0, np.nan, np.nan, event=f"fallback: continuation: {reason}")
    st, out = continuation(model, start.copy(), settings, history, frame, cnt)
    if out.ok:
        return st, out, "continuation"
    reason = out.status.value
    # 3. MKEAM (imported only when the chain gets this far)
    history.add(frame, 0, np.nan, np.nan, event=f"fallback: mkeam: {reason}")
    try:
        from poise.solvers.mkeam import relax
        st2, ok = relax(model, start.copy(), settings, history, frame, cnt)
    except Exception as e:   # noqa: BLE001 - any MKEAM failure just ends the chain
        history.add(frame, 0, np.nan, np.nan, event=f"fallback: mkeam failed: {e}")
        return st, out, ""
    if ok:
        st3, out3 = newton(model, st2, settings, history, frame, cnt, event="fallback-polish")
        if out3.ok:
            return st3, out3, "mkeam"
        return st3, out3, ""
    return st, out, ""


def continuation(model, state, settings, history, frame, cnt):
    """Pseudo-transient continuation (PTC): Newton steps on ``(K + mu M) dx = -F``.

    ``mu`` (units 1/time^2) starts comparable to the largest stiffness/mass ratio, so the first
    steps follow a damped pseudo-time flow ``M dx/dtau = -F`` towards a *stable* equilibrium, and
    is relaxed by switched evolution relaxation ``mu <- mu * |F_new| / |F_old|`` so the last
    iterations are plain Newton (quadratic). Only the Jacobian changes; the residual, and hence
    the equilibrium found, does not.
    """
    from poise.solvers.newton import Scales, merit
    sc = Scales(model, settings)
    try:
        ev = _evaluate(model, state, cnt, need_jac=True)
    except EvaluationError as e:
        return state, FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, str(e))
    kd = np.abs(np.asarray(ev.J.diagonal()).ravel()[:model.nq])     # dense or CSR, never densified
    md = np.maximum(model.mass_diagonal(state), 1e-300)
    mu = float(np.max(kd / md)) if model.nq else 0.0
    m_old = merit(ev, sc)
    total = 0
    for _ in range(PTC_MAX_ITER):
        s_mu = replace(settings, stability=mu * mu, fallback=False, line_search=False)
        st, o = newton(model, state, s_mu, history, frame, cnt, max_iter=1,
                       event=f"continuation mu={mu:.3g}")
        total += o.iterations
        if o.ok:
            return st, FrameOutcome(Status.CONVERGED, total, o.imbalance, o.error, "converged")
        if o.status in (Status.NONFINITE,):
            return st, o
        state = st
        ev = _evaluate(model, state, cnt, need_jac=False)
        m_new = merit(ev, sc)
        mu = mu * np.sqrt(m_new / max(m_old, 1e-300))
        if mu < PTC_MU_MIN * max(float(np.max(kd / md)), 1e-300):
            mu = 0.0
        m_old = m_new
    return state, FrameOutcome(Status.MAX_ITERATIONS, total, np.nan, np.nan,
                               f"pseudo-transient continuation did not converge in {PTC_MAX_ITER} steps")
