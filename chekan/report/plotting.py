"""Figures without pyplot: the object API on an Agg canvas, so that drawing a file never
switches the process's matplotlib backend (inline plots in a notebook keep working)."""

from __future__ import annotations

from typing import Any


def new_figure(figsize: tuple[float, float], *, constrained: bool = False) -> Any:
    """A :class:`matplotlib.figure.Figure` attached to its own Agg canvas, outside pyplot:
    nothing to close, no global state; ``fig.subplots(...)`` and ``fig.savefig(...)`` work."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained" if constrained else None)
    FigureCanvasAgg(fig)
    return fig
