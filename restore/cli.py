"""The `restore` command line."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import overload

import typer
from rich.console import Console
from rich.table import Table

from targets.mitsuba import SCENES

from .render._methods import LANES, METHOD_LANES, METHODS, P_LARGE, TOUR_LENGTH, default_lanes

app = typer.Typer(
    help="Restore samplers in JAX: jump Restore, baselines and checks.", no_args_is_help=True, add_completion=False
)
console = Console()


@app.callback()
def main(
    cache: bool = typer.Option(
        True,
        help="Keep compiled programs on disk ($JAX_COMPILATION_CACHE_DIR, else ~/.cache/restore/xla), so that a "
        "second run with the same settings loads them instead of compiling again.",
    ),
) -> None:
    """Restore samplers in JAX."""
    warnings.showwarning = _show_warning
    if cache:
        _cache_compilations()


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as the command's own words: its kind and message, without the file and line of
    the library frame it was attributed to (a command has no line of the user's to point at)."""
    print(f"{category.__name__}: {message}", file=sys.stderr if file is None else file)


def _cache_compilations() -> None:
    """Turn on JAX's persistent compilation cache, in the user's cache folder unless JAX's own variable names one."""
    import os

    import jax

    folder = os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(
        Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "restore" / "xla"
    )
    jax.config.update("jax_compilation_cache_dir", folder)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        # Programs that compile in a fraction of a second are worth keeping too: a run compiles many.
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.1)


