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


def _compare(da: dict, db: dict, where: str, rtol: float, skip) -> list[str]:
    out = []
    for k in sorted(set(da) | set(db)):
        if k in skip:
            continue
        if k not in da or k not in db:
            out.append(f"{where} {k}: only in one file")
            continue
        d = _differs(da[k], db[k], rtol)
        if d:
            out.append(f"{where} {k}: {d}")
    return out


def differences(a, b, rtol: float = 1e-12, skip=()) -> list[str]:
    """Every dataset where two RunResults differ (empty when they give the same results)."""
    skip = set(PROVENANCE) | set(skip)
    out = _compare(a.model_datasets, b.model_datasets, "model", rtol, skip)
    if len(a.analyses) != len(b.analyses):
        return out + [f"{len(a.analyses)} != {len(b.analyses)} analyses"]
    for i, (x, y) in enumerate(zip(a.analyses, b.analyses)):
        if (x.status, x.analysis_type, x.method) != (y.status, y.analysis_type, y.method):
            out.append(f"analysis {i}: {x.status} {x.method} != {y.status} {y.method}")
        out += _compare(x.datasets, y.datasets, f"analysis {i}", rtol, skip)
    if (a.units, a.active_effects) != (b.units, b.active_effects):
        out.append("units or active effects differ")
    return out
