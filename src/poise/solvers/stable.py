"""``--require-stable``: when Newton's equilibrium is unstable, reach a stable one downhill.

:func:`descend` is an inertia-controlled Newton: the tangent stiffness is shifted by the
smallest ``sigma`` whose ``L D L^T`` inertia says the reduced matrix is positive definite, so
every step is a descent direction; steps are limited and backtracked (Armijo) on the potential
energy of trials projected onto the constraints (:mod:`poise.solvers.trials`). The energy never
increases; the end point is Newton-polished. :func:`seek_stable` runs it first from the input
Newton started from (the rest position downhill from the input), then, if that does not end
stable, leaves Newton's equilibrium along its unstable modes (escape: the trial of lowest
energy, both signs, shrinking) and descends again (unstable end point -> escape again).
Without a potential energy the trapezoidal work of the applied forces is the energy change.
Every escape and descent step is a history row; past the budget (``STEPS_PER_ITER x
max_num_iter`` steps, ``MAX_ESCAPES`` escapes) the analysis fails with status ``unstable``.
MKEAM uses :func:`descend` as its fast continuation (``Relaxation._handover``).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from poise.core.errors import EvaluationError
from poise.core.wording import plural
from poise.solvers.energy import potential_energy
from poise.solvers.linalg import SingularMatrix
from poise.solvers.newton import (
    FrameOutcome,
    Scales,
    initial_multipliers,
    measures,
    newton,
)
from poise.solvers.pencil_dense import DENSE_PENCIL, DensePencil
from poise.solvers.reach import assemble
from poise.solvers.stability import AUG_RHO, SparsePencil, unknown_info
from poise.solvers.status import Status
from poise.solvers.trials import Chord, LagrangeTest, Projector, project, trial_tol, violation_work

ESCAPE_ROT = 0.3          # rad: largest rotation of the first escape trial
ESCAPE_TRANS = 0.05       # x L: largest translation of the first escape trial
ESCAPE_SHRINK = (1.0, 0.3, 0.1, 0.03, 0.01)
MAX_ESCAPES = 20
STEPS_PER_ITER = 2        # descent budget: this many x max_num_iter Newton steps in all
STEP_TRANS = 0.4          # x L: largest translation of one descent step
STEP_ROT = 1.0            # rad: largest rotation of one descent step
EXTEND = 2.0              # a shifted full step accepted at once is tried this much longer ...
MAX_EXTEND = 3            # ... at most this many times (within the step limits)
SKIP_ZERO_SHIFT = 0.05    # x spectral radius: above, the next step does not try sigma = 0


def acceptable(info, settings) -> bool:
    """Is the classification good enough for ``require_stable``: ``stable``, or ``neutral``
    when ``allow_neutral``."""
    return info.klass == "stable" or (info.klass == "neutral" and settings.allow_neutral)


def require_stable_check(frames, message: str, settings) -> tuple:
    """The driver's step after a static frame is measured: with ``require_stable``, a
    converged frame whose classification is not :func:`acceptable` fails (status
    ``unstable``, exit 1; the results are written as they are). ``frames``: the analysis'
    :class:`~poise.solvers.record.FrameSet`. Returns ``(frames, message, failed)``."""
    out = frames.outcomes[0]
    if not settings.require_stable or not out.ok:
        return frames, message, False
    klass = frames.stability[0].klass
    if klass == "stable" or (klass == "neutral" and settings.allow_neutral):
        return frames, message, False
    why = f"the equilibrium found is {klass}"
    if klass == "neutral":
        why += " and --no-allow-neutral was given"
    elif klass == "unknown":
        why += " (its stability could not be established)"
    rest = "; ".join(m for m in message.split("; ") if m and m != "converged")
    return (frames.with_outcome(0, replace(out, status=Status.UNSTABLE)),
            "no stable equilibrium reached (--require-stable): " + why
            + (f"; {rest}" if rest else ""), True)


def _energy_drop(model, a, b, cnt, pa=None):
    """``V(b) - V(a)`` (potential energy, or minus the trapezoidal work of the applied forces
    along the tangent difference when the model has no potential). Returns (dV, V(b))."""
    pb = potential_energy(model, b)
    if pa is None:
        pa = potential_energy(model, a)
    if np.isfinite(pa) and np.isfinite(pb):
        return pb - pa, pb
    dq = model.local_difference(a, b)
    # residual r = -Q + G^T lam: its projection on a constraint-respecting step is -Q . dq
    ra = np.asarray(cnt.evaluate(model, a, "residual", every_row=True).r).ravel()[:model.nq]
    rb = np.asarray(cnt.evaluate(model, b, "residual", every_row=True).r).ravel()[:model.nq]
    return 0.5 * float((ra + rb) @ dq), np.nan


def _escape_direction(model, info):
    vs = [np.asarray(v, float) for v in info.vectors if np.all(np.isfinite(v))]
    if not vs:
        return None
    d = np.zeros(model.nq)
    for v in vs:
        n = float(np.max(np.abs(v * model.q_scale)))
        if n > 0:
            d += v / n
    # unit: the largest rotation 1 rad / translation 1 L
    rot = model.q_kind == 1
    sr = float(np.max(np.abs(d[rot]))) if np.any(rot) else 0.0
    st = float(np.max(np.abs(d[~rot]))) / model.L if np.any(~rot) else 0.0
    s = max(sr / ESCAPE_ROT, st / ESCAPE_TRANS)
    return d / s if s > 0 else None


def seek_stable(model, state, settings, history, frame, cnt, info, classify_at, start=None):
    """Continue from the unstable equilibrium ``state`` (classification ``info``) to a stable
    one. ``classify_at(state) -> StabilityInfo``. Returns ``(state, outcome, info, note)``;
    ``outcome.ok`` only at an equilibrium whose classification is :func:`acceptable`; ``info``
    is the returned state's classification (``unknown`` when the descent stopped short of an
    equilibrium), also when the outcome fails.

    ``start``: the (assembled) input Newton started from. The descent is tried from there
    first, with at most half the budget: it is the rest position reached downhill from the
    input (MKEAM's answer), and Newton's path into an unstable equilibrium often leaves the
    model in a shape far from any minimum (a chain released as a V converges to a kinked V;
    the descent from there is several times longer: docs/mkeam.md). If that does not end at an
    acceptable equilibrium, Newton's point is left along its unstable modes."""
    budget = STEPS_PER_ITER * settings.max_num_iter
    used = 0
    if start is not None:
        history.add(frame, 0, np.nan, np.nan, event=f"stable: Newton's equilibrium is unstable "
                    f"({plural(info.n_negative, 'negative mode')}): descent from the input")
        why = []
        try:
            st, out, _, used = descend(model, start, settings, history, frame, cnt,
                                       budget // 2, why=why)
        except (EvaluationError, SingularMatrix) as e:
            out = None
            why.append(f"{type(e).__name__}: {e}")
        if out is not None:
            i2 = classify_at(st)
            if acceptable(i2, settings):
                note = (f"--require-stable: Newton's equilibrium was unstable "
                        f"({plural(info.n_negative, 'negative mode')}); descended from the input "
                        f"({plural(used, 'step')}) to a "
                        f"{i2.klass} one")
                return st, FrameOutcome(Status.CONVERGED, used, np.nan, np.nan, "converged"), \
                    i2, note
        history.add(frame, 0, np.nan, np.nan, event="stable: the descent from the input did not "
                    "end at a stable equilibrium" + (f" ({why[0]})" if why else "") +
                    "; leaving Newton's along its unstable modes")
    escapes = 0
    pe = potential_energy(model, state)
    while True:
        if acceptable(info, settings):
            note = (f"--require-stable: left {escapes} unstable equilibri"
                    f"{'um' if escapes == 1 else 'a'} downhill ({plural(used, 'descent step')}) to a "
                    f"{info.klass} one")
            return state, FrameOutcome(Status.CONVERGED, used, np.nan, np.nan, "converged"), info, note
        if info.klass != "unstable":
            why = (f"the equilibrium reached is {info.klass}" +
                   (" and --no-allow-neutral was given" if info.klass == "neutral" else "") +
                   (f" ({info.modes})" if info.modes else ""))
            return state, _fail(used, why), info, ""
        if escapes >= MAX_ESCAPES or used >= budget:
            return state, _fail(used, f"still unstable ({plural(info.n_negative, 'negative mode')}) "
                                f"after {plural(escapes, 'escape')} and "
                                f"{plural(used, 'descent step')} (budget "
                                f"{budget} = {STEPS_PER_ITER} x max_num_iter)"), info, ""
        d = _escape_direction(model, info)
        if d is None:
            return state, _fail(used, "unstable, and no unstable mode vector to leave it along"), \
                info, ""
        escapes += 1
        history.add(frame, 0, np.nan, np.nan, event=f"stable: escape {escapes}: unstable "
                    f"({plural(info.n_negative, 'negative mode')})")
        moved = None
        for f in ESCAPE_SHRINK:
            for sgn in (1.0, -1.0):
                try:
                    x, ok = project(model, model.retract(state, sgn * f * d), cnt)
                    if not ok:
                        x, _, ast = assemble(model, x, settings, history, frame, cnt)
                        if not ast.ok:
                            continue
                    dv, pe_x = _energy_drop(model, state, x, cnt, pe)
                except EvaluationError:
                    continue
                if dv < 0 and (moved is None or dv < moved[0]):
                    moved = (dv, x, pe_x)
            if moved is not None:
                break
        if moved is None:
            return state, _fail(used, "unstable, and no move along its unstable modes lowers "
                                "the potential energy"), info, ""
        _, state, pe = moved
        state = initial_multipliers(model, state, cnt)
        why = []
        state, out, pe, n = descend(model, state, settings, history, frame, cnt,
                                    budget - used, pe, why=why)
        used += n
        if out is None:
            reason = why[0] if why else (f"the descent did not reach an equilibrium within its "
                                         f"budget ({budget} = {STEPS_PER_ITER} x max_num_iter "
                                         "steps)")
            return state, _fail(used, reason + _zero_modes_at(classify_at, state)), \
                unknown_info(f"not classified: not at an equilibrium ({reason})"), ""
        info = classify_at(state)


def _zero_modes_at(classify_at, state) -> str:
    """``"; the point reached has N zero-stiffness modes (...)"`` when it has any: the neutral
    directions a descent cannot resolve by energy (their energy does not change)."""
    try:
        info = classify_at(state)
    except (EvaluationError, SingularMatrix, ValueError, ArithmeticError):
        return ""
    if info.n_zero > 0:
        return (f"; the point reached has {plural(info.n_zero, 'zero-stiffness mode')} "
                f"({info.modes})")
    return ""


def _ic_step(model, state, cnt, sigma, like=None):
    """One inertia-controlled Newton direction at ``state``: ``(K_s + sigma D) dq + G^T y = -r``,
    ``G dq = -phi`` in the equilibrated length coordinates of the pencil (sparse, or
    :class:`~poise.solvers.pencil_dense.DensePencil` for small models; ``D`` its diagonal
    metric), with the
    smallest ``sigma`` (0, else from a quarter of the last step's, grown by 8; 0 is not tried
    after a shift above ``SKIP_ZERO_SHIFT``) whose KKT inertia is ``(nq, m, 0)``: the reduced
    matrix is positive definite and ``dq`` a descent direction of the potential energy.
    ``like``: the previous step's pencil (its elimination order and scaling are reused; when
    no valid factorisation is found with them, a fresh pencil is tried).
    Returns ``(dq, sigma, ev, dlam, chord)``: ``dq`` None when no valid factorisation was
    found; ``chord``: the factorised step (:class:`~poise.solvers.trials.Chord`) the
    line-search projections reuse."""
    ev = cnt.evaluate(model, state, "jacobian")
    pencil = DensePencil if model.nq + model.nc <= DENSE_PENCIL else SparsePencil
    P = pencil(model, ev.J, active=cnt.active, like=like)
    out = _ic_solve(model, P, ev, cnt, sigma)
    if out[0] is None and P.reused:
        out = _ic_solve(model, pencil(model, ev.J, active=cnt.active), ev, cnt, sigma)
    return out


def _ic_solve(model, P, ev, cnt, sigma):
    nq, m = P.nq, P.m
    r = np.asarray(ev.r, float)[:nq]
    f = -(P.dq / P.d) * r
    g = -P.dl * np.asarray(ev.phi, float)[P.rows] if m else np.zeros(0)
    scale = P.eps / 1e-8                      # spectral radius estimate of Kt
    # plain Newton (sigma = 0) whenever the inertia allows; after a step that needed a large
    # shift, start from a quarter of it (the zero-shift factorisation would almost surely fail)
    k0 = 1 if sigma > SKIP_ZERO_SHIFT * scale else 0
    sig = max(sigma / 4.0, 1e-6 * scale) if k0 else 0.0
    for k in range(k0, 40):
        for rho in AUG_RHO:
            F = cnt.factor((-sig, rho), lambda at: P.ldl(*at))      # the pencil at (shift, rho)
            if F.ok and np.all(np.abs(F.pivots) > 1e-14 * scale):
                break
        if F.ok and F.n_negative == m and np.all(np.abs(F.pivots) > 1e-14 * scale):
            b = np.concatenate([f + rho * (P.Gt.T @ g), g]) if m else f
            sol = F.solve(b)
            if np.all(np.isfinite(sol)):
                dlam = np.zeros(model.nc)
                dlam[P.rows] = P.dl * sol[nq:]
                return sol[:nq] * P.dq / P.d, sig, ev, dlam, Chord(P, F, rho)
        sig = max(sigma / 4.0, 1e-6 * scale) if k == 0 else 8.0 * sig
    return None, sig, ev, None, None


def descend(model, state, settings, history, frame, cnt, budget, pe=None, why=None):
    """Inertia-controlled Newton from ``state`` down to an equilibrium (:func:`_ic_step`
    directions limited to ``STEP_ROT`` rad / ``STEP_TRANS`` x L, an Armijo backtracking on the
    potential energy of the trial projected onto the constraints by :func:`project`, starting
    at twice the last accepted step; the Newton polish once a full step with ``sigma = 0`` was
    taken, its point kept only if its energy is not higher). The potential energy never
    increases. Returns ``(state, outcome or None, pe, steps)``; on None, the reason is
    appended to the list ``why`` when one is given (:func:`_stalled`)."""
    sc = Scales(model, settings)
    if pe is None:
        pe = potential_energy(model, state)
    sigma = 0.0
    steps = 0
    polish_fail = 0
    alpha0 = 1.0                       # first trial: twice the last accepted step (<= 1)
    like = None                        # the last step's pencil (order and scaling reused)
    why = [] if why is None else why
    failed = 0                         # line searches failed in a row
    imb = np.nan
    while steps < budget:
        try:
            dq, sigma, ev, dlam, chord = _ic_step(model, state, cnt, sigma, like)
        except EvaluationError as e:
            why.append(f"an element could not be evaluated during the descent ({e})")
            return state, None, pe, steps
        steps += 1
        imb, cerr, zinf, worst = measures(model, ev, sc)
        if dq is None:
            history.add(frame, steps, imb, cerr, np.nan, np.nan, worst,
                        "stable-descent: no valid factorisation", pos=state.pos, rot=state.rot)
            why.append(_stalled(imb, sigma, failed))
            return state, None, pe, steps
        like = chord.P
        # step limits (a trust region on the linearisation of the constraints)
        rot = model.q_kind == 1
        big = max(float(np.max(np.abs(dq[rot]), initial=0.0)) / STEP_ROT,
                  float(np.max(np.abs(dq[~rot]), initial=0.0)) / (STEP_TRANS * model.L), 1.0)
        dq = dq / big
        slope = float(np.asarray(ev.r, float)[:model.nq] @ dq)
        proj = Projector(model, cnt, chord)
        work = violation_work(model, ev, state)
        lagrange = LagrangeTest(model, ev, state, cnt) if np.isfinite(pe) else None
        alpha = alpha0
        accepted = None
        for _ in range(12):
            try:
                x = model.retract(state, alpha * dq)
                x, ok = proj(x, trial_tol(alpha, slope, work))   # not projected: shorter
                if ok:
                    dv, pe_x = _energy_drop(model, state, x, cnt, pe)
                    tol = 1e-13 * max(abs(pe) if np.isfinite(pe) else 0.0, 1.0)
                    goal = 1e-4 * alpha * min(slope, 0.0) + tol
                    if dv + proj.err * work <= goal or (
                            lagrange is not None and
                            lagrange.decrease(dv, proj, state.lam + min(alpha, 1.0) * dlam)
                            <= goal):
                        accepted = (x, pe_x if np.isfinite(pe_x) else pe + dv)
                        break
            except EvaluationError:
                pass
            alpha *= 0.5
        if accepted is not None and alpha == 1.0 and sigma > 0.0 and big == 1.0:
            alpha, accepted = _extend(model, state, dq, proj, cnt, pe, slope, accepted, work)
        history.add(frame, steps, imb, cerr, float(np.max(np.abs(alpha * dq) / sc.q_len)),
                    alpha if accepted else np.nan, worst,
                    f"stable-descent sigma={sigma:.3g}", pos=state.pos, rot=state.rot)
        if zinf <= 1.0 and (accepted is None or
                            not accepted[1] < pe - 1e-13 * max(abs(pe), 1.0)):
            break                      # at an equilibrium already (no step lowers the energy
            #                            either): the polish certifies it, the caller classifies
        if accepted is None:
            failed += 1
            sigma = max(8.0 * sigma, 1.0) if sigma > 0 else 0.0
            if sigma == 0.0:
                why.append(_stalled(imb, sigma, failed))
                return state, None, pe, steps
            continue
        failed = 0
        state, pe = accepted
        alpha0 = min(1.0, 2.0 * alpha)
        state.lam = state.lam + min(alpha, 1.0) * dlam     # the KKT step's multiplier update
        if sigma == 0.0 and alpha == 1.0 and big == 1.0 and polish_fail < 3:
            st, o = newton(model, state, replace(settings, fallback=False), history, frame,
                           cnt, max_iter=min(settings.max_num_iter, 20), event="stable-polish")
            steps += o.iterations
            if o.ok:
                dv, _ = _energy_drop(model, state, st, cnt, pe)
                if dv <= 1e-9 * max(abs(pe) if np.isfinite(pe) else 0.0, 1.0):
                    return st, o, pe + dv, steps
            polish_fail += 1
    st, o = newton(model, state, replace(settings, fallback=False), history, frame, cnt,
                   max_iter=min(settings.max_num_iter, 20), event="stable-polish")
    steps += o.iterations
    if o.ok:
        return st, o, pe, steps
    why.append(f"not at an equilibrium after {plural(steps, 'descent step')} (imbalance {imb:.3g}; "
               f"budget {budget}), and Newton's polish from there failed ({o.message})"
               if steps >= budget else
               f"the descent stopped at imbalance {imb:.3g} and Newton's polish from there "
               f"failed ({o.message})")
    return state, None, pe, steps


def _stalled(imb, sigma, failed):
    """Why the descent stopped without a step (not the budget: it was not used up)."""
    if failed:
        return (f"the descent stalled at imbalance {imb:.3g}: no trial along "
                f"{plural(failed, 'successively shifted direction')} (shift up to {sigma:.3g}) "
                "lowered the potential energy measurably")
    return (f"the descent stalled at imbalance {imb:.3g}: no shift of the stiffness (up to "
            f"{sigma:.3g}) gave a positive definite reduced matrix with a reliable "
            "factorisation")


def _extend(model, state, dq, proj, cnt, pe, slope, accepted, work):
    """A full shifted step that was accepted at once and stays inside the step limits: the
    shift made the quadratic model conservative, so try ``EXTEND`` x longer steps along it (up
    to the limits) while each lowers the energy more. Returns ``(alpha, (state, pe))``."""
    rot = model.q_kind == 1
    room = 1.0 / max(float(np.max(np.abs(dq[rot]), initial=0.0)) / STEP_ROT,
                     float(np.max(np.abs(dq[~rot]), initial=0.0)) / (STEP_TRANS * model.L),
                     1e-300)
    alpha, best = 1.0, accepted
    for _ in range(MAX_EXTEND):
        a = min(EXTEND * alpha, room)
        if a <= alpha * 1.01:
            break
        try:
            x, ok = proj(model.retract(state, a * dq), trial_tol(a, slope, work))
            if not ok:
                break
            dv, pe_x = _energy_drop(model, state, x, cnt, pe)
        except EvaluationError:
            break
        pe_new = pe_x if np.isfinite(pe_x) else pe + dv
        if not (pe_new + proj.err * work < best[1]
                and dv + proj.err * work <= 1e-4 * a * min(slope, 0.0)):
            break
        alpha, best = a, (x, pe_new)
    return alpha, best


def _fail(used, why):
    return FrameOutcome(Status.UNSTABLE, used, np.nan, np.nan,
                        "no stable equilibrium reached (--require-stable): " + why)
