"""Writing the results: `results.csv` (one row per run), `results.md` (tables, ratios, machine) and plots."""

from __future__ import annotations

import datetime
import math
import os
import platform
from importlib import metadata
from pathlib import Path

import jax
import numpy as np

from .._io import write_csv, write_text
from ._metrics import pooled_rms
from ._problems import get_problem

COLUMNS = (
    "problem", "sampler", "family", "kernel", "seed", "budget", "fraction", "asked", "evaluations", "wall_time",
    "run_time", "compile_time", "evals_per_s", "mode_rmse", "mean_error", "second_moment_error", "mmd", "ess",
    "ess_per_s", "ess_per_eval", "modes_found", "notes",
)


def _cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "not installed"


def _affinity() -> str:
    try:
        cores = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return "unknown"
    return f"{len(cores)} ({', '.join(map(str, cores))})"


def machine_description() -> dict[str, str]:
    """CPU, cores, load, library versions and the date: what the timings depend on."""
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": _cpu_name(),
        "cores": str(os.cpu_count()),
        "cores this process may use": _affinity(),
        "load average at start (1, 5, 15 min)": ", ".join(f"{x:.2f}" for x in load),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": f"{jax.__version__} ({jax.default_backend()}, {jax.device_count()} device(s), float64={jax.config.read('jax_enable_x64')})",
        "numpy": np.__version__,
        "emcee": _version("emcee"),
        "blackjax": _version("blackjax"),
        "restore": _version("restore-mcmc"),
    }


def machine_table(machine: dict[str, str]) -> list[str]:
    """The `## Machine` section of a results page: one table row per entry of `machine_description`."""
    return ["", "## Machine", "", "| | |", "|---|---|", *(f"| {k} | {v} |" for k, v in machine.items())]


def _fmt(x, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, (int, np.integer)):
        return f"{x:,}"
    if abs(x) >= 1000:
        return f"{x:,.0f}"
    return f"{x:.{digits}g}"


def summary_rows(rows: list[dict]) -> list[dict]:
    """One line per (problem, sampler, budget kind) at the full budget, aggregated over seeds."""
    groups: dict[tuple, list[dict]] = {}
    compile_time: dict[tuple, float] = {}
    for r in rows:
        key = (r["problem"], r["sampler"])
        compile_time[key] = max(compile_time.get(key, 0.0), r["compile_time"])
        if r["fraction"] == 1.0:
            groups.setdefault((r["problem"], r["sampler"], r["budget"]), []).append(r)
    out = []
    for (problem, sampler, budget), rs in groups.items():
        med = lambda k: float(np.nanmedian([r[k] for r in rs])) if any(math.isfinite(r[k]) for r in rs) else math.nan  # noqa: B023, E731
        notes = sorted({n for r in rs for n in r["notes"].split("; ") if n})
        out.append({
            "problem": problem, "sampler": sampler, "budget": budget, "seeds": len(rs),
            "evaluations": int(np.mean([r["evaluations"] for r in rs])), "run_time": med("run_time"), "compile_time": compile_time[(problem, sampler)],
            "evals_per_s": med("evals_per_s"), "mode_rmse": pooled_rms(r["mode_rmse"] for r in rs),
            "mean_error": pooled_rms(r["mean_error"] for r in rs), "second_moment_error": pooled_rms(r["second_moment_error"] for r in rs),
            "mmd": pooled_rms(r["mmd"] for r in rs), "ess_per_s": med("ess_per_s"), "notes": "; ".join(notes),
        })
    return out


