"""The columns of ChannelAssociation-v0's observation that change during an episode, written by the env
(``env.py``, whose module docstring lays the observation out) and by its copy-axis worlds (``copy_axis.py``)
with the same code: ``dyn`` is the dynamic part of the observation, ``(…, N, D)`` with any leading copy axes,
and every argument has the same leading shape as ``dyn`` without its last axis."""

from __future__ import annotations

import numpy as np

#: own past emissions in the observation (newest first)
HISTORY = 4


def push_emission(dyn: np.ndarray, emit: np.ndarray) -> None:
    """Shift each robot's emission history by one step and put this step's emission ``emit`` in front."""
    dyn[..., 2 : 1 + HISTORY] = dyn[..., 1:HISTORY]
    dyn[..., 1] = emit


def write_istate(dyn, frac, nv, ne, unres, new, squash8: np.ndarray, squash4: np.ndarray) -> None:
    """Each robot's own i-state: fraction matched, ambiguity (edges − v)/edges, unresolved u/(u+8) and new IDs
    n/(n+4) (the last two read from the tables ``squash8``, ``squash4``)."""
    j = 1 + HISTORY
    dyn[..., j] = frac
    dyn[..., j + 1] = (np.maximum(ne, nv) - nv) / np.maximum(ne, 1)  # unsigned-safe (ne − nv)⁺ / ne
    dyn[..., j + 2] = squash8[unres]  # u / (u + 8), tabulated
    dyn[..., j + 3] = squash4[new]  # n / (n + 4), tabulated
