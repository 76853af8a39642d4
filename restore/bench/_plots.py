"""Plots (matplotlib, Agg): error against run time per problem, and the recorded ratios."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .._io import matplotlib_for, save_and_close
from ._metrics import pooled_rms

_STYLE = {"restore": ("C0", "o"), "mh": ("C3", "s"), "chains": ("C5", "v"), "emcee": ("C2", "^"), "blackjax": ("C4", "D"), "exact": ("0.4", "x")}


def _pyplot():
    matplotlib_for("the comparison's plots")
    import matplotlib.pyplot as plt

    return plt


def curve_points(rows: list[dict], problem: str, sampler: str, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """(median run time, pooled error) at each evaluation-budget point of one sampler."""
    mine = [r for r in rows if r["problem"] == problem and r["sampler"] == sampler and r["budget"] == "evaluations"]
    xs, ys = [], []
    for f in sorted({r["fraction"] for r in mine}):
        at = [r for r in mine if r["fraction"] == f]
        xs.append(float(np.median([r["run_time"] for r in at])))
        ys.append(pooled_rms(r[metric] for r in at))
    return np.asarray(xs), np.asarray(ys)


def plot_curves(rows: list[dict], problem: str, path: Path) -> Path | None:
    """Two panels, error and MMD against run time (log-log), one line per sampler.

    Lines join the evaluation-budget points; hollow markers are the equal-wall-time runs.
    The error is the mode-weight RMSE on multimodal problems, else the mean error.
    """
    mine = [r for r in rows if r["problem"] == problem]
    if not mine:
        return None
    metric = "mode_rmse" if any(math.isfinite(r["mode_rmse"]) for r in mine) else "mean_error"
    labels = {"mode_rmse": "mode-weight RMSE", "mean_error": "error of the mean (sd units)", "mmd": "MMD to exact draws"}
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10.5, 4.0), constrained_layout=True)
    samplers = list(dict.fromkeys(r["sampler"] for r in mine))
    for ax, m in zip(axes, (metric, "mmd")):
        for i, s in enumerate(samplers):
            family = next(r["family"] for r in mine if r["sampler"] == s)
            colour, marker = _STYLE.get(family, ("k", "."))
            x, y = curve_points(rows, problem, s, m)
            ok = np.isfinite(y) & (x > 0) & ((y > 0) | (m == "mmd"))
            if not ok.any():
                continue
            style = "-" if family == "restore" else ("--" if family == "exact" else ":")
            shade = 1.0 - 0.12 * sum(1 for t in samplers[:i] if next(r["family"] for r in mine if r["sampler"] == t) == family)
            ax.plot(x[ok], y[ok], style, marker=marker, color=colour, alpha=max(shade, 0.35), label=s)
            timed = [r for r in mine if r["sampler"] == s and r["budget"] == "time"]
            if timed:
                xt, yt = float(np.median([r["run_time"] for r in timed])), pooled_rms(r[m] for r in timed)
                if math.isfinite(yt) and (yt > 0 or m == "mmd") and xt > 0:
                    ax.plot([xt], [yt], marker=marker, mfc="none", color=colour, alpha=max(shade, 0.35), ls="none")
        ax.set_xscale("log")
        ax.set_yscale("log" if m != "mmd" else "linear")  # MMD can be 0: within noise of exact draws
        ax.set_xlabel("run time (s, compilation excluded)")
        ax.set_ylabel(labels[m])
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_title(f"{problem}: error against run time")
    axes[1].set_title("hollow markers: equal wall time to jump Restore")
    axes[0].legend(fontsize=7, loc="best")
    save_and_close(fig, path, dpi=90)
    return path


def plot_ratios(ratios, path: Path) -> Path | None:
    """Bar chart of the recorded ratios (log scale), goal bounds drawn on each bar."""
    if not ratios:
        return None
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10.5, 0.32 * len(ratios) + 1.2), constrained_layout=True)
    y = np.arange(len(ratios))[::-1]
    values = np.asarray([r.value if math.isfinite(r.value) and r.value > 0 else np.nan for r in ratios])
    colours = ["C2" if r.met else ("C3" if r.met is False else "0.6") for r in ratios]
    ax.barh(y, np.nan_to_num(values, nan=0.0), color=colours, log=True)
    for yi, r in zip(y, ratios):
        if r.goal:
            bound = float(r.goal.split()[1])
            ax.plot([bound, bound], [yi - 0.4, yi + 0.4], color="k", lw=1.5)
    ax.axvline(1.0, color="0.3", lw=0.8, ls=":")
    ax.set_yticks(y, [f"{r.name} [{r.problem}]" for r in ratios], fontsize=7)
    ax.set_xlabel("ratio (jump Restore / other); green: goal met, red: missed, black tick: goal")
    save_and_close(fig, path, dpi=90)
    return path
