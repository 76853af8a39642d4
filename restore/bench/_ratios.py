"""The recorded ratios: jump Restore against emcee, the MH baseline and the raw target, with their goals."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ._metrics import pooled_rms


class Ratio(NamedTuple):
    """One recorded ratio; `problem` is `"geometric mean"` for the summary over problems."""

    name: str
    problem: str
    value: float
    goal: str  # e.g. "<= 0.1", or "" when there is none
    detail: str

    @property
    def met(self) -> bool | None:
        if not self.goal or not math.isfinite(self.value):
            return None
        op, bound = self.goal.split()
        return self.value <= float(bound) if op == "<=" else self.value >= float(bound)


ERROR_VS_EMCEE = "error / best emcee, equal wall time"
ERROR_VS_MH = "error / MH ({kernel}), equal evaluations"
THROUGHPUT_VS_EMCEE = "evaluations per second / fastest emcee"
THROUGHPUT_VS_RAW = "evaluations per second / raw jit(vmap(logdensity))"
GOALS = {ERROR_VS_EMCEE: "<= 0.1", ERROR_VS_MH: "<= 0.8", THROUGHPUT_VS_EMCEE: "", THROUGHPUT_VS_RAW: ">= 0.5"}


def _select(rows, problem, sampler=None, family=None, budget=None, fraction=1.0):
    return [
        r for r in rows
        if r["problem"] == problem and (sampler is None or r["sampler"] == sampler) and (family is None or r["family"] == family)
        and (budget is None or r["budget"] == budget) and r["fraction"] == fraction
    ]


def _error_key(rows, problem) -> str:
    multimodal = any(math.isfinite(r["mode_rmse"]) for r in _select(rows, problem, "restore-rw"))
    return "mode_rmse" if multimodal else "mean_error"


def recorded_ratios(rows: list[dict], raw_rates: dict[str, float]) -> list[Ratio]:
    """Per-problem ratios, then their geometric means.

    Errors (mode-weight RMSE on multimodal problems) are pooled over seeds as a root
    mean square before dividing; the emcee denominator is the emcee configuration (moves
    and walkers) with the smallest pooled error at equal wall time, the most favourable
    choice for emcee. Throughputs are medians over seeds of the full-budget runs
    (compilation excluded); against emcee the fastest emcee configuration is used.
    """
    out: list[Ratio] = []
    problems = list(dict.fromkeys(r["problem"] for r in rows))
    for p in problems:
        ours = _select(rows, p, "restore-rw", budget="evaluations")
        if not ours:
            continue
        multimodal = _error_key(rows, p) == "mode_rmse"
        if multimodal:
            err = pooled_rms(r["mode_rmse"] for r in ours)
            emcee: dict[str, list[float]] = {}
            for r in _select(rows, p, family="emcee", budget="time"):
                emcee.setdefault(r["sampler"], []).append(r["mode_rmse"])
            if emcee:
                best = min(emcee, key=lambda s: pooled_rms(emcee[s]))
                out.append(Ratio(ERROR_VS_EMCEE, p, err / pooled_rms(emcee[best]), GOALS[ERROR_VS_EMCEE], f"mode-weight RMSE {err:.3g} vs {pooled_rms(emcee[best]):.3g} ({best})"))
            for kernel in ("rw", "mala", "hmc"):
                mine = _select(rows, p, f"restore-{kernel}", budget="evaluations")
                base = _select(rows, p, f"mh-{kernel}", budget="evaluations")
                if mine and base:
                    a, b = pooled_rms(r["mode_rmse"] for r in mine), pooled_rms(r["mode_rmse"] for r in base)
                    name = ERROR_VS_MH.format(kernel=kernel)
                    out.append(Ratio(name, p, a / b, GOALS[ERROR_VS_MH], f"mode-weight RMSE {a:.3g} vs {b:.3g}"))
        rate = float(np.median([r["evals_per_s"] for r in ours]))
        emcee_rates: dict[str, list[float]] = {}
        for r in _select(rows, p, family="emcee"):
            emcee_rates.setdefault(r["sampler"], []).append(r["evals_per_s"])
        if emcee_rates:
            fastest = max(emcee_rates, key=lambda s: np.median(emcee_rates[s]))
            theirs = float(np.median(emcee_rates[fastest]))
            out.append(Ratio(THROUGHPUT_VS_EMCEE, p, rate / theirs, "", f"{rate:,.0f}/s vs {theirs:,.0f}/s ({fastest})"))
        if p in raw_rates:
            out.append(Ratio(THROUGHPUT_VS_RAW, p, rate / raw_rates[p], GOALS[THROUGHPUT_VS_RAW], f"{rate:,.0f}/s vs {raw_rates[p]:,.0f}/s"))
    for name in list(dict.fromkeys(r.name for r in out)):
        group = [r for r in out if r.name == name and r.problem != "geometric mean"]
        values = [r.value for r in group if math.isfinite(r.value) and r.value > 0]
        if len(values) > 1:
            goal = group[0].goal
            worst = max(values) if goal.startswith("<=") else min(values)
            gm = float(np.exp(np.mean(np.log(values))))
            out.append(Ratio(name, "geometric mean", gm, goal, f"over {len(values)} problems; worst {worst:.3g}"))
    return out
