"""A matplotlib `Axes` to draw on: the caller's, or one of a new figure."""

from __future__ import annotations


def axes_or_new(ax=None, figsize=(5.5, 3.8)):
    """`ax`, or the axes of a new figure (matplotlib is imported only here, when a plot is made)."""
    if ax is not None:
        return ax
    try:
        import matplotlib.pyplot as plt
    except ImportError as err:  # pragma: no cover - matplotlib is an optional extra
        raise ImportError("restore.plot needs matplotlib: pip install 'restore-mcmc[plot]'") from err
    return plt.subplots(figsize=figsize, layout="constrained")[1]