@app.command()
def demo(
    dim: int = typer.Option(10, min=1, help="Dimension of the Gaussian mixture."),
    lanes: int = typer.Option(512, min=2, help="Parallel lanes of each sampler."),
    steps: int = typer.Option(1500, min=10, help="Steps per lane (one density evaluation each)."),
    tour_length: float = typer.Option(
        10.0, min=1e-6, help="Mean tour duration T = 1/c; MH large-step probability is 1/T."
    ),
    seed: int = typer.Option(0, help="Random seed."),
    out: Path = typer.Option(Path("restore-demo.png"), help="Where to write the plot."),
    progress: bool = typer.Option(True, help="Show progress bars."),
) -> None:
    """Jump Restore vs the MH mixture baseline on a multimodal target, at equal evaluations."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import restore

    from ._demo import plot_demo, run_demo

    console.print(f"[bold]Target:[/] {dim}-d mixture of 3 well-separated Gaussians, weights 1/6, 2/6, 3/6")
    outcome = run_demo(dim=dim, num_lanes=lanes, num_steps=steps, tour_length=tour_length, seed=seed, progress=progress)
    console.print(
        f"Regeneration: Student-t Laplace mixture with equal weights at {outcome.num_modes_found} modes found by optimistix"
    )

    table = Table(title=f"Mode weights, {outcome.evaluations:,} density evaluations per sampler")
    table.add_column("mode")
    table.add_column("truth", justify="right")
    table.add_column("jump Restore", justify="right")
    table.add_column("k_hat", justify="right")
    table.add_column("MH mixture", justify="right")
    table.add_column("k_hat", justify="right")
    for i, truth in enumerate(outcome.truth):
        table.add_row(
            str(i),
            f"{truth:.4f}",
            f"{outcome.restore.value[i]:.4f} ± {outcome.restore.standard_error[i]:.4f}",
            _k_hat(outcome.restore, i),
            f"{outcome.mh.value[i]:.4f} ± {outcome.mh.standard_error[i]:.4f}",
            _k_hat(outcome.mh, i),
        )
    rmse = lambda est: float(((est.value - outcome.truth) ** 2).mean() ** 0.5)  # noqa: E731
    table.add_row("RMSE", "", f"{rmse(outcome.restore):.4f}", "", f"{rmse(outcome.mh):.4f}", "", end_section=True)
    table.add_row(
        "wall time (with compilation)", "", f"{outcome.restore_seconds:.1f} s", "", f"{outcome.mh_seconds:.1f} s", ""
    )
    console.print(table)
    stats = outcome.restore_result.tour_statistics()
    console.print(
        f"jump Restore: {stats.num_tours:,} tours, mean duration {stats.mean_duration:.2f} ± {stats.mean_duration_se:.2f} "
        f"(1/c = {stats.expected_duration:.2f}); log Z = {float(outcome.log_z.value):.4f} ± {float(outcome.log_z.standard_error):.4f} "
        f"(truth 0), tail shape of the tours k_hat = {float(outcome.log_z.k_hat):.2f}"
    )
    console.print(
        "± is one standard error (Restore: regenerative, over tours; MH: over independent lanes). k_hat is the Pareto "
        f"shape of the tail of the terms each estimate sums: at or above {restore.K_HAT_LIMIT} (fewer terms: lower) the "
        "error bar is not trusted and the estimate is marked [red]*[/]."
    )
    try:
        console.print(f"Plot written to {plot_demo(outcome, out)}")
    except ImportError as err:  # matplotlib is an optional extra
        console.print(f"No plot: {err}")


def _k_hat(estimate, i: int) -> str:
    """`k_hat` of component `i`, starred in red when its error bar cannot be trusted."""
    k = float(estimate.k_hat[i])
    return f"{k:.2f}" + ("" if bool(estimate.reliable[i]) else " [red]*[/]")


@overload
def _names(text: str) -> tuple[str, ...]: ...
@overload
def _names(text: None) -> None: ...
def _names(text: str | None) -> tuple[str, ...] | None:
    return None if text is None else tuple(part.strip() for part in text.split(",") if part.strip())


_LANES_HELP = ", ".join(f"{n} for {m}" for m, n in METHOD_LANES.items()) + f", {LANES} for the others"


def _lanes(text: str) -> dict[str, int]:
    """`--lanes`: `2048`, `restore=16384` or `2048,restore=16384` (a bare count sets every method)."""
    given: dict[str, int] = {}
    for part in _names(text):
        name, _, count = part.rpartition("=")
        try:
            given[name.strip() or "*"] = int(count)
        except ValueError:
            _fail(f"--lanes must look like 2048 or 2048,restore=16384, got {text!r}")
    return given


@app.command()
def bench(
    quick: bool = typer.Option(
        False,
        "--quick",
        help="Small subset (2-d and 10-d mixtures; jump Restore RW, MH RW, emcee stretch): a few minutes.",
    ),
    medium: bool = typer.Option(
        False, "--medium", help="Every problem and sampler of the full mode with the quick budgets and 2 seeds."
    ),
    out: Path = typer.Option(Path("bench-results"), help="Folder for results.csv, results.md and the plots."),
    seeds: int | None = typer.Option(None, min=1, help="Number of seeds (default: 2 quick, 3 full)."),
    problems: str | None = typer.Option(None, help="Comma-separated problems to run (default: all of the mode)."),
    samplers: str | None = typer.Option(
        None, help="Comma-separated sampler-name prefixes to keep, e.g. 'restore-rw,mh-rw,emcee'."
    ),
    progress: bool = typer.Option(True, help="Show a progress bar over the runs (without it: one line per run)."),
    evidence: bool = typer.Option(
        False,
        "--evidence",
        help="The evidence benchmark instead: log Z of Restore, tempered SMC and nested sampling, moments beside NUTS (evidence.csv, evidence.md).",
    ),
) -> None:
    """Jump Restore against the MH baseline, emcee and BlackJAX, at equal evaluations and equal wall time."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from .bench import SuiteConfig, check_dependencies, run_suite

    if quick and medium:
        console.print("[red]error:[/] choose at most one of --quick and --medium")
        raise typer.Exit(code=1)
    if evidence:
        if medium:
            console.print("[red]error:[/] --evidence has a full and a --quick mode, no --medium")
            raise typer.Exit(code=1)
        _evidence(quick, out, seeds, problems, samplers, progress)
        return
    config = SuiteConfig.quick() if quick else SuiteConfig.medium() if medium else SuiteConfig.full()
    changes = {
        k: v
        for k, v in (("seeds", seeds), ("problems", _names(problems)), ("samplers", _names(samplers)))
        if v is not None
    }
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
    table.add_column("ratio", justify="left")
    table.add_column("problem", justify="left")
    table.add_column("value", justify="right")
    table.add_column("goal", justify="right")
    table.add_column("met", justify="center")
    summary_at = next((i for i, r in enumerate(result.ratios) if r.problem == "geometric mean"), None)
    for i, r in enumerate(result.ratios):
        met = {True: "[green]yes[/]", False: "[red]no[/]", None: ""}[r.met]
        table.add_row(
            r.name, r.problem, f"{r.value:.3g}", r.goal, met, end_section=summary_at is not None and i == summary_at - 1
        )
    console.print(table)
    if result.interrupted:
        console.print(
            f"[bold yellow]Interrupted by Ctrl-C:[/] the files hold the {len(result.rows)} runs that finished."
        )
    console.print(f"Suite took {result.seconds / 60:.1f} min. Files:")
    for path in result.files.values():
        console.print(f"  {path}")


