"""The paper's equations in code (Julian, Schwager, Angermann & Rus, paper 003).

* §2.1: a slot of ``m`` estimates of ``b`` bits lasts ``m b / r_b`` seconds; the maximum frame rate is
  ``r_f = r_b / (m n b)`` (TDMA overhead ignored, footnote 3).
* eq. (1): importance ``f_ij = d(p_i, p̂_j)^-α``.
* eq. (2): ``P^ij = f_ij / Σ_{k∈M_i} f_ik`` over the selectable set ``M_i``.
* §4: coverage cost of a Voronoi coverage controller (Cortés et al.), ``H = Σ_i ∫_{V_i} ||q - p_i||² φ(q) dq``
  with uniform ``φ``; we report it divided by the area, i.e. the mean squared distance to the nearest robot.
"""

from __future__ import annotations

import numpy as np


def slot_duration(m: int, bits: float, baud: float) -> float:
    """Seconds one TDMA slot of ``m`` estimates lasts (§2.1)."""
    return m * bits / baud


def frame_rate(m: int, n: int, bits: float, baud: float) -> float:
    """Maximum frame rate ``r_f = r_b / (m n b)`` in Hz (§2.1)."""
    return baud / (m * n * bits)


def importance(dist, alpha: float):
    """Eq. (1) ``d^-α`` (``inf`` at ``d = 0``, the robot's own estimate)."""
    with np.errstate(divide="ignore"):
        return np.asarray(dist, dtype=np.float64) ** (-alpha)


def eq2_probabilities(f, selectable) -> np.ndarray:
    """Eq. (2) over the selectable set (0 outside it)."""
    f = np.where(selectable, np.asarray(f, dtype=np.float64), 0.0)
    return f / f.sum()


def coverage_cost(positions: np.ndarray, points: np.ndarray) -> float:
    """Mean over ``points`` (uniform samples of the square) of the squared distance to the nearest robot,
    which is ``H / area`` for the Voronoi partition of ``positions`` (uniform density)."""
    d2 = ((points[:, None, :] - positions[None, :, :]) ** 2).sum(-1)
    return float(d2.min(axis=1).mean())


def paper_frame_rates() -> dict[int, float]:
    """§4: nine robots, 192-bit estimates, 3000 baud: 1.7 Hz (m=1), 0.6 Hz (m=3), 0.2 Hz (m=9)."""
    return {1: 1.7, 3: 0.6, 9: 0.2}
