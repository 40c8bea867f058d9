"""Rendering through matplotlib: ``rgb_array`` on the Agg canvas, ``human`` through pyplot.

matplotlib is a required dependency and is imported with the env (about a quarter of a second, once per process).
Importing pyplot does not choose a GUI backend: matplotlib resolves its backend when the first pyplot figure is
made, which only ``human`` mode does.
"""

from __future__ import annotations

import os
import textwrap
import warnings
from collections.abc import Callable

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

#: the smallest title font (points) :func:`fit_title` shrinks to before it wraps onto another line
MIN_TITLE_POINTS = 8.0


def to_rgb_array(draw: Callable, size_inches: tuple[float, float] = (5.0, 5.0), dpi: int = 80) -> np.ndarray:
    """Draw onto a fresh Agg figure and return its pixels as an ``(H, W, 3)`` uint8 array."""
    fig = Figure(figsize=size_inches, dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    draw(ax)
    fit_title(ax)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def fit_title(ax) -> None:
    """Keep the axes' title inside the figure: shrink its font down to ``MIN_TITLE_POINTS``, then wrap it onto
    more lines, until it fits the figure's width (a long title was cut off at 400 × 400 pixels)."""
    title = ax.title
    text = title.get_text()
    if not text:
        return
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    # the room beside the axes: the figure's edges, or a neighbouring axes (a colour bar) where there is one
    mine = ax.get_window_extent(renderer)
    others = [other.get_window_extent(renderer) for other in fig.axes if other is not ax]
    left = max([0.0] + [box.x1 for box in others if box.x1 <= mine.x0])
    right = min([fig.bbox.width] + [box.x0 for box in others if box.x0 >= mine.x1])

    def fits() -> bool:
        box = title.get_window_extent(renderer)
        return box.x0 >= left and box.x1 <= right and box.y1 <= fig.bbox.height

    size = title.get_fontsize()
    while not fits() and size > MIN_TITLE_POINTS:
        size = max(size - 1.0, MIN_TITLE_POINTS)
        title.set_fontsize(size)
    columns = len(text)
    while not fits() and columns > 10:
        columns = int(columns * 0.8)
        title.set_text(textwrap.fill(text, columns))
    if title.get_window_extent(renderer).y1 > fig.bbox.height:  # more lines: make room above the axes
        fig.subplots_adjust(top=max(0.5, 1.0 - 1.25 * title.get_window_extent(renderer).height / fig.bbox.height))


#: links labelled at most per frame (the busiest, and none closer to another label than ``LABEL_SPACING`` of the
#: drawing's extent): more labels would cover the robots and each other
MAX_LINK_LABELS = 20
LABEL_SPACING = 0.12


def format_bits(bits: float) -> str:
    """``96 b``, ``1.5 kb``, ``2.3 Mb``: a link's label."""
    for scale, unit in ((1e6, "Mb"), (1e3, "kb")):
        if bits >= scale:
            return f"{bits / scale:.3g} {unit}"
    return f"{bits:.0f} b"


def draw_link_bits(ax, points: np.ndarray, pairs: np.ndarray, bits: np.ndarray) -> None:
    """Draw the links that carried bits this step, each labelled with how many crossed it (both directions).

    ``points``: (N, 2) positions; ``pairs``: (K, 2) robot indices; ``bits``: (K,) bits over each link this step.
    Links that carried nothing are left to the env's own drawing; the busiest ``MAX_LINK_LABELS`` are labelled."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    bits = np.asarray(bits, dtype=float).reshape(-1)
    used = bits > 0
    if not used.any():
        return
    pairs, bits = pairs[used], bits[used]
    ends = np.asarray(points, dtype=float)[pairs]  # (K, 2 ends, 2)
    ax.add_collection(LineCollection(list(ends), colors="tab:orange", linewidths=1.2, alpha=0.8, zorder=2.5))
    middles = ends.mean(axis=1)
    spacing = LABEL_SPACING * max(float(np.ptp(np.asarray(points, dtype=float), axis=0).max()), 1e-9)
    placed: list[np.ndarray] = []
    for k in np.argsort(-bits, kind="stable"):
        middle = middles[k]
        if len(placed) >= MAX_LINK_LABELS or any(np.hypot(*(middle - q)) < spacing for q in placed):
            continue
        placed.append(middle)
        ax.annotate(
            format_bits(bits[k]),
            middle,
            fontsize=6,
            color="tab:brown",
            ha="center",
            va="center",
            zorder=5,
            bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.7},
        )


def has_display() -> bool:
    """Whether ``human`` mode can open a window: an interactive matplotlib backend with a display to use."""
    backend = matplotlib.get_backend().lower()
    if backend in ("agg", "pdf", "ps", "svg", "cairo", "template") or backend.startswith("module://matplotlib_inline"):
        return backend.startswith("module://matplotlib_inline")  # a notebook shows figures itself
    if os.name == "posix" and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return backend.startswith("macos")
    return True


_warned_no_display = False


def warn_no_display() -> None:
    """Say once per process that ``human`` mode has nowhere to draw (no display, or a non-interactive backend)."""
    global _warned_no_display
    if not _warned_no_display:
        _warned_no_display = True
        warnings.warn(
            "render_mode='human' has no display to draw on (no $DISPLAY, or matplotlib's backend is "
            "non-interactive): nothing is shown; use render_mode='rgb_array', or `mrcomm record` for a GIF",
            RuntimeWarning,
            stacklevel=3,
        )


def show_human(draw: Callable, figure, fps: float):
    """Redraw the window of ``figure`` (created on first use) and let the GUI loop run."""
    if figure is None:
        figure = plt.figure(figsize=(5.0, 5.0))
    figure.clf()
    ax = figure.add_subplot(1, 1, 1)
    draw(ax)
    fit_title(ax)
    figure.canvas.draw_idle()
    plt.pause(1.0 / max(fps, 1.0))
    return figure


def close(figure) -> None:
    plt.close(figure)
