"""One static analysis (FIM_S): redundancy -> assembly -> multipliers -> Newton -> outputs.

``FIM_D`` requested for a pure static analysis falls back to FIM_S (recorded in the message),
as the specification says.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from poise.core.errors import EvaluationError
from poise.results.data import STATUS_CONVERGED, STATUS_FAILED, AnalysisResult
from poise.solvers.fallback import solve_frame
from poise.solvers.history import History
from poise.solvers.newton import Counters, FrameOutcome, assemble, initial_multipliers
from poise.solvers.outputs import element_loads
from poise.solvers.redundancy import (dependent_rows, left_null_basis, min_norm_multipliers,
                                      redundant_rows)
from poise.solvers.status import MESSAGES, Status


def detect_redundancy(model, state) -> np.ndarray:
    """Redundant constraint rows at ``state`` (sets ``model.row_active``)."""
    model.row_active[:] = True
    if model.nc == 0:
        return np.zeros(0, int)
    ev = model.evaluate(state, need_jac=True)
    J = ev.J
    Pq = J[model.nq:, :model.nq]
    col = np.where(model.q_kind == 1, 1.0 / model.L, 1.0)
    red = redundant_rows(Pq, col)
    model.row_active[red] = False
    return red


class StaticAnalysis:
    """A single static equilibrium with FIM_S.

    Parameters
    ----------
    model : Model
    settings : StaticSettings
    redundancy : ndarray or None
        Redundant rows found by an earlier analysis (detection runs once per model).
    """

    def __init__(self, model, request, redundancy=None):
        self.model = model
        self.request = request
        self.settings = request.settings
        self.redundancy = redundancy
        self.counters = Counters()
        self.history = History()

    def run(self, state, index: int = 0):
        model, s = self.model, self.settings
        notes = []
        method = "FIM_S"
        if s.method == "FIM_D":
            notes.append("FIM_D falls back to FIM_S for a pure static analysis")
        moved = False
        try:
            if self.redundancy is None:
                self.redundancy = detect_redundancy(model, state)
            else:
                model.row_active[:] = True
                model.row_active[self.redundancy] = False
            red = self.redundancy
            if len(red):
                notes.append(f"{len(red)} redundant constraint equations removed")
            state, moved, ast = assemble(model, state, s, self.history, 0, self.counters)
            if moved:
                notes.append("initial configuration assembled onto the constraints")
            if not ast.ok:
                out = FrameOutcome(Status.ASSEMBLY_FAILED, 0, np.nan, np.nan,
                                   MESSAGES[Status.ASSEMBLY_FAILED])
            else:
                state = initial_multipliers(model, state, self.counters)
                state, out = solve_frame(model, state, s, self.history, 0, self.counters)
                if out.ok and s.require_stable:
                    state, out = self._require_stable(state, out, notes)
        except EvaluationError as e:
            if self.redundancy is None:
                self.redundancy = np.zeros(0, int)
            red = self.redundancy
            out = FrameOutcome(Status.NONFINITE, 0, np.nan, np.nan, str(e))
        ar = AnalysisResult(index=index, analysis_type="static", method=method,
                            settings=dict(s.as_dict(), method_requested=s.method))
        ar.attrs["reactions_unique"] = bool(len(red) == 0)
        ar.attrs["assembled"] = bool(moved)
        ar.datasets.update(self.frame_datasets(state, [out]))     # certifies ``out``
        ar.status = STATUS_CONVERGED if out.ok else STATUS_FAILED
        ar.message = "; ".join([out.message] + notes)
        from poise.solvers.stable import require_stable_check
        require_stable_check(ar, out, s)
        ar.datasets.update(stack_frames([frame_outputs(model, state)]))
        from poise.solvers.compliance import attach     # after frame_datasets (stability)
        attach(ar, model, [state], [out], self.redundancy, s)
        ar.datasets.update(self.history.datasets())
        ar.attrs.update(self.history.attrs())
        ar.attrs.update(strategy_attrs(ar.datasets))
        ar.datasets.update(self.redundancy_datasets())
        return state, ar

    def _require_stable(self, state, out, notes):
        """``require_stable``: classify the converged point; unstable -> continue downhill to a
        stable equilibrium (:func:`poise.solvers.stable.seek_stable`)."""
        from poise.solvers.stability import classify
        from poise.solvers.stable import acceptable, seek_stable
        model, s = self.model, self.settings
        info = classify(model, state)
        if acceptable(info, s) or info.klass != "unstable":
            return state, out        # judged on the output classification
        st, o, _, note = seek_stable(model, state, s, self.history, 0, self.counters, info,
                                     lambda x: classify(model, x))
        if note:
            notes.append(note)
        return st, replace(o, iterations=out.iterations + o.iterations)

    # ------------------------------------------------------------------ outputs
    def frame_datasets(self, state, outcomes, on_eval=None):
        """Datasets of one frame. ``on_eval(ev, active)``, if given, is called with the output
        evaluation (all rows active) and the analysis' active-row mask before the outcomes are
        read (FIM_D records its interpolated frames' measures from it: no second evaluation).
        The outcomes are certified on that evaluation (:func:`~poise.solvers.certify.certify`:
        measured imbalance / error; demoted if the tolerances are not met)."""
        model = self.model
        # one evaluation (all rows active, slot data kept) serves the minimum-norm reactions,
        # the element loads and the stability classification
        saved = model.row_active.copy()
        model.row_active[:] = True
        J = None
        dep = np.asarray(self.redundancy, int)
        try:
            ev = model.evaluate(state, need_jac=True, keep=True)
            J = ev.J
            if on_eval is not None:
                on_eval(ev, saved)
            from poise.solvers.certify import certify
            for o in outcomes:
                certify(model, self.settings, o, ev.r, np.where(saved, ev.phi, 0.0))
            lam = state.lam
            if len(self.redundancy) and model.nc:
                Pfull = J[model.nq:, :model.nq]
                Y = left_null_basis(Pfull, saved)       # one factorisation serves both
                w = np.where(model.row_kind == 1, 1.0 / model.L ** 2, 1.0)
                lam = min_norm_multipliers(Pfull, state.lam, saved, w, Y=Y)
                dep = dependent_rows(Pfull, saved, Y=Y)
            loads = element_loads(model, state, lam=lam, reuse=True)
        except EvaluationError:
            loads = {}
        model.row_active[:] = saved
        d = output_datasets(model, [state], {g: (F[None], T[None]) for g, (F, T) in loads.items()},
                            dep, outcomes)
        from poise.solvers.stability import classify, stability_datasets, unknown_info
        if all(o.ok for o in outcomes) and J is not None:
            d.update(stability_datasets([classify(model, state, J=J)]))
        else:   # the same datasets either way: frames of a sequence are concatenated by key
            d.update(stability_datasets([unknown_info()] * len(outcomes)))
        return d


    def redundancy_datasets(self):
        m = self.model
        rows = [m.row_info[r] for r in self.redundancy]
        return {
            "redundant/tag": np.array([r["tag"] for r in rows], dtype=str),
            "redundant/id": np.array([r["id"] for r in rows], dtype=np.int64),
            "redundant/equation": np.array([r["equation"] for r in rows], dtype=str),
            "redundant/line": np.array([r["line"] for r in rows], dtype=np.int64),
        }


def output_datasets(model, frames, loads, dep, outcomes) -> dict:
    """Datasets of ``frames`` (one or many) common to every analysis: ``time``, ``bodies/*``,
    per output group the ids, tags, element loads and (joints, jprims) reaction-uniqueness
    flags, and ``frames/*`` of the ``outcomes``.

    ``loads``: ``{group: (F, T)}`` with arrays (n_frames, n_group, 3); groups missing are
    zero. ``dep``: constraint rows taking part in a dependency (not unique).
    """
    nf = len(frames)
    d = {"time": np.array([s.t for s in frames])}
    d["bodies/id"] = model.body_id
    d["bodies/position"] = np.stack([s.pos for s in frames])
    d["bodies/orientation"] = np.stack([s.rot for s in frames])
    d.update(orientation_datasets(model, frames, d["bodies/orientation"]))
    for g, o in model.outputs.items():
        n_out = len(o["ids"])
        zero = np.zeros((nf, n_out, 3))
        F, T = loads.get(g, (zero, zero))
        d[f"{g}/id"] = np.asarray(o["ids"])
        if g == "forces":
            d["forces/tag"] = np.asarray(o["tag"], dtype=str)
        d[f"{g}/force"] = F
        d[f"{g}/torque"] = T
        if g in ("joints", "jprims"):
            uniq = np.ones(n_out, bool)
            for r in dep:
                ri = model.row_info[r]
                if ri["group"] == g:
                    uniq[ri["owner"]] = False
            d[f"{g}/unique"] = uniq
    d["frames/converged"] = np.array([o.ok for o in outcomes])
    d["frames/iterations"] = np.array([o.iterations for o in outcomes], dtype=np.int64)
    d["frames/imbalance"] = np.array([o.imbalance for o in outcomes])
    d["frames/error"] = np.array([o.error for o in outcomes])
    d["frames/status"] = np.array([o.status.value for o in outcomes], dtype=str)
    d.update(strategy_datasets(outcomes))
    return d


def orientation_datasets(model, frames, rot) -> dict:
    """``bodies/euler_parameters`` (F,B,4), ``bodies/euler_313`` (F,B,3) of the orientations
    ``rot`` (F,B,3,3) and ``bodies/rotation_from_input`` (F,B,3): each state's continuous
    rotation vector (turns counted by State.rotvec; principal, |v| <= pi, for a state without
    it). docs/results-format.md defines them."""
    from poise.elements.rotation import euler_313, euler_parameters
    if all(s.rotvec is not None for s in frames):       # every frame at once
        rv = model.rotation_from_input(None, rot, np.stack([s.rotvec for s in frames]))
    else:
        rv = np.stack([model.rotation_from_input(s) for s in frames])
    return {"bodies/euler_parameters": euler_parameters(rot), "bodies/euler_313": euler_313(rot),
            "bodies/rotation_from_input": rv}


def strategy_datasets(outcomes) -> dict:
    """``frames/strategy`` (the recovery stage that produced each frame, ``plain`` without
    recovery) and ``frames/strategy_iterations`` (F, len(STRATEGIES)): each frame's iterations
    split by stage (columns in :data:`~poise.solvers.history.STRATEGIES` order; they sum to
    ``frames/iterations``)."""
    from poise.solvers.history import STRATEGIES
    it = np.zeros((len(outcomes), len(STRATEGIES)), np.int64)
    for k, o in enumerate(outcomes):
        c = o.counts or {"plain": o.iterations}
        for j, name in enumerate(STRATEGIES):
            it[k, j] = int(c.get(name, 0))
        it[k, 0] += int(o.iterations) - int(it[k].sum())   # work not split: plain
    return {"frames/strategy": np.array([o.strategy for o in outcomes], dtype=str),
            "frames/strategy_iterations": it}


def strategy_attrs(datasets) -> dict:
    """Analysis attributes ``iterations_<strategy>``: totals over the frames, and
    ``iterations_total``."""
    from poise.solvers.history import STRATEGIES
    it = np.asarray(datasets.get("frames/strategy_iterations", np.zeros((0, len(STRATEGIES)))))
    tot = it.sum(axis=0) if it.size else np.zeros(len(STRATEGIES), np.int64)
    out = {f"iterations_{n}": int(v) for n, v in zip(STRATEGIES, tot)}
    out["iterations_total"] = int(tot.sum())
    return out


def frame_outputs(model, state) -> dict:
    """Per-frame datasets from the model's output hooks (requests, contact points, ...).

    Each hook in ``model.frame_hooks`` is ``hook(model, state) -> {path: array}`` for ONE frame;
    callers stack frames along a new leading axis (see :func:`stack_frames`).
    """
    out = {}
    for hook in getattr(model, "frame_hooks", []):
        out.update(hook(model, state))
    return out


def stack_frames(per_frame: list[dict]) -> dict:
    """Stack a list of per-frame dicts along axis 0 (keys ending in ``/id`` are not stacked)."""
    if not per_frame:
        return {}
    out = {}
    for k in per_frame[0]:
        if k.endswith("/id") or k.endswith("/tag") or k.endswith("/label"):
            out[k] = np.asarray(per_frame[0][k])
        else:
            out[k] = np.stack([np.asarray(f[k]) for f in per_frame])
    return out

