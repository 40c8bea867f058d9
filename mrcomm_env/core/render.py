"""Rendering through matplotlib: ``rgb_array`` on the Agg canvas, ``human`` through pyplot."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def to_rgb_array(draw: Callable, size_inches: tuple[float, float] = (5.0, 5.0), dpi: int = 80) -> np.ndarray:
    """Draw onto a fresh Agg figure and return its pixels as an ``(H, W, 3)`` uint8 array."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size_inches, dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    draw(fig.add_subplot(1, 1, 1))
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def show_human(draw: Callable, figure, fps: float):
    """Redraw the window of ``figure`` (created on first use) and let the GUI loop run."""
    import matplotlib.pyplot as plt

    if figure is None:
        figure = plt.figure(figsize=(5.0, 5.0))
    figure.clf()
    draw(figure.add_subplot(1, 1, 1))
    figure.canvas.draw_idle()
    plt.pause(1.0 / max(fps, 1.0))
    return figure


def close(figure) -> None:
    import matplotlib.pyplot as plt

    plt.close(figure)
