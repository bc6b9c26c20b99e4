"""Figures for every package: a Matplotlib figure on the Agg canvas, saved atomically.

Figures are built on :class:`matplotlib.figure.Figure` directly and rendered
by the Agg canvas, never through ``pyplot``: no global backend is selected
(importing this module leaves a user's interactive backend alone), no
figure registry leaks memory across a sweep, and it is safe from worker
threads.  Files are written atomically (:func:`nnsf.io.atomic_path`).
Stick-figure animations of key points are :mod:`nnsf.stick`.
"""
from __future__ import annotations

from pathlib import Path

from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from nnsf.io import atomic_path

DPI = 150


def new_figure(width, height):
    """A constrained-layout figure of ``width`` × ``height`` inches on its own Agg canvas."""
    fig = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path) -> Path:
    """Write ``fig`` to ``path`` atomically (format from the suffix, PNG by default)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, format=path.suffix.lstrip(".") or "png")
    return path


def categorical_colors(n):
    """``n`` distinct colours: tab10 up to 10, tab20 up to 20, then evenly spaced hues."""
    if n <= 10:
        return [colormaps["tab10"](i) for i in range(n)]
    if n <= 20:
        return [colormaps["tab20"](i) for i in range(n)]
    return [colormaps["hsv"](i / n) for i in range(n)]
