"""Closed forms of the sensor model: the finite information available per landmark (the sensor floor).

Observations are isotropic, z = x_l + v with v ~ N(0, σ_obs² I), made at ``obs_rate`` per second while a
vehicle is at a landmark. A landmark has finitely many resolvable features, so it yields at most
``budget`` independent observations in the whole mission, by any vehicle; further observations repeat
earlier ones and add nothing (the sensor floor: no landmark can be known better than
σ² = 1/(1/σ₀² + budget/σ_obs²)). This is what makes "50 % of the information available" (§VI-B) a
number, and it is why "once the observational information has been exhausted" vehicles loiter (§VI-B.2).
"""

from __future__ import annotations

import math


def information_per_observation(obs_sigma: float) -> float:
    """R⁻¹ = I / σ_obs²: the information (per axis) one observation adds."""
    return 1.0 / (obs_sigma * obs_sigma)


def prior_information(prior_sigma: float) -> float:
    """Y₀ = I / σ₀²: the common prior map's information per axis (§III: a common initial map)."""
    return 1.0 / (prior_sigma * prior_sigma)


def available_information(prior_sigma: float, obs_sigma: float, budget: int) -> float:
    """ln det Y_floor − ln det Y₀ (nats) of one landmark: all it can yield, 2 ln(1 + budget σ₀²/σ_obs²)."""
    return 2.0 * math.log1p(budget * prior_sigma**2 / obs_sigma**2)


def max_utility(prior_sigma: float, obs_sigma: float, budget: int) -> float:
    """The largest eq. (1) utility: ½ of :func:`available_information` (a fresh landmark observed to the floor)."""
    return 0.5 * available_information(prior_sigma, obs_sigma, budget)
