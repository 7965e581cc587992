"""Per-frame outputs: body poses, reactions of constraints, element forces."""
from __future__ import annotations

import numpy as np

from poise.elements.loads import element_loads, loads_of  # noqa: F401  (re-exported)


