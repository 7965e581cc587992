"""Per-frame element loads for the solvers (they live in :mod:`poise.elements.loads`)."""
from __future__ import annotations

from poise.elements.loads import element_loads, loads_of  # noqa: F401  (re-exported)
