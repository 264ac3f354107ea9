"""The figure canvas shared by the report's figure modules: a matplotlib Agg figure without
pyplot, and the down-sampling of long series to at most MAX_POINTS points."""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

FIGSIZE = (10.0, 8.0)
DPI = 100
MAX_POINTS = 8000


def canvas(nrows: int, title: str):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=FIGSIZE, dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, 1, sharex=True, squeeze=False)[:, 0]
    # fixed margins: a constrained layout doubles the drawing time
    fig.subplots_adjust(left=0.09, right=0.98, top=0.94, bottom=0.07, hspace=0.12)
    fig.suptitle(title)
    return fig, axes


def save(fig: Any, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    return path


def stride(t: np.ndarray, *ys: np.ndarray):
    """Every k-th sample so that at most MAX_POINTS remain (for smooth estimates)."""
    k = max(1, -(-t.size // MAX_POINTS))
    return (t[::k],) + tuple(y[::k] for y in ys)


def maxpool(t: np.ndarray, y: np.ndarray):
    """The maximum of each bin so that at most MAX_POINTS remain (keeps the peaks of a
    statistic); NaN bins stay NaN."""
    k = -(-t.size // MAX_POINTS)
    if k <= 1:
        return t, y
    nb = -(-t.size // k)
    pad = nb * k - t.size
    yp = np.concatenate([y, np.full(pad, np.nan)]).reshape(nb, k)
    tp = np.concatenate([t, np.full(pad, t[-1])]).reshape(nb, k)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN bins stay NaN
        peak = np.nanmax(yp, axis=1)
    return tp[:, 0], peak
