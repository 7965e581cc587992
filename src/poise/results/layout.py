"""Where a solved analysis goes in the results file: the one module that knows its paths.

The solvers hand on typed records (:class:`poise.solvers.record.AnalysisRecord`: frames,
history, redundant rows, compliance, the method's statistics); :func:`analysis_datasets` maps
them onto the declared schema (``docs/results-format.md``, :mod:`poise.results.schema`): the
analysis group's datasets keyed by their path relative to the group, and its attributes.
Element output groups (``joints/*``, ``forces/*``, ...) are the registry's declarations
(:mod:`poise.results.schema_groups`); what the model's frame hooks give is already named by
its element types and passes through.
"""
from __future__ import annotations

import numpy as np

from poise.elements.rotation import euler_313, euler_parameters
from poise.solvers.history import STRATEGIES
from poise.solvers.record import AnalysisRecord, ComplianceRecord, FrameSet, IdaSteps, MkeamRun


def analysis_datasets(rec: AnalysisRecord) -> tuple[dict, dict]:
    """``(datasets, attrs)`` of the analysis group of ``rec``."""
    d, attrs = {}, dict(rec.attrs)
    if rec.frames is not None:
        d.update(frame_datasets(rec.frames))
        if rec.stage_totals:
            attrs.update(stage_totals(rec.frames))
    d.update(rec.element_outputs)
    if rec.compliance is not None:
        d.update(compliance_datasets(rec.compliance))
    if rec.history is not None:
        d.update(history_datasets(rec.history, rec.frames))
        if rec.analysis_type == "static" and "iterations/pose_row" in d:     # rows with poses
            attrs["iterations_poses_stride"] = int(rec.history.pose_stride)
    d.update(redundant_datasets(rec.redundant))
    if isinstance(rec.method_data, IdaSteps):
        d.update(steps_datasets(rec.method_data))
    elif isinstance(rec.method_data, MkeamRun):
        d.update(mkeam_datasets(rec.method_data, rec.history))
    return d, attrs


def frame_datasets(fs: FrameSet) -> dict:
    """``time``, ``bodies/*``, each output group's loads, ``frames/*`` and ``modes/*``."""
    d = {"time": fs.time, "bodies/id": fs.body_id, "bodies/position": fs.position,
         "bodies/orientation": fs.orientation,
         "bodies/euler_parameters": euler_parameters(fs.orientation),
         "bodies/euler_313": euler_313(fs.orientation),
         "bodies/rotation_from_input": fs.rotation_from_input}
    for g, gl in fs.groups.items():
        d[f"{g}/id"] = gl.ids
        if gl.tag is not None:
            d[f"{g}/tag"] = gl.tag
        d[f"{g}/force"] = gl.force
        d[f"{g}/torque"] = gl.torque
        if gl.unique is not None:
            d[f"{g}/unique"] = gl.unique
    outs = fs.outcomes
    d["frames/converged"] = np.array([o.ok for o in outs])
    d["frames/iterations"] = np.array([o.iterations for o in outs], dtype=np.int64)
    d["frames/imbalance"] = np.array([o.imbalance for o in outs])
    d["frames/error"] = np.array([o.error for o in outs])
    d["frames/status"] = np.array([o.status.value for o in outs], dtype=str)
    d["frames/strategy"] = np.array([o.strategy for o in outs], dtype=str)
    d["frames/strategy_iterations"] = fs.strategy_iterations
    d.update(stability_datasets(fs.stability))
    return d


