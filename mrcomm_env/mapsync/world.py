"""The grid world of §III and §V-C: a 4-connected grid with obstacles, random-walking robots, local sensing.

Cells are numbered row-major, ``cell = y · size + x``, with ``(x, y)`` the coordinates the paper lists (Fig. 7
fits 0 … 15). A robot moves each step to a uniformly chosen free 4-neighbour (it stays if it has none) and,
on entering a cell, senses that cell and its 4-neighbours (§V-C: "the robots can detect any neighboring
obstacle when they step into a new cell"). Obstacles may appear on free, unoccupied cells and disappear,
each cell independently per step (§I: "new obstacles are appearing and disappearing frequently").
"""

from __future__ import annotations

import numpy as np

#: Fig. 7: the ten obstacles and the two starts, as (x, y)
PAPER_OBSTACLES = ((12, 15), (6, 13), (6, 9), (3, 15), (12, 3), (12, 13), (5, 5), (13, 7), (14, 1), (6, 5))
PAPER_STARTS = ((11, 7), (3, 7))  # Alice, Bob
PAPER_GRID = 16
PAPER_STEPS = 200
PAPER_K = 10
PAPER_PERIOD = 10  # "after making every ten moves, the robots communicate"

_MOVES = ((0, -1), (1, 0), (0, 1), (-1, 0))


def cell_of(x: int, y: int, size: int) -> int:
    return y * size + x


def neighbour_table(size: int) -> np.ndarray:
    """(n, 4) 4-neighbours of every cell, −1 outside the grid."""
    ys, xs = np.divmod(np.arange(size * size), size)
    table = np.full((size * size, 4), -1, dtype=np.int64)
    for k, (dx, dy) in enumerate(_MOVES):
        nx, ny = xs + dx, ys + dy
        inside = (nx >= 0) & (nx < size) & (ny >= 0) & (ny < size)
        table[inside, k] = ny[inside] * size + nx[inside]
    return table


def sensing_table(neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, 5) cells sensed from each cell (itself and its 4-neighbours; outside the grid: itself again) and
    (n, 5) which of them are distinct (to count each sensed cell once)."""
    n = neighbours.shape[0]
    own = np.arange(n)[:, None]
    cells = np.concatenate([own, neighbours], axis=1)
    distinct = cells >= 0
    return np.where(distinct, cells, own), distinct
