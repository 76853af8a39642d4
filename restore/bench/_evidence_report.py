"""Writing the evidence benchmark's results: `evidence.csv` (one row per run) and `evidence.md` (tables per problem)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .._io import write_csv, write_text
from ._evidence_problems import get_evidence_problem
from ._report import _fmt, machine_table

COLUMNS = (
    "problem", "method", "family", "seed", "status", "log_z", "log_z_true", "log_z_error", "abs_log_z_error", "log_z_se",
    "log_z_z", "k_hat", "reliable", "mean_error", "second_moment_error", "max_z_mean", "max_z_second", "positive",
    "positive_true", "positive_error", "positive_z", "evaluations", "wall_time", "run_time", "compile_time", "notes",
)


def _finite(rows: list[dict], key: str) -> list[float]:
    return [float(r[key]) for r in rows if isinstance(r[key], (int, float)) and math.isfinite(r[key])]


def _median(rows: list[dict], key: str) -> float:
    values = _finite(rows, key)
    return float(np.median(values)) if values else math.nan


def _largest(rows: list[dict], key: str) -> float:
    values = _finite(rows, key)
    return max(values, key=abs) if values else math.nan


def summary_rows(rows: list[dict]) -> list[dict]:
    """One line per (problem, method), over seeds, in the order the runs were made."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["problem"], r["method"]), []).append(r)
    out = []
    for (problem, method), rs in groups.items():
        done = [r for r in rs if r["status"] in ("ok", "capped")]
        errors = _finite(done, "log_z_error")
        statuses = {s: sum(r["status"] == s for r in rs) for s in ("ok", "capped", "failed", "skipped")}
        notes = list(dict.fromkeys(n for r in rs for n in r["notes"].split("; ") if n))
        out.append({
            "problem": problem, "method": method, "runs": ", ".join(f"{n} {s}" for s, n in statuses.items() if n),
            "errors": ", ".join(f"{e:+#.3g}" for e in errors) if errors else "-",
            "rms_error": float(np.sqrt(np.mean(np.square(errors)))) if errors else math.nan,
            "log_z_se": _median(done, "log_z_se"), "log_z_z": _largest(done, "log_z_z"), "k_hat": _largest(done, "k_hat"),
            "reliable": ", ".join(sorted({r["reliable"] for r in done if r["reliable"]})) or "-",
            "max_z": max(_finite(done, "max_z_mean") + _finite(done, "max_z_second"), default=math.nan),
            "mean_error": _median(done, "mean_error"), "second_moment_error": _median(done, "second_moment_error"),
            "positive": _median(done, "positive"), "positive_z": _largest(done, "positive_z"),
            "evaluations": _median(done, "evaluations"), "run_time": _median(rs, "run_time"),
            "compile_time": max(_finite(rs, "compile_time"), default=math.nan), "notes": "; ".join(notes),
        })
    return out


def _settings(cfg) -> list[str]:
    """One line per method of the configuration."""
    lines = [
        f"- **restore-laplace**: the hand-built recipe. `laplace_mixture(..., tails=\"student_t\", df=5)` from {cfg.restore_starts} "
        f"starts uniform in the box, `RandomWalk(2.38 / sqrt(d))`, `tour_length=10`, {cfg.restore_lanes} lanes x "
        f"{cfg.restore_steps} steps; log Z from the tours. Evaluations include the mode finding, the pilot and the steps "
        "that finish open tours.",
        f"- **restore-autosample**: `restore.autosample(logdensity, key, box=box, num_lanes={cfg.restore_lanes}, "
        f"num_steps={cfg.restore_steps})`; evaluations as it reports them (all stages).",
        f"- **smc-hmc**: BlackJAX adaptive tempered SMC from the uniform prior on the box, {cfg.smc_particles} particles, "
        f"target ESS 0.5, {cfg.smc_mcmc_steps} HMC moves per temperature (diagonal inverse mass matrix from the particles' "
        "variances, step size adapted to acceptance 0.65); log Z is the sum of the log likelihood increments. No standard "
        "error from one run.",
        "- **smc-hmc-dense**: the same with the particles' full covariance as the inverse mass matrix (for correlated targets).",
        f"- **dynesty**: `NestedSampler(nlive={cfg.nested_live}, bound=\"multi\", sample=\"auto\")`, uniform prior on the "
        f"box, default `dlogz`, stopped after {cfg.nested_seconds:g} s of sampling at the latest (`capped`); "
        "log Z = logz + log(box volume), standard error `logzerr`.",
        f"- **nuts**: BlackJAX NUTS, `window_adaptation` with a dense mass matrix, {cfg.nuts_chains} chains from starts "
        f"uniform in the box, {cfg.nuts_warmup} warm-up and {cfg.nuts_kept} kept steps each; moments only (no log Z), "
        "standard errors ArviZ's Monte Carlo standard errors, `reliable` when every R-hat < 1.01 and every bulk ESS > 400 "
        "(Stan's rule). Evaluations: gradients of all steps.",
    ]
    names = [r.name for r in cfg.runners()]
    return [line for line in lines if any(line.startswith(f"- **{name}**") for name in names)]


