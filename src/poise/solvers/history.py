"""Per-iteration history, recorded as data (written to ``iterations/...``)."""
from __future__ import annotations

import numpy as np

COLUMNS = ("frame", "iteration", "imbalance", "error", "step_norm", "step_length",
           "worst_equation", "event")


class History:
    """Append-only table of solver iterations (every frame, every method)."""

    def __init__(self):
        self.rows: list[tuple] = []

    def add(self, frame, iteration, imbalance, error, step_norm=np.nan, step_length=np.nan,
            worst_equation="", event="newton"):
        self.rows.append((int(frame), int(iteration), float(imbalance), float(error),
                          float(step_norm), float(step_length), str(worst_equation), str(event)))

    def __len__(self):
        return len(self.rows)

    def datasets(self, prefix="iterations/") -> dict:
        cols = list(zip(*self.rows)) if self.rows else [[] for _ in COLUMNS]
        out = {}
        for name, col in zip(COLUMNS, cols):
            if name in ("frame", "iteration"):
                out[prefix + name] = np.asarray(col, dtype=np.int64)
            elif name in ("worst_equation", "event"):
                out[prefix + name] = np.asarray(col, dtype=str) if len(col) else np.zeros(0, dtype=str)
            else:
                out[prefix + name] = np.asarray(col, dtype=float)
        return out