def _evidence(
    quick: bool, out: Path, seeds: int | None, problems: str | None, samplers: str | None, progress: bool
) -> None:
    """`restore bench --evidence`: run the evidence benchmark and print its summary."""
    from .bench import EvidenceConfig, run_evidence
    from .bench._evidence_report import summary_rows

    config = EvidenceConfig.quick() if quick else EvidenceConfig.full()
    changes = {
        k: v
        for k, v in (("seeds", seeds), ("problems", _names(problems)), ("samplers", _names(samplers)))
        if v is not None
    }
    try:
        config = config.replace(**changes)
    except ValueError as err:
        console.print(f"[red]error:[/] {err}")
        raise typer.Exit(code=1) from None
    console.print(f"[bold]{config.name} evidence benchmark:[/] {', '.join(config.problems)}; {config.seeds} seed(s)")
    result = run_evidence(config, out, progress=progress, log=None if progress else console.print)
    table = Table(title="log Z error (estimate - truth) per seed")
    table.add_column("problem", justify="left")
    table.add_column("method", justify="left")
    table.add_column("runs", justify="left")
    table.add_column("log Z error", justify="right")
    table.add_column("evaluations", justify="right")
    table.add_column("run time (s)", justify="right")
    for s in summary_rows(result.rows):
        table.add_row(
            s["problem"],
            s["method"],
            s["runs"],
            s["errors"],
            f"{s['evaluations']:,.0f}" if s["evaluations"] == s["evaluations"] else "-",
            f"{s['run_time']:.1f}",
        )
    console.print(table)
    if result.interrupted:
        console.print(
            f"[bold yellow]Interrupted by Ctrl-C:[/] the files hold the {len(result.rows)} runs that finished."
        )
    console.print(f"Evidence benchmark took {result.seconds / 60:.1f} min. Files:")
    for path in result.files.values():
        console.print(f"  {path}")


#: `restore render`'s film size and depth for the built-in scenes.
_BUILTIN_RESOLUTION, _BUILTIN_MAX_DEPTH = "128", 5


def _fail(message: str) -> None:
    console.print(f"[bold red]error:[/] {message}", soft_wrap=True)
    raise typer.Exit(code=2)


def _resolution(text: str) -> tuple[int, int]:
    try:
        parts = [int(v) for v in text.lower().split("x")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) < 1:
        _fail(f"--resolution must look like 128 or 160x120, got {text!r}")
    return parts[0], parts[1]


