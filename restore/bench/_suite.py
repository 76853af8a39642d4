"""Run every sampler of a configuration on every problem and seed, side by side, and write the results."""

from __future__ import annotations

import contextlib
import importlib.util
import math
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import jax
import jax.numpy as jnp

from ._config import SuiteConfig
from ._metrics import score
from ._problems import get_problem
from ._ratios import Ratio, recorded_ratios
from ._runner import Budget, RunOutput
from ._starting import starting_information
from ._timing import raw_rate


@dataclass
class SuiteResult:
    """Everything a suite run measured, and where its files went."""

    config: SuiteConfig
    rows: list[dict]
    raw_rates: dict[str, float]
    ratios: list[Ratio]
    machine: dict[str, str]
    seconds: float
    files: dict[str, Path] = field(default_factory=dict)
    interrupted: bool = False


def check_dependencies(config: SuiteConfig) -> None:
    """Raise a clear `ImportError` if emcee or BlackJAX is needed but missing."""
    needed = ["emcee"] if config.emcee_moves and config.walkers else []
    needed += ["blackjax"] if config.blackjax else []
    missing = [m for m in needed if importlib.util.find_spec(m) is None]
    if missing:
        raise ImportError(f"restore bench needs {' and '.join(missing)}: pip install 'restore-mcmc[compare]'")



class _Seeded(Protocol):
    """A configuration with a base seed (`SuiteConfig`, `EvidenceConfig`)."""

    @property
    def base_seed(self) -> int: ...

def _key(config: _Seeded, *parts) -> jax.Array:
    """A key per (problem, seed, sampler, budget): stable when samplers are added or removed."""
    key = jax.random.key(config.base_seed)
    for part in parts:
        key = jax.random.fold_in(key, zlib.crc32(str(part).encode()) & 0x7FFFFFFF)
    return key


def _row(problem, runner, seed: int, budget: Budget, out: RunOutput, metrics: dict, modes_found: int, asked: float) -> dict:
    run_time = out.run_time
    per = lambda a, b: a / b if b > 0 and math.isfinite(a) else math.nan  # noqa: E731
    return {
        "problem": problem.name, "sampler": runner.name, "family": runner.family, "kernel": getattr(runner, "kernel", "") or "",
        "seed": seed, "budget": budget.kind, "fraction": budget.fraction, "asked": asked,
        "evaluations": out.evaluations, "wall_time": out.wall_time, "run_time": run_time, "compile_time": out.compile_time,
        "evals_per_s": per(out.evaluations, run_time), **metrics, "ess": out.ess,
        "ess_per_s": per(out.ess, run_time), "ess_per_eval": per(out.ess, out.evaluations),
        "modes_found": modes_found, "notes": out.notes,
    }


def _num_runs(config: SuiteConfig) -> int:
    total = 0
    for name in config.problems:
        for r in config.runners(get_problem(name)):
            total += len(config.fractions) + (1 if r.time_budget and r.matches else 0)
    return total * config.seeds


@contextlib.contextmanager
def _progress(total: int, enabled: bool):
    if not enabled:
        yield lambda text: None, lambda: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description:<48}"), BarColumn(), MofNCompleteColumn(), TextColumn("runs"), TimeElapsedColumn()) as bar:
        task = bar.add_task("benchmark", total=total)
        yield (lambda text: bar.update(task, description=text)), (lambda: bar.advance(task))


def run_suite(config: SuiteConfig, out_dir: str | Path | None = None, *, progress: bool = True, log: Callable[[str], None] | None = None) -> SuiteResult:
    """Run `config` and (if `out_dir` is given) write `results.csv`, `results.md` and the plots there.

    `log`, if given, is called with one line per finished run (e.g. `print`, for logs
    where no progress bar can be drawn).

    Ctrl-C (KeyboardInterrupt) stops the suite; the runs finished so far are kept, written
    out, and the result says `interrupted=True`.

    Order within a problem and seed: jump Restore at each budget point first, then every
    other sampler at the evaluations jump Restore used (its matched kernel's run, same
    budget point), then at jump Restore's wall time (compilation excluded) for the full
    budget. All samplers share the seed's starting information.
    """
    from ._report import machine_description, write_results

    check_dependencies(config)
    started, machine = time.perf_counter(), machine_description()
    rows: list[dict] = []
    raw_rates: dict[str, float] = {}
    interrupted = False
    try:
        _run_all(config, rows, raw_rates, progress, log)
    except KeyboardInterrupt:
        interrupted = True  # keep and write what has been measured
    result = SuiteResult(config, rows, raw_rates, recorded_ratios(rows, raw_rates), machine, time.perf_counter() - started, interrupted=interrupted)
    if out_dir is not None and (rows or not interrupted):
        result.files = write_results(result, Path(out_dir))
    return result


def _run_all(config: SuiteConfig, rows: list[dict], raw_rates: dict[str, float], progress: bool, log) -> None:
    """Run every problem, seed, runner and budget of `config`, appending to `rows` and `raw_rates` as it goes."""
    with _progress(_num_runs(config), progress) as (describe, advance):
        for name in config.problems:
            problem = get_problem(name)
            describe(f"{name}: reference draws and raw throughput")
            ref = problem.reference(_key(config, name, "reference"), config.max_points)
            raw_rates[name] = raw_rate(problem.logdensity, jnp.asarray(ref.draws[: config.lanes]))
            runners = config.runners(problem)
            for seed in range(config.seeds):
                describe(f"{name} seed {seed}: finding modes")
                start = starting_information(problem, _key(config, name, seed, "starts"))
                used: dict[tuple[str, float], RunOutput] = {}
                for runner in runners:
                    budgets = []
                    for f in config.fractions:
                        ref_run = used.get((runner.matches, f)) if runner.matches else None
                        amount = ref_run.evaluations if ref_run is not None else f * config.full_evaluations
                        budgets.append(Budget.evaluations(amount, f))
                    if runner.time_budget and runner.matches is not None and (runner.matches, 1.0) in used:
                        budgets.append(Budget.seconds(used[(runner.matches, 1.0)].run_time, 1.0))
                    for budget in budgets:
                        describe(f"{name} seed {seed}: {runner.name} ({budget.kind} x{budget.fraction:g})")
                        out = runner.run(problem, start, _key(config, name, seed, runner.name, budget.kind, budget.fraction), budget)
                        if runner.family == "restore":
                            used[(runner.name, budget.fraction)] = out
                        metrics = score(out, ref, config.max_points, seed)
                        rows.append(_row(problem, runner, seed, budget, out, metrics, start.num_modes_found, budget.amount))
                        advance()
                        if log is not None:
                            log(
                                f"{name} seed {seed} {runner.name} {budget.kind} x{budget.fraction:g}: {out.evaluations:,} evaluations, "
                                f"{out.run_time:.2f} s (+{out.compile_time:.1f} s compile), mode RMSE {metrics['mode_rmse']:.3g}, "
                                f"mean error {metrics['mean_error']:.3g}, MMD {metrics['mmd']:.3g}"
                            )
