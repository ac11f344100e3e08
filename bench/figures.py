"""Figures the benches report, computed one way: a percentile is a measured value, not a blend."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def percentile(values: Sequence[float], q: float) -> float | None:
    """The measured value at or above quantile `q` (0..1) of `values`; None when there are none
    or it is infinite (never happened)."""
    if not values:
        return None
    value = float(np.percentile(np.asarray(values, dtype=float), 100 * q, method="higher"))
    return None if math.isinf(value) else value
