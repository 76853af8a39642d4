"""A matplotlib `Axes` to draw on: the caller's, or one of a new figure."""

from __future__ import annotations

from .._io import matplotlib_for


def axes_or_new(ax=None, figsize=(5.5, 3.8)):
    """`ax`, or the axes of a new figure (matplotlib is imported only here, when a plot is made)."""
    if ax is not None:
        return ax
    matplotlib_for("restore.plot", backend=None)
    import matplotlib.pyplot as plt

    return plt.subplots(figsize=figsize, layout="constrained")[1]
