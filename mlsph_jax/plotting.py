"""Figures for the library's plots through matplotlib's object API.

The library never switches the global backend (``matplotlib.use``) and never touches pyplot's
state: a figure is a :class:`matplotlib.figure.Figure` with its own Agg canvas, written to a file
and dropped.  So plots made by a run inside Jupyter do not stop the notebook's own inline plots.
"""

from __future__ import annotations

from pathlib import Path


def subplots(nrows: int = 1, ncols: int = 1, **kwargs):
    """``(figure, axes)`` like ``pyplot.subplots``, on a private Agg canvas (keyword arguments go to
    :class:`~matplotlib.figure.Figure` (figsize, dpi, layout) or to ``Figure.subplots``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig_keys = {"figsize", "dpi", "layout", "constrained_layout", "tight_layout"}
    fig = Figure(**{k: v for k, v in kwargs.items() if k in fig_keys})
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, **{k: v for k, v in kwargs.items() if k not in fig_keys})
    return fig, axes


def colormap(name: str):
    """A registered matplotlib colormap by name."""
    import matplotlib

    return matplotlib.colormaps[name]


def save(fig, path: str | Path, **kwargs) -> None:
    """Write ``fig`` to ``path`` (format from the suffix)."""
    fig.savefig(path, **kwargs)
