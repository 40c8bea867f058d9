"""Random inputs the RendezvousMapping tests share: information matrices and map packets."""

from __future__ import annotations

import numpy as np

from mrcomm_env.rendezvous import filters


def random_spd(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """A random symmetric positive-definite 2 × 2 matrix (eigenvalues at least ``0.2 · scale``)."""
    a = rng.normal(size=(2, 2))
    return scale * (a @ a.T + 0.2 * np.eye(2))


def make_packet(rng: np.random.Generator, n_landmarks: int) -> filters.Packet:
    """A packet of 1–3 distinct landmarks (sorted ids) with random information vectors and 1–3 observations each."""
    m = int(rng.integers(1, 4))
    ids = np.sort(rng.choice(n_landmarks, size=m, replace=False))
    return filters.Packet(ids, rng.normal(size=(m, 2)), rng.integers(1, 4, size=m))
