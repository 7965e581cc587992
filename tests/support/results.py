"""A synthetic two-analysis results file (:func:`make_result`) for the writer, reader and output
tests: labels with non-ASCII text, a failed FIM_D analysis, timings and warnings."""
from __future__ import annotations

import numpy as np

from poise.results.data import AnalysisResult, RunResult


def make_result(timings=None) -> RunResult:
    F, B, J = 3, 2, 1
    rng = np.random.default_rng(0)
    a0 = AnalysisResult(
        index=0, analysis_type="static", method="FIM_S", status="converged",
        message="converged", settings={"max_num_iter": 25, "max_imbalance": 1e-6},
        datasets={
            "time": np.array([0.0]),
            "bodies/id": np.array([10, 20]),
            "bodies/label": np.array(["arm", "bras \u00e9l\u00e8ve"]),
            "bodies/position": rng.normal(size=(1, B, 3)),
            "bodies/orientation": np.broadcast_to(np.eye(3), (1, B, 3, 3)).copy(),
            "joints/id": np.array([5]),
            "joints/force": rng.normal(size=(1, J, 3)),
            "joints/torque": rng.normal(size=(1, J, 3)),
            "frames/converged": np.array([True]),
            "frames/iterations": np.array([5]),
            "frames/imbalance": np.array([3.2e-9]),
            "frames/error": np.array([1e-12]),
            "frames/stability": np.array(["unknown"]),
            "iterations/frame": np.zeros(5, dtype=np.int64),
            "iterations/iteration": np.arange(5),
            "iterations/imbalance": np.logspace(0, -8, 5),
            "iterations/worst_equation": np.array(["<Constraint_Joint id=5> rot_x"] * 5),
            "iterations/event": np.array(["assembly", "newton", "newton", "newton", "newton"]),
            "redundant/tag": np.array([], dtype=str),
            "redundant/id": np.zeros(0, dtype=np.int64),
            "frames/strategy_iterations": np.array([[1, 2, 0, 0, 2]], dtype=np.int32),
        },
        attrs={"reactions_unique": True, "assembled": False},
    )
    a1 = AnalysisResult(
        index=1, analysis_type="static", method="FIM_D", status="failed",
        message="no convergence after 25 iterations\n(fallback: FIM_S)",
        settings={"method": "FIM_D"},
        datasets={
            "time": np.arange(F, dtype=float),
            "bodies/position": np.zeros((F, B, 3)),
            "frames/converged": np.array([True, True, False]),
            "frames/iterations": np.array([3, 4, 25]),
            "frames/imbalance": np.array([1e-9, 1e-9, 12.5]),
            "frames/error": np.array([0.0, 0.0, 0.1]),
            "frames/stability": np.array(["stable", "stable", "unknown"]),
        },
    )
    return RunResult(
        deck="decks/x.xml", deck_sha256="ab" * 32,
        units="force=NEWTON mass=KILOGRAM length=MILLIMETER time=SECOND",
        active_effects=["gravity", "revolute"], command="poise solve decks/x.xml",
        analyses=[a0, a1],
        model_datasets={"bodies/id": np.array([10, 20]), "bodies/mass": np.array([1.0, 2.5])},
        timings=timings if timings is not None else {"parse": 0.01, "solve": 0.2},
        counts={"residuals": 40, "jacobians": 12},
        warnings=["decks/x.xml:3: <Part id=10>: unknown attribute 'foo' ignored"],
    )