def stability_datasets(infos) -> dict:
    """Per frame (F): ``frames/stability``, ``frames/n_negative``, ``frames/n_zero``,
    ``frames/stability_modes`` (text), ``frames/min_stiffness_eigenvalue``, ``frames/n_modes``;
    the described modes as numbers, flat in frame order (K = the sum of ``n_modes``; the frame
    of mode ``j`` is ``np.repeat(np.arange(F), n_modes)[j]``): ``modes/class``, ``modes/kind``
    (K,) strings, ``modes/body`` (K,) ids, ``modes/direction`` (K, 3) unit vectors,
    ``modes/eigenvalue`` (K,)."""
    ml = [mo for info in infos for mo in info.mode_list]
    return {
        "frames/stability": np.array([i.klass for i in infos], dtype=str),
        "frames/n_negative": np.array([i.n_negative for i in infos], dtype=np.int64),
        "frames/n_zero": np.array([i.n_zero for i in infos], dtype=np.int64),
        "frames/stability_modes": np.array([i.modes for i in infos], dtype=str),
        "frames/min_stiffness_eigenvalue": np.array([i.min_eigenvalue for i in infos]),
        "frames/n_modes": np.array([len(i.mode_list) for i in infos], dtype=np.int64),
        "modes/class": np.array([mo.klass for mo in ml], dtype=str),
        "modes/kind": np.array([mo.kind for mo in ml], dtype=str),
        "modes/body": np.array([mo.body for mo in ml], dtype=np.int64),
        "modes/direction": np.array([mo.direction for mo in ml], float).reshape(len(ml), 3),
        "modes/eigenvalue": np.array([mo.eigenvalue for mo in ml], float),
    }


def stage_totals(fs: FrameSet) -> dict:
    """Analysis attributes ``iterations_<stage>``: iterations per recovery stage over the
    frames, and ``iterations_total``."""
    it = fs.strategy_iterations
    tot = it.sum(axis=0) if it.size else np.zeros(len(STRATEGIES), np.int64)
    out = {f"iterations_{n}": int(v) for n, v in zip(STRATEGIES, tot)}
    out["iterations_total"] = int(tot.sum())
    return out


def history_datasets(history, frames: FrameSet | None = None) -> dict:
    """``iterations/<column>`` (rows measured at an output frame show the measures of
    ``frames``) and, when rows carried poses, ``iterations/position``,
    ``iterations/orientation``, ``iterations/pose_row``."""
    cols = history.columns(None if frames is None else frames.measures)
    d = {f"iterations/{k}": v for k, v in cols.items()}
    poses = history.poses()
    if poses is not None:
        rows, P, R = poses
        d.update({"iterations/position": P, "iterations/orientation": R,
                  "iterations/pose_row": rows})
    return d


def redundant_datasets(rows) -> dict:
    """``redundant/*``: the deck element and equation of every redundant constraint row
    (``model.row_info`` entries)."""
    return {
        "redundant/tag": np.array([r["tag"] for r in rows], dtype=str),
        "redundant/id": np.array([r["id"] for r in rows], dtype=np.int64),
        "redundant/equation": np.array([r["equation"] for r in rows], dtype=str),
        "redundant/line": np.array([r["line"] for r in rows], dtype=np.int64),
    }


def compliance_datasets(c: ComplianceRecord) -> dict:
    return {"frames/compliance": c.matrices,
            "frames/compliance_flag": np.array(c.flags, dtype=str),
            "compliance/marker_id": c.marker_id,
            "compliance/method": np.array(c.method, dtype=str)}


def steps_datasets(s: IdaSteps) -> dict:
    return {f"steps/{k}": np.asarray(v, dtype=float if k in ("time", "step_size") else np.int64)
            for k, v in s.columns.items()}


def mkeam_datasets(run: MkeamRun, history) -> dict:
    """The MKEAM columns of ``iterations/*`` (NaN, and -1 integrator steps, on the rows of
    other solvers) and ``mkeam/*``."""
    d = {f"iterations/{k}": v for k, v in history.mkeam_columns().items()}
    if run.iterates:
        d["mkeam/iterate_position"] = np.stack([p for p, _ in run.iterates])
        d["mkeam/iterate_orientation"] = np.stack([r for _, r in run.iterates])
    d["mkeam/position"] = run.position
    d["mkeam/orientation"] = run.orientation
    d["mkeam/initial_potential_energy"] = np.array(run.initial_potential_energy)
    return d