@app.command()
def render(
    scene: str = typer.Argument(..., help=f"A built-in scene ({', '.join(sorted(SCENES))}) or a Mitsuba XML file."),
    method: str = typer.Option("restore", help=f"One of {', '.join(METHODS)} (path: Mitsuba's own path tracer)."),
    time_budget: float | None = typer.Option(
        None,
        "--time",
        min=1e-3,
        help="Wall-time budget of the sampling, in seconds. Loading the scene and compiling come "
        "before it, and Restore's finishing of its open tours after it, so the command takes longer: the summary shows the split.",
    ),
    evaluations: int | None = typer.Option(None, min=1, help="Path budget instead of (or as well as) a time budget."),
    out: Path = typer.Option(
        Path("render.exr"), help="Image to write (.exr, or .npy); a tonemapped .png preview is written beside it."
    ),
    resolution: str | None = typer.Option(
        None,
        help=f"Film size, e.g. 128 or 160x120 (default: an XML scene's own; {_BUILTIN_RESOLUTION} for built-in scenes).",
    ),
    max_depth: int | None = typer.Option(
        None,
        min=1,
        help=f"Maximum path depth, as in Mitsuba's path integrator (default: an XML scene's own; {_BUILTIN_MAX_DEPTH} for built-in scenes).",
    ),
    lanes: int | None = typer.Option(
        None, min=1, help=f"Parallel lanes of the PSS renderers (default: {_LANES_HELP})."
    ),
    tour_length: float = typer.Option(TOUR_LENGTH, min=1e-6, help="Restore's mean tour length (local moves per tour)."),
    p_large: float = typer.Option(P_LARGE, min=1e-6, max=1.0, help="PSSMLT's large-step probability."),
    seed: int = typer.Option(0, help="Random seed."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
    checkpoint: Path | None = typer.Option(
        None,
        help="Save the render's state to this file every minute, at the end and on Ctrl-C; resume from it if it exists (PSS methods).",
    ),
) -> None:
    """Render a Mitsuba scene with Metropolis Restore, a baseline, or Mitsuba's own path tracer.

    An XML scene keeps its film size and maximum depth unless --resolution or --max-depth
    is given; every setting of it that is changed (its reconstruction filter becomes a box
    filter) is printed. A table then says how many paths were traced and how fast, where
    the wall time went (scene loading, compiling, the budget, finishing), and whether a
    few samples decide the image (k_hat).
    """
    from .render._methods import GRADIENT_METHODS

    if method not in METHODS:
        _fail(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    if time_budget is None and evaluations is None:
        _fail("give a budget: --time SECONDS and/or --evaluations N")
    if out.suffix.lower() not in (".exr", ".npy"):
        _fail(f"--out must end in .exr or .npy, got {out.name!r}")
    if not out.parent.is_dir():
        _fail(f"folder {out.parent} does not exist")
    if checkpoint is not None and method == "path":
        _fail("--checkpoint works with the PSS methods; Mitsuba's path tracer (--method path) has no resumable state")
    if checkpoint is not None and not checkpoint.parent.is_dir():
        _fail(f"folder {checkpoint.parent} of --checkpoint does not exist")
    size = None if resolution is None else _resolution(resolution)
    try:
        from targets.mitsuba import LLVMNotFoundError, UnsupportedSceneError
    except ImportError as error:  # pragma: no cover - targets ships with the package
        _fail(str(error))
    try:
        settings = {"tour_length": tour_length, "p_large": p_large}
        lanes = default_lanes(method) if lanes is None else lanes
        image, rows, note = _render(scene, method, time_budget, evaluations, size, max_depth, lanes, settings, seed, progress, method in GRADIENT_METHODS, checkpoint)  # fmt: skip
    except (FileNotFoundError, UnsupportedSceneError, LLVMNotFoundError, ImportError) as error:
        _fail(str(error))
    except ValueError as error:
        _fail(str(error))
    from .render._images import save_image

    save_image(out, image)
    preview = save_image(out.with_suffix(".png"), image)
    table = Table(title=f"{method} on {Path(scene).name if scene not in SCENES else scene}", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    for row in rows:
        table.add_row(*row)
    console.print(table)
    if note:
        console.print(note, soft_wrap=True)
    console.print(f"Image written to {out} (preview {preview})")


def _render(scene, method, seconds, evaluations, resolution, max_depth, lanes, settings, seed, progress, needs_gradient, checkpoint=None):  # fmt: skip
    """Run one render; returns the image, the rows of its summary (`restore.render._summary`)
    and a note on an interrupted run. `settings` go to `make_renderer`.

    `resolution` and `max_depth` are `None` where not given: a built-in scene then gets the
    command's defaults, a scene file keeps its own (a depth is needed: Mitsuba's default of
    none becomes the library's default, with a note).
    """
    import time

    import jax

    from targets.mitsuba import PrimarySampleSpace, load_scene, render_native, render_native_for
    from targets.mitsuba._scene_checks import check_path_model, path_settings
    from targets.mitsuba._scenes import DEFAULT_MAX_DEPTH, is_scene_file

    from .render._summary import native_rows, render_rows

    start = time.perf_counter()

    if not is_scene_file(scene):
        resolution = resolution or _resolution(_BUILTIN_RESOLUTION)
        max_depth = max_depth or _BUILTIN_MAX_DEPTH
    notes: list[str] = []
    loaded = load_scene(scene, resolution, max_depth, log=notes.append)
    check_path_model(loaded)
    if max_depth is None:
        max_depth = path_settings(loaded).max_depth
        if max_depth is None:
            max_depth = DEFAULT_MAX_DEPTH
            notes.append(
                f"the scene's path integrator has no maximum depth; {max_depth} is used (pass --max-depth to choose)"
            )
    for note in notes:
        console.print(f"[yellow]note:[/] {note}", soft_wrap=True)
    resolution = tuple(int(v) for v in loaded.sensors()[0].film().crop_size())
    if method == "path":
        pixels = resolution[0] * resolution[1]
        scene_seconds = time.perf_counter() - start
        if evaluations is not None and seconds is None:
            spp = max(1, evaluations // pixels)
            began = time.perf_counter()
            image = render_native(loaded, spp, seed=seed, max_depth=max_depth)
            return image, native_rows(spp, pixels, time.perf_counter() - began, scene_seconds), ""
        native = render_native_for(loaded, seconds, max_depth=max_depth, seed=seed)
        note = (
            "[bold yellow]Interrupted by Ctrl-C:[/] the image holds the finished passes." if native.interrupted else ""
        )
        return native.image, native_rows(native.spp, pixels, native.seconds, scene_seconds), note
    from .render import render as run_render
    from .render._methods import make_renderer

    target = PrimarySampleSpace(loaded, max_depth=max_depth, russian_roulette=not needs_gradient)
    if needs_gradient:
        target.check_gradient_support()
    renderer = make_renderer(method, **settings)
    scene_seconds = time.perf_counter() - start
    result = run_render(
        target, renderer, key=jax.random.key(seed), seconds=seconds,
        evaluations=evaluations, num_lanes=lanes, progress=progress, checkpoint=checkpoint,
    )  # fmt: skip
    note = ""
    if result.interrupted:
        note = "[bold yellow]Interrupted by Ctrl-C:[/] the image holds the finished part of the run"
        note += "." if checkpoint is None else f" (run the same command again to resume from {checkpoint})."
    return result.image, render_rows(result, renderer, scene_seconds), note


@app.command("render-compare")
def render_compare(
    scenes: str = typer.Option(
        "cornell_box,door_ajar,caustic,glass_torus", help="Comma-separated scenes (names or XML files)."
    ),
    methods: str = typer.Option("path,uniform,pssmlt,restore,mala-restore,erpt", help="Comma-separated methods."),
    time_budget: float = typer.Option(10.0, "--time", min=1e-3, help="Seconds per render (compilation excluded)."),
    realisations: int = typer.Option(3, min=1, help="Independent renders per method and scene."),
    resolution: str = typer.Option("64", help="Film size, e.g. 64 or 96x64."),
    max_depth: int = typer.Option(5, min=1, help="Maximum path depth."),
    lanes: str | None = typer.Option(
        None,
        help=f"Parallel lanes of the PSS renderers: one count, or per method, e.g. 2048,restore=16384 (default: {_LANES_HELP}).",
    ),
    tour_length: float = typer.Option(TOUR_LENGTH, min=1e-6, help="Restore's mean tour length (local moves per tour)."),
    p_large: float = typer.Option(P_LARGE, min=1e-6, max=1.0, help="PSSMLT's large-step probability."),
    reference_spp: int = typer.Option(4096, min=1, help="Samples per pixel of the cached reference."),
    technique: str = typer.Option(
        "path", help="Target of the PSS methods: path (path tracing) or bdpt (multiplexed BDPT; pssmlt is then MMLT)."
    ),
    out: Path = typer.Option(Path("render-results"), help="Folder for results.md, results.csv and the figures."),
    progress: bool = typer.Option(True, help="Progress bars (without: one line per render)."),
) -> None:
    """Every method at equal time on each scene against a cached reference: figures, a table and the ratios."""
    from .render._compare import compare_renderers

    try:
        result = compare_renderers(
            _names(scenes), _names(methods), seconds=time_budget, realisations=realisations,
            resolution=_resolution(resolution), max_depth=max_depth, lanes=None if lanes is None else _lanes(lanes), tour_length=tour_length,
            p_large=p_large, reference_spp=reference_spp, technique=technique, out_dir=out, progress=progress,
            log=console.print,
        )  # fmt: skip
    except (FileNotFoundError, ValueError, ImportError, RuntimeError) as error:
        _fail(str(error))
    table = Table(title="Rendering ratios")
    for column in ("ratio", "scene", "value", "goal"):
        table.add_column(column)
    for name, scene, value, goal in result.ratios():
        table.add_row(name, scene, f"{value:.3g}", goal)
    console.print(table)
    console.print("Files:")
    for path in result.files.values():
        console.print(f"  {path}")


if __name__ == "__main__":  # pragma: no cover
    app()