def markdown(result) -> str:
    """The results page: recorded ratios, per-problem tables, plots and the machine."""
    cfg = result.config
    lines = [
        f"# Restore comparison suite: `{cfg.name}` configuration",
        "",
        f"{cfg.seeds} seed(s); full budget {cfg.full_evaluations:,} target evaluations ({cfg.lanes} lanes x {cfg.steps} steps "
        f"of jump Restore with a random walk), curve points at {', '.join(f'{f:g}' for f in cfg.fractions)} of it; "
        f"MMD on at most {cfg.max_points} draws. Suite wall time {result.seconds / 60:.1f} min.",
        "",
    ]
    if getattr(result, "interrupted", False):
        lines += [f"**Interrupted**: partial results, {len(result.rows)} runs.", ""]
    lines += [
        "## Recorded ratios",
        "",
        "| ratio | problem | value | goal | met | detail |",
        "|---|---|---|---|---|---|",
    ]
    for r in result.ratios:
        met = {True: "yes", False: "**no**", None: ""}[r.met]
        lines.append(f"| {r.name} | {r.problem} | **{_fmt(r.value)}** | {r.goal} | {met} | {r.detail} |")
    lines += [
        "",
        "Errors are pooled over seeds as a root mean square; throughputs are medians over seeds, compilation excluded.",
        "",
        "## Results at the full budget",
        "",
        "`evaluations`: budget rows give every sampler the evaluations jump Restore (same kernel; random walk for "
        "emcee, BlackJAX and the chains) used; `time` rows give it jump Restore's run time. Mode RMSE: root-mean-square "
        "error of the mode weights. Mean / 2nd moment: root-mean-square over coordinates of the error in units of the "
        "marginal standard deviation (variance for second moments). MMD: to exact draws, Gaussian kernel, median-heuristic "
        "bandwidth; 0 means within the noise of exact draws. ESS/s: each sampler's own estimate (not comparable across "
        "samplers on multimodal targets). Compile: the largest compilation time of any of the sampler's runs on the problem "
        "(the one-off cost, paid by its first run).",
    ]
    summary = summary_rows(result.rows)
    for problem in cfg.problems:
        rows = [s for s in summary if s["problem"] == problem]
        if not rows:
            continue
        p = get_problem(problem)
        found = sorted({r["modes_found"] for r in result.rows if r["problem"] == problem})
        lines += [
            "",
            f"### {problem}: {p.title}",
            "",
            f"Modes found by the Laplace mixture from {p.num_starts} starts: {', '.join(map(str, found))}. "
            f"Raw `jit(vmap(logdensity))`: {_fmt(result.raw_rates.get(problem, math.nan))} evaluations/s.",
            "",
            "| sampler | budget | evaluations | run time (s) | compile (s) | evals/s | mode RMSE | mean err | 2nd moment err | MMD | ESS/s | notes |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for s in rows:
            lines.append(
                f"| {s['sampler']} | {s['budget']} | {_fmt(s['evaluations'])} | {_fmt(s['run_time'])} | {_fmt(s['compile_time'])} | "
                f"{_fmt(s['evals_per_s'])} | {_fmt(s['mode_rmse'])} | {_fmt(s['mean_error'])} | {_fmt(s['second_moment_error'])} | "
                f"{_fmt(s['mmd'])} | {_fmt(s['ess_per_s'])} | {s['notes']} |"
            )
        if f"curves-{problem}.png" in {f.name for f in result.files.values()}:
            lines += ["", f"![error against run time, {problem}](curves-{problem}.png)"]
    if "ratios" in result.files:
        lines += ["", "![recorded ratios](ratios.png)"]
    lines += machine_table(result.machine)
    return "\n".join(lines) + "\n"


def write_results(result, out: Path) -> dict[str, Path]:
    """Write `results.csv`, the plots and `results.md` into `out` (created if needed).

    Every file is written atomically (a temporary file, then a rename), so an interrupted
    write leaves the previous file, never a truncated one.
    """
    from ._plots import plot_curves, plot_ratios

    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {"csv": out / "results.csv"}
    write_csv(files["csv"], result.rows, COLUMNS)
    for problem in result.config.problems:
        path = plot_curves(result.rows, problem, out / f"curves-{problem}.png")
        if path is not None:
            files[f"curves-{problem}"] = path
    path = plot_ratios(result.ratios, out / "ratios.png")
    if path is not None:
        files["ratios"] = path
    result.files = files
    files["markdown"] = out / "results.md"
    write_text(files["markdown"], markdown(result))
    return files
