"""Summary statistics shared by evaluation and reproduction."""

from __future__ import annotations

import math

import numpy as np


def mean_ci95(values) -> tuple[float, float]:
    """Mean and half-width of the 95 % Student-t confidence interval (0 for fewer than 2 values)."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan
    mean = float(x.mean())
    if x.size < 2:
        return mean, 0.0
    # imported here: scipy.stats takes about a second to import, which every fresh sweep worker would pay
    # (baselines import this module) although only the summaries use it
    from scipy import stats

    half = float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return mean, half


#: bootstrap resamples and their seed: the interval is a function of the values alone, so a rerun gives the same
#: page (rliable uses 50,000 resamples for its figures; 10,000 moves these intervals by well under 1 %)
BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0


def iqm_ci95(values) -> tuple[float, float, float]:
    """Interquartile mean and its 95 % percentile-bootstrap interval over runs, as rliable defines them
    (Agarwal et al., "Deep RL at the edge of the statistical precipice", NeurIPS 2021): the IQM is the 25 %
    trimmed mean (``rliable.metrics.aggregate_iqm`` is ``scipy.stats.trim_mean(scores, 0.25)``) and, with one
    task, rliable's stratified bootstrap resamples the runs of that task, which is scipy's percentile bootstrap.
    Returns (iqm, low, high); with fewer than 2 finite values the interval is the point itself."""
    from scipy import stats  # see mean_ci95

    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan, math.nan
    iqm = float(stats.trim_mean(x, 0.25))
    if x.size < 2 or np.all(x == x[0]):
        return iqm, iqm, iqm
    result = stats.bootstrap(
        (x,),
        lambda sample, axis=-1: stats.trim_mean(sample, 0.25, axis=axis),
        n_resamples=BOOTSTRAP_RESAMPLES,
        method="percentile",
        confidence_level=0.95,
        random_state=np.random.default_rng(BOOTSTRAP_SEED),
    )
    return iqm, float(result.confidence_interval.low), float(result.confidence_interval.high)
