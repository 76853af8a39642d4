"""The `restore` command line."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

app = typer.Typer(help="Restore samplers in JAX: jump Restore, baselines and checks.", no_args_is_help=True, add_completion=False)
console = Console()


@app.callback()
def main() -> None:
    """Restore samplers in JAX."""


@app.command()
def demo(
    dim: int = typer.Option(10, min=1, help="Dimension of the Gaussian mixture."),
    lanes: int = typer.Option(512, min=2, help="Parallel lanes of each sampler."),
    steps: int = typer.Option(1500, min=10, help="Steps per lane (one density evaluation each)."),
    tour_length: float = typer.Option(10.0, min=1e-6, help="Mean tour duration T = 1/c; MH large-step probability is 1/T."),
    seed: int = typer.Option(0, help="Random seed."),
    out: Path = typer.Option(Path("restore-demo.png"), help="Where to write the plot."),
    progress: bool = typer.Option(True, help="Show progress bars."),
) -> None:
    """Jump Restore vs the MH mixture baseline on a multimodal target, at equal evaluations."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from ._demo import plot_demo, run_demo

    console.print(f"[bold]Target:[/] {dim}-d mixture of 3 well-separated Gaussians, weights 1/6, 2/6, 3/6")
    outcome = run_demo(dim=dim, num_lanes=lanes, num_steps=steps, tour_length=tour_length, seed=seed, progress=progress)
    console.print(f"Regeneration: Student-t Laplace mixture with equal weights at {outcome.num_modes_found} modes found by optimistix")

    table = Table(title=f"Mode weights, {outcome.evaluations:,} density evaluations per sampler")
    table.add_column("mode")
    table.add_column("truth", justify="right")
    table.add_column("jump Restore", justify="right")
    table.add_column("MH mixture", justify="right")
    for i, truth in enumerate(outcome.truth):
        table.add_row(
            str(i),
            f"{truth:.4f}",
            f"{outcome.restore.value[i]:.4f} ± {outcome.restore.standard_error[i]:.4f}",
            f"{outcome.mh.value[i]:.4f} ± {outcome.mh.standard_error[i]:.4f}",
        )
    rmse = lambda est: float(((est.value - outcome.truth) ** 2).mean() ** 0.5)  # noqa: E731
    table.add_row("RMSE", "", f"{rmse(outcome.restore):.4f}", f"{rmse(outcome.mh):.4f}", end_section=True)
    table.add_row("wall time (with compilation)", "", f"{outcome.restore_seconds:.1f} s", f"{outcome.mh_seconds:.1f} s")
    console.print(table)
    stats = outcome.restore_result.tour_statistics()
    console.print(
        f"jump Restore: {stats.num_tours:,} tours, mean duration {stats.mean_duration:.2f} ± {stats.mean_duration_se:.2f} "
        f"(1/c = {stats.expected_duration:.2f}); log Z = {float(outcome.log_z.value):.4f} ± {float(outcome.log_z.standard_error):.4f} (truth 0)"
    )
    console.print("± is one standard error (Restore: regenerative, over tours; MH: over independent lanes).")
    console.print(f"Plot written to {plot_demo(outcome, out)}")


def _names(text: str | None) -> tuple[str, ...] | None:
    return None if text is None else tuple(part.strip() for part in text.split(",") if part.strip())


@app.command()
def bench(
    quick: bool = typer.Option(False, "--quick", help="Small subset (2-d and 10-d mixtures; jump Restore RW, MH RW, emcee stretch): a few minutes."),
    medium: bool = typer.Option(False, "--medium", help="Every problem and sampler of the full mode with the quick budgets and 2 seeds."),
    out: Path = typer.Option(Path("bench-results"), help="Folder for results.csv, results.md and the plots."),
    seeds: int | None = typer.Option(None, min=1, help="Number of seeds (default: 2 quick, 3 full)."),
    problems: str | None = typer.Option(None, help="Comma-separated problems to run (default: all of the mode)."),
    samplers: str | None = typer.Option(None, help="Comma-separated sampler-name prefixes to keep, e.g. 'restore-rw,mh-rw,emcee'."),
    progress: bool = typer.Option(True, help="Show a progress bar over the runs (without it: one line per run)."),
) -> None:
    """Jump Restore against the MH baseline, emcee and BlackJAX, at equal evaluations and equal wall time."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from .bench import SuiteConfig, check_dependencies, run_suite

    if quick and medium:
        console.print("[red]error:[/] choose at most one of --quick and --medium")
        raise typer.Exit(code=1)
    config = SuiteConfig.quick() if quick else SuiteConfig.medium() if medium else SuiteConfig.full()
    changes = {k: v for k, v in (("seeds", seeds), ("problems", _names(problems)), ("samplers", _names(samplers))) if v is not None}
    try:
        config = config.replace(**changes)
        check_dependencies(config)
    except (ValueError, ImportError) as err:
        console.print(f"[red]error:[/] {err}")
        raise typer.Exit(code=1) from None
    console.print(
        f"[bold]{config.name} suite:[/] {', '.join(config.problems)}; {config.seeds} seed(s); "
        f"full budget {config.full_evaluations:,} evaluations"
    )
    result = run_suite(config, out, progress=progress, log=None if progress else console.print)

    table = Table(title="Recorded ratios (jump Restore / other)")
    for column, justify in (("ratio", "left"), ("problem", "left"), ("value", "right"), ("goal", "right"), ("met", "center")):
        table.add_column(column, justify=justify)
    summary_at = next((i for i, r in enumerate(result.ratios) if r.problem == "geometric mean"), None)
    for i, r in enumerate(result.ratios):
        met = {True: "[green]yes[/]", False: "[red]no[/]", None: ""}[r.met]
        table.add_row(r.name, r.problem, f"{r.value:.3g}", r.goal, met, end_section=summary_at is not None and i == summary_at - 1)
    console.print(table)
    console.print(f"Suite took {result.seconds / 60:.1f} min. Files:")
    for path in result.files.values():
        console.print(f"  {path}")


if __name__ == "__main__":  # pragma: no cover
    app()
