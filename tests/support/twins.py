"""Compare two runs of the same model (an Adams dataset and its XML twin): every dataset of the
model and of each analysis, numbers to a tolerance relative to the dataset's largest magnitude,
integers and text exactly. Provenance (deck path, hash, lines, timings, warnings) is not compared:
the two files differ there by design."""
from __future__ import annotations

import numpy as np

#: datasets that name source locations (element tags or deck lines): provenance
PROVENANCE = ("iterations/worst_equation", "iterations/message", "redundant/line")


def _differs(x, y, rtol: float) -> str | None:
    x, y = np.asarray(x), np.asarray(y)
    if x.shape != y.shape:
        return f"shape {x.shape} != {y.shape}"
    if x.dtype.kind in "fc":
        if np.array_equal(x, y, equal_nan=True):
            return None
        finite = np.isfinite(x) & np.isfinite(y)
        if not np.array_equal(np.isfinite(x), np.isfinite(y)) or \
                not np.array_equal(x[~finite], y[~finite], equal_nan=True):
            return "non-finite values differ"
        scale = max(1.0, float(np.max(np.abs(x[finite]), initial=0.0)))
        d = float(np.max(np.abs(x[finite] - y[finite]), initial=0.0))
        return None if d <= rtol * scale else f"differs by {d:.3g} (scale {scale:.3g})"
    if x.dtype.kind in "iub":
        return None if np.array_equal(x, y) else "integers differ"
    return None if np.array_equal(x.astype(str), y.astype(str)) else "text differs"


def differences(a, b, rtol: float = 1e-12, skip=()) -> list[str]:
    """Every dataset where two RunResults differ (empty when they give the same results)."""
    out = []
    skip = set(PROVENANCE) | set(skip)
    for k in sorted(set(a.model_datasets) | set(b.model_datasets)):
        if k in skip:
            continue
        if k not in a.model_datasets or k not in b.model_datasets:
            out.append(f"model {k}: only in one file")
            continue
        d = _differs(a.model_datasets[k], b.model_datasets[k], rtol)
        if d:
            out.append(f"model {k}: {d}")
    if len(a.analyses) != len(b.analyses):
        return out + [f"{len(a.analyses)} != {len(b.analyses)} analyses"]
    for i, (x, y) in enumerate(zip(a.analyses, b.analyses)):
        if (x.status, x.analysis_type, x.method) != (y.status, y.analysis_type, y.method):
            out.append(f"analysis {i}: {x.status} {x.method} != {y.status} {y.method}")
        for k in sorted(set(x.datasets) | set(y.datasets)):
            if k in skip:
                continue
            if k not in x.datasets or k not in y.datasets:
                out.append(f"analysis {i} {k}: only in one file")
                continue
            d = _differs(x.datasets[k], y.datasets[k], rtol)
            if d:
                out.append(f"analysis {i} {k}: {d}")
    if (a.units, a.active_effects) != (b.units, b.active_effects):
        out.append("units or active effects differ")
    return out
