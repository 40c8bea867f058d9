"""Summary statistics shared by evaluation and reproduction."""

from __future__ import annotations

import math

import numpy as np
from scipy import special


def mean_ci95(values) -> tuple[float, float]:
    """Mean and half-width of the 95 % Student-t confidence interval (0 for fewer than 2 values)."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan
    mean = float(x.mean())
    if x.size < 2:
        return mean, 0.0
    # Student's t quantile straight from scipy.special (what ``scipy.stats.t.ppf`` calls, the same bits): every
    # process that steps an env has scipy.special loaded already, while scipy.stats would add about 0.3 s to each
    half = float(special.stdtrit(x.size - 1, 0.975) * x.std(ddof=1) / math.sqrt(x.size))
    return mean, half