def _box_text(lower: np.ndarray, upper: np.ndarray) -> str:
    """The box as runs of equal bounds: `[-5, 5]^32`, or `[-15, 15] (x0), [-300, 300]^9 (x1..x9)`."""
    runs: list[list] = []  # [lower, upper, first coordinate, count]
    for i, (a, b) in enumerate(zip(lower.tolist(), upper.tolist(), strict=True)):
        if runs and runs[-1][:2] == [a, b]:
            runs[-1][3] += 1
        else:
            runs.append([a, b, i, 1])
    if len(runs) == 1:
        return f"[{runs[0][0]:g}, {runs[0][1]:g}]^{runs[0][3]}"
    text = lambda a, b, i, n: f"[{a:g}, {b:g}] (x{i})" if n == 1 else f"[{a:g}, {b:g}]^{n} (x{i}..x{i + n - 1})"  # noqa: E731
    return ", ".join(text(*run) for run in runs)


def markdown(result) -> str:
    """The results page: settings, one table per problem, the machine."""
    cfg = result.config
    lines = [
        f"# Evidence benchmark: `{cfg.name}` configuration",
        "",
        f"{cfg.seeds} seed(s) per method and problem. Suite wall time {result.seconds / 60:.1f} min. "
        "Every method gets the same knowledge of the problem: its log density and a box that holds the mass.",
        "",
    ]
    if result.interrupted:
        lines += [f"**Interrupted**: partial results, {len(result.rows)} runs.", ""]
    lines += ["## Methods", "", *_settings(cfg), "", "## Results", ""]
    lines += [
        "`log Z error`: estimate minus truth, per seed (nats). `SE`: the median standard error the method reported. "
        "`|z|`: the largest |error / SE| over seeds (signed). `k_hat`, `reliable`: the method's own tail diagnostic and verdict, "
        "where it reports them. `max |z| moments`: the largest |z| of the means and second moments of all coordinates, "
        "where the method reports standard errors (up to about 3 is expected from 2d z-scores). `mean err`, `2nd err`: "
        "RMS over coordinates in marginal standard deviations (variances). `P(x1 > 0)`: the median over seeds of the "
        "estimated share of double-well coordinates in the right well, with the largest z-score where the method reports "
        "a standard error. Evaluations, run time (compilation excluded; for a failed run, the time until it failed): "
        "medians over seeds; compile: the largest.",
    ]
    summary = summary_rows(result.rows)
    for name in cfg.problems:
        rows = [s for s in summary if s["problem"] == name]
        if not rows:
            continue
        problem = get_evidence_problem(name)
        ref = result.references.get(name)
        box = _box_text(*problem.box)
        lines += [
            "",
            f"### {name}: {problem.title}",
            "",
            f"Exact log Z = **{problem.log_normalising_constant:.6f}**. Box {box}"
            + (f"; {round(ref.outside_share * cfg.reference_draws):,} of {cfg.reference_draws:,} exact draws fall outside it." if ref is not None else "."),
        ]
        wells = problem.has_wells
        head = "| method | runs | log Z error | RMS error | SE | \\|z\\| | k_hat | reliable | max \\|z\\| moments | mean err | 2nd err |"
        if wells:
            head += f" P(x1 > 0) (truth {ref.positive_probability:.4f}) |" if ref is not None else " P(x1 > 0) |"
        head += " evaluations | run time (s) | compile (s) | notes |"
        lines += ["", head, "|" + "---|" * (head.replace("\\|", "").count("|") - 1)]
        for s in rows:
            cells = [
                s["method"], s["runs"], s["errors"], _fmt(s["rms_error"]), _fmt(s["log_z_se"]), _fmt(s["log_z_z"]), _fmt(s["k_hat"]),
                s["reliable"], _fmt(s["max_z"]), _fmt(s["mean_error"]), _fmt(s["second_moment_error"]),
            ]
            if wells:
                z = f" (z {_fmt(s['positive_z'])})" if math.isfinite(s["positive_z"]) else ""
                cells.append(_fmt(s["positive"], 4) + z)
            cells += [_fmt(s["evaluations"]), _fmt(s["run_time"]), _fmt(s["compile_time"]), s["notes"].replace("|", "/")]
            lines.append("| " + " | ".join(cells) + " |")
    lines += machine_table(result.machine)
    return "\n".join(lines) + "\n"


def write_evidence(result, out: Path) -> dict[str, Path]:
    """Write `evidence.csv` and `evidence.md` into `out` (created if needed), each atomically."""
    out.mkdir(parents=True, exist_ok=True)
    files = {"csv": out / "evidence.csv", "markdown": out / "evidence.md"}
    write_csv(files["csv"], result.rows, COLUMNS)
    result.files = files
    write_text(files["markdown"], markdown(result))
    return files
