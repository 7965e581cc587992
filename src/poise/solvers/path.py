"""Verdicts across the frames of a quasi-static path: stiffness sign changes, --require-stable.

Once a run's frames are solved, every converged frame is classified (the classification the
output reuses: :func:`classify_frames`). Two events end the path where they happen:

* the number of negative eigenvalues of the reduced stiffness changes between two frames: the
  path crossed a singular configuration (a bifurcation under load), status
  ``singular_configuration``;
* with ``require_stable``, a frame is not stable enough (:func:`~poise.solvers.stable.
  acceptable`): the run follows the stable branch and ends where it stops being stable, status
  ``unstable``.

The time is located by bisection (:class:`Bisection`, run by the one loop) between the two
frames, each midpoint solved by continuation
from the frame before (:func:`~poise.solvers.quasistatic.fims_step`) and classified; the frames
after the event are dropped and the state just past it is the last frame. :func:`check` gives
the new :class:`~poise.solvers.context.Analysis` and the row it ends with (the strategy's last
step returns it to the loop).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from poise.model.evaluate import evaluate
from poise.model.frame_batch import batchable, chunk_size
from poise.solvers import singular
from poise.solvers.history import Row
from poise.solvers.iterate import Next, Solver, iterate
from poise.solvers.stability import DENSE_LIMIT, classify, classify_dense_frames
from poise.solvers.stable import acceptable
from poise.solvers.status import Status

LOCATE_REL = 1e-9       # bisection width, relative to max(1, |t|)


def cached_info(data, state):
    """The classification of ``state`` made during the solve (``data.infos``), or None."""
    got = data.infos.get(id(state))
    return got[1] if got is not None and got[0] is state else None


def classify_frames(model, data, frames) -> list:
    """Classify ``frames`` (converged states) with the solve's active rows, all at once where
    the model allows it; the results are cached in the per-solve ``data`` for the output."""
    saved = data.mask(model)
    todo = [st for st in frames if cached_info(data, st) is None]
    if todo and model.nq <= DENSE_LIMIT and batchable(model):
        C = chunk_size(model)
        for a in range(0, len(todo), C):
            chunk = todo[a:a + C]
            for st, info in zip(chunk, classify_dense_frames(
                    model, evaluate(model, chunk, "jacobian").J, saved)):
                data.infos[id(st)] = (st, info)
    for st in todo:
        if cached_info(data, st) is None:
            data.infos[id(st)] = (st, classify(model, st, active=saved))
    return [cached_info(data, st) for st in frames]


def check(env, a, step):
    """Apply the module's two rules to the frames of the analysis ``a``: classify the
    converged frames, find the first event, locate it and end the path there. ``step``: the
    continuation step, :func:`~poise.solvers.quasistatic.fims_step`'s signature. Returns
    ``(analysis, rows)``."""
    frames, outcomes, s = list(a.frames), list(a.outcomes), env.settings
    n = next((k for k, o in enumerate(outcomes) if not o.ok), len(outcomes))
    if n == 0 or (a.time_independent and not s.require_stable):
        return a, ()
    infos = classify_frames(env.model, env.data,
                            frames[:n] if not a.time_independent else frames[:1])
    prev, start = None, 0
    while True:
        event = _first_event(infos, s, prev, start)
        if event is None:
            return a, ()
        k, kind, prev = event
        if k == 0:               # --require-stable and the start is not stable enough
            first = replace(outcomes[0], status=Status.UNSTABLE, message=(
                f"no stable equilibrium reached (--require-stable): the start of the path is "
                f"{infos[0].klass}"))
            return replace(a, frames=a.frames[:1], outcomes=(first,)), ()
        lo = k - 1 if kind == "unstable" else prev
        if kind == "unstable":
            same = lambda i: acceptable(i, s)                                       # noqa: E731
        else:
            same = lambda i, n0=infos[lo].n_negative: (i.klass != "unknown"          # noqa: E731
                                                      and i.n_negative == n0)
        st, info, t = _locate(env, frames, step, lo, k, infos[k], same)
        crossed = _crossed(info, infos[lo], infos[k])
        if kind == "unstable" or crossed:
            break
        prev, start = k, k + 1   # the stiffness jumped (a discontinuous load): no singular point
    del frames[lo + 1:], outcomes[lo + 1:]
    env.history.drop_frames_after(lo)
    env.data.infos[id(st)] = (st, info)
    where = singular.SingularInfo(t, "bifurcation", (), _mode(info, infos[lo]))
    if kind == "unstable":
        modes = "; ".join(m.text(short=True) for m in info.mode_list)
        out = singular.SingularOutcome(
            Status.UNSTABLE, 0, np.nan, np.nan,
            f"stability lost at t = {t:.6g} (--require-stable: the path ends where its branch "
            f"stops being stable; there it is {info.klass}" + (f": {modes})" if modes else ")"),
            {}, "plain", where=where if crossed else None)
    else:
        out = singular.singular_outcome(where, 0)
    row = Row(len(frames), 0, np.nan, np.nan, np.nan, np.nan, out.message, "singular")
    return replace(a, frames=(*frames, st), outcomes=(*outcomes, out)), (row,)


def _first_event(infos, s, prev, start):
    """``(frame, kind, previous known frame)`` of the first event from frame ``start`` on
    (``prev``: the last classified frame before it), or None."""
    for k in range(start, len(infos)):
        info = infos[k]
        if s.require_stable and not acceptable(info, s):
            return k, "unstable", prev
        if info.klass == "unknown":
            continue
        if prev is not None and info.n_negative != infos[prev].n_negative:
            return k, "bifurcation", prev
        prev = k
    return None


def _crossed(info, a, b) -> bool:
    """Did an eigenvalue of the reduced stiffness cross zero where the classification changed
    (``info``: just past the change), rather than jump (a discontinuous load or stiffness)?
    Its smallest eigenvalue there is at most ``singular.DROP`` of the smallest eigenvalues of
    the frames ``a`` and ``b`` on either side."""
    scale = max(abs(a.min_eigenvalue), abs(b.min_eigenvalue))
    lam = abs(info.min_eigenvalue)
    return bool(info.klass != "unknown" and np.isfinite(lam) and np.isfinite(scale)
                and lam <= singular.DROP * scale)


def _mode(a, b) -> str:
    """The unstable mode gained or lost between classifications ``a`` and ``b``."""
    more = a if a.n_negative > b.n_negative else b
    ms = [m for m in more.mode_list if m.klass == "unstable"]
    return ms[0].text(short=True) if ms else ""


def _locate(env, frames, step, lo, hi, hi_info, same):
    """Bisection between ``frames`` ``lo`` (``same`` holds) and ``hi`` (it does not)
    (:class:`Bisection` run by the one loop, within ``Limits.locate_max_probes`` midpoints).
    Returns the first state found past the event, its classification and the located time."""
    t_hi = frames[hi].t
    return iterate(Bisection(env, step, hi, same), env.settings.limits.locate_max_probes,
                   env.history, _Bracket(tuple(frames[max(0, lo - 2):lo + 1]), frames[lo].t,
                                         t_hi, frames[hi], hi_info,
                                         LOCATE_REL * max(1.0, abs(t_hi))))


@dataclass(frozen=True)
class _Bracket:
    """:class:`Bisection`'s state: the last (up to 3) states on this side of the event
    (``hist``), the bracket, the first state found past the event and its classification."""

    hist: tuple
    t_lo: float
    t_hi: float
    st_hi: object
    info_hi: object
    tol: float
    stopped: bool = False       # a midpoint could not be solved: the bracket as it is


class Bisection(Solver[_Bracket]):
    """Where a classification changes between two frames: each midpoint solved by
    continuation (``step``, :func:`~poise.solvers.quasistatic.fims_step`'s signature; its rows
    appended by its own loop) from the states before and classified; ``same(info)``: still on
    this side. A spent budget leaves the bracket as far as it got (as a stopped one)."""

    out_of_budget = Status.CONVERGED

    def __init__(self, env, step, hi, same):
        self.env, self.step_to, self.hi, self.same = env, step, hi, same

    def init(self, bracket):
        return bracket

    def terminate(self, s):
        return (True, Status.CONVERGED) if s.stopped or not s.t_hi - s.t_lo > s.tol else (
            False, None)

    def step(self, s, left):
        env = self.env
        model, st_s, data = env.model, env.settings, env.data
        t = 0.5 * (s.t_lo + s.t_hi)
        st, o, _ = self.step_to(model, list(s.hist), t, st_s, env.history, data, self.hi,
                                st_s.limits.path_min_substep * (t - s.t_lo))
        if not o.ok:
            return Next(replace(s, stopped=True))
        info = classify(model, st, active=data.mask(model))
        if self.same(info):
            return Next(replace(s, hist=(*s.hist, st)[-3:], t_lo=t))
        return Next(replace(s, st_hi=st, info_hi=info, t_hi=t))

    def postprocess(self, s, status, used):
        return s.st_hi, s.info_hi, 0.5 * (s.t_lo + s.t_hi)
