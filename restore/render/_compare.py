"""Equal-time comparison of the renderers on Mitsuba scenes: images, error curves, a table and the ratios.

For each scene: a cached high-spp reference (Mitsuba's `path` integrator), then every
method for `seconds` of wall time (compilation excluded), `realisations` times with
independent keys. The PSS methods run on the path-tracing target (`technique="path"`,
`PrimarySampleSpace`) or on multiplexed BDPT (`technique="bdpt"`, `MultiplexedBDPT`:
PSSMLT is then MMLT); `path` is always Mitsuba's own path tracer. Errors are measured against the reference; error-versus-time curves
come from the progressive images. Writes `results.md`, `results.csv` and one figure per
scene (`scene-<name>.png`: reference and method images, zoomed crops, error curves).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import jax
import numpy as np

from .._io import matplotlib_for, save_and_close, write_text
from ._driver import render
from ._methods import GRADIENT_METHODS, METHODS, P_LARGE, TOUR_LENGTH, default_lanes, make_renderer
from ._metrics import l1, mape, mrse, mse, relative_mse, relative_variance, variance_across
from ._restore_renderer import RestoreStatistics

#: The primary-sample-space targets the PSS methods can run on.
TECHNIQUES = ("path", "bdpt")

CSV_COLUMNS = ("scene", "method", "realisation", "seconds", "evaluations", "l1", "mse", "relative_mse", "mrse", "mape")
#: Renderer diagnostics kept per run (Metropolis Restore's; empty for the other methods).
DIAGNOSTICS = ("finishing_seconds", "tour_k_hat", "effective_tours", "tours_completed")


@dataclasses.dataclass
class MethodRun:
    """One render of one method on one scene, with its error curve `(seconds, relative MSE)`, a few
    of its progressive images `(seconds, image)` (log-spaced in time, for the variance across
    realisations over time) and the renderer's diagnostics (`DIAGNOSTICS`, those it has)."""

    scene: str
    method: str
    realisation: int
    image: np.ndarray
    seconds: float
    evaluations: int
    metrics: dict[str, float]
    curve: list[tuple[float, float]]
    diagnostics: dict[str, float] = dataclasses.field(default_factory=dict)
    snapshots: list[tuple[float, np.ndarray]] = dataclasses.field(default_factory=list)


#: Progressive images kept per render (log-spaced in time) for the variance over time.
SNAPSHOTS = 16


def thin_snapshots(snapshots: list[tuple[float, np.ndarray]], keep: int = SNAPSHOTS) -> list[tuple[float, np.ndarray]]:
    """At most `keep` of `(seconds, image)` snapshots, the last always among them, the others
    those nearest to log-spaced times from the first."""
    if len(snapshots) <= keep:
        return list(snapshots)
    times = np.array([max(t, 1e-9) for t, _ in snapshots])
    wanted = np.geomspace(times[0], times[-1], keep)
    chosen = sorted({int(np.argmin(np.abs(np.log(times) - np.log(w)))) for w in wanted} | {len(snapshots) - 1})
    return [snapshots[i] for i in chosen]


@dataclasses.dataclass
class RenderComparison:
    """Everything `compare_renderers` measured."""

    scenes: tuple[str, ...]
    methods: tuple[str, ...]
    seconds: float
    realisations: int
    resolution: tuple[int, int]
    max_depth: int
    references: dict[str, np.ndarray]
    runs: list[MethodRun]
    throughput: dict[str, tuple[float, float]]  # scene -> (PSS paths/s, native paths/s)
    skipped: dict[tuple[str, str], str]
    settings: dict[str, float] = dataclasses.field(default_factory=dict)  # lanes, tour_length, p_large
    files: dict[str, Path] = dataclasses.field(default_factory=dict)
    technique: str = "path"  # the PSS methods' target: "path" (PrimarySampleSpace) or "bdpt" (MultiplexedBDPT)

    def mean_metric(self, scene: str, method: str, metric: str = "relative_mse") -> float:
        values = [r.metrics[metric] for r in self.runs if r.scene == scene and r.method == method]
        return float(np.mean(values)) if values else math.nan

    def mean_seconds(self, scene: str, method: str) -> float:
        values = [r.seconds for r in self.runs if r.scene == scene and r.method == method]
        return float(np.mean(values)) if values else math.nan

    def work_normalised(self, scene: str, method: str) -> float:
        """Mean relative MSE times mean wall time: the inverse efficiency, which compares
        renders that ran for slightly different times (Restore finishes its open tours
        after the budget) as if at equal time, for errors falling as 1 / time."""
        return self.mean_metric(scene, method) * self.mean_seconds(scene, method)

    def median_normalised(self, scene: str, method: str) -> float:
        """The median over realisations of relative MSE x seconds (one bad seed moves it less than the mean)."""
        values = [r.metrics["relative_mse"] * r.seconds for r in self.runs if r.scene == scene and r.method == method]
        return float(np.median(values)) if values else math.nan

    def ratios(self) -> list[tuple[str, str, float, str]]:
        """`(ratio, scene, value, goal)` rows: throughput, Restore / PSSMLT and Restore / path tracing,
        and each gradient Restore variant / its counterpart, where both ran (relative MSE x
        seconds, see `work_normalised`)."""
        return [row[:4] for row in self._ratio_rows()]

    def _ratio_rows(self) -> list[tuple[str, str, float, str, float]]:
        """`ratios()` with, last, the same ratio of the medians over realisations (NaN for throughput)."""
        rows = []
        for scene in self.scenes:
            if scene in self.throughput:
                pss, native = self.throughput[scene]
                rows.append(("PSS paths/s / native path samples/s", scene, pss / native, ">= 0.5", math.nan))
        mlt = "MMLT" if self.technique == "bdpt" else "pssmlt"
        pairs = [("restore", other, f"Metropolis Restore / {mlt if other == 'pssmlt' else other}", goal) for other, goal in (("pssmlt", "<= 0.8"), ("path", "< 1"))]
        pairs += [(variant, counterpart, label, "<= 0.8") for variant, counterpart, label in GRADIENT_PAIRS]
        for scene in self.scenes:
            for method, other, label, goal in pairs:
                value = self.work_normalised(scene, method) / self.work_normalised(scene, other)
                if math.isfinite(value):
                    median = self.median_normalised(scene, method) / self.median_normalised(scene, other)
                    rows.append((f"relative MSE x time, {label}", scene, value, goal, median))
        return rows

    def variance_curve(self, scene: str, method: str, points: int = 12) -> list[tuple[float, float]]:
        """`(seconds, relative variance across realisations)` of `method`'s progressive images on
        `scene` (`relative_variance` against the reference), at `points` log-spaced times that
        every realisation reached: each contributes its last image at or before the time.
        Empty with fewer than two realisations with images."""
        runs = [r for r in self.runs if r.scene == scene and r.method == method and r.snapshots]
        if len(runs) < 2:
            return []
        start = max(r.snapshots[0][0] for r in runs)
        end = min(r.snapshots[-1][0] for r in runs)
        if not (start > 0 and end >= start):
            return []
        curve = []
        for t in np.geomspace(start, end, points) if end > start else [end]:
            images = [next(image for time, image in reversed(r.snapshots) if time <= t * (1 + 1e-9)) for r in runs]
            curve.append((float(t), relative_variance(images, self.references[scene])))
        return curve


#: The Restore variants of the gradient methods and their counterparts, as the Restore paper pairs them.
GRADIENT_PAIRS = (("mala-restore", "mala", "MALA Restore / MALA"), ("h2mc-restore", "h2mc", "H2MC Restore / H2MC"))


def _metrics(image: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    return {
        "l1": l1(image, reference), "mse": mse(image, reference), "relative_mse": relative_mse(image, reference),
        "mrse": mrse(image, reference), "mape": mape(image, reference),
    }


def _native_run(scene, reference, seconds: float, max_depth: int, seed: int):
    """Mitsuba's `path` integrator at full speed for `seconds` (passes of about 2^20 paths);
    returns image, spp, time and error curve (one point per pass)."""
    from targets.mitsuba import render_native, render_native_for

    width, height = (int(v) for v in scene.sensors()[0].film().crop_size())
    render_native(scene, max(1, (1 << 20) // (width * height)), seed=10**6 + seed, max_depth=max_depth)  # compile outside the budget
    curve: list[tuple[float, float]] = []
    native = render_native_for(
        scene, seconds, max_depth=max_depth, seed=seed,
        on_update=lambda image, elapsed: curve.append((elapsed, relative_mse(image, reference))),
    )
    return native.image, native.spp, native.seconds, curve


def lanes_by_method(lanes: int | Mapping[str, int] | None, methods: Sequence[str]) -> dict[str, int]:
    """Parallel lanes of each PSS method among `methods`: each method's default
    (`default_lanes`) for `None`, `lanes` for all, or a mapping from method names to lanes
    (`"*"` sets the methods it leaves out, which otherwise keep their defaults).

    Raises:
        ValueError: a count that is not a positive integer, or a name that is not a PSS method.
    """
    given = {} if lanes is None else dict(lanes) if isinstance(lanes, Mapping) else {"*": lanes}
    for name, n in given.items():
        if name != "*" and (name not in METHODS or name == "path"):
            raise ValueError(f"lanes given for {name!r}, which is not a PSS method ({', '.join(METHODS[1:])})")
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"lanes must be positive integers, got {n!r} for {name!r}")
    return {m: int(given.get(m, given.get("*", default_lanes(m)))) for m in methods if m != "path"}


def compare_renderers(
    scenes: Sequence[str] = ("cornell_box", "door_ajar", "caustic", "glass_torus"),
    methods: Sequence[str] = METHODS,
    *,
    seconds: float = 10.0,
    realisations: int = 3,
    resolution: tuple[int, int] = (64, 64),
    max_depth: int = 5,
    lanes: int | Mapping[str, int] | None = None,
    tour_length: float = TOUR_LENGTH,
    p_large: float = P_LARGE,
    reference_spp: int = 4096,
    technique: str = "path",
    out_dir: str | Path | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> RenderComparison:
    """Render every method on every scene at equal time and compare with a reference.

    Arguments:
        scenes: registry names (`targets.mitsuba.SCENES`) or XML paths.
        methods: among `METHODS`; gradient methods are skipped (and noted) on scenes they do not support.
        seconds: wall time per render, compilation excluded.
        realisations: independent renders per method (for the variance across realisations).
        resolution, max_depth: the film and path length, for every method and the reference.
        lanes: parallel lanes of the PSS renderers, or a mapping from method names to
            lanes (`lanes_by_method`); by default each method's own (`default_lanes`:
            Restore's independent tours gain from more lanes than PSSMLT's chains, which
            need length, `docs/rendering.md`).
        tour_length: Restore's mean tour length (local moves per tour, complete tours).
        p_large: PSSMLT's large-step probability.
        reference_spp: samples per pixel of the cached reference.
        technique: the target of the PSS methods: `"path"` (`PrimarySampleSpace`, path
            tracing) or `"bdpt"` (`MultiplexedBDPT`: small steps keep the depth and strategy,
            so `pssmlt` is MMLT; gradient methods are skipped, it has no gradients).
        out_dir: where to write `results.md`, `results.csv` and the figures (nothing written if `None`).
        progress: progress bars for each render.
        log: called with one line per finished render, and with each change made to a
            scene file (its filter, film size and depth: every method renders the same
            `resolution` and `max_depth`).
    """
    from targets.mitsuba import (
        MultiplexedBDPT,
        PrimarySampleSpace,
        UnsupportedSceneError,
        load_scene,
        native_paths_per_second,
        reference_image,
    )

    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise ValueError(f"unknown methods {bad}; choose from {', '.join(METHODS)}")
    if technique not in TECHNIQUES:
        raise ValueError(f"unknown technique {technique!r}; choose from {', '.join(TECHNIQUES)}")
    if not seconds > 0 or realisations < 1:
        raise ValueError(f"need seconds > 0 and realisations >= 1, got {seconds} and {realisations}")
    lanes_of = lanes_by_method(lanes, methods)
    say = log or (lambda text: None)
    references, runs, throughput, skipped = {}, [], {}, {}
    for scene_name in scenes:
        scene_key = Path(scene_name).stem
        references[scene_key] = reference = reference_image(scene_name, reference_spp, resolution=resolution, max_depth=max_depth)

        def note(text: str, name: str = scene_key) -> None:  # the default binds this scene's name (a closure would see a later one)
            say(f"{name}: note: {text}")

        scene = load_scene(scene_name, resolution, max_depth, log=note)
        target = PrimarySampleSpace(scene) if technique == "path" else MultiplexedBDPT(scene, max_depth=max_depth)
        throughput[scene_key] = (target.paths_per_second(), native_paths_per_second(scene, max_depth=max_depth))
        for method in methods:
            pss_target = target
            if method in GRADIENT_METHODS and technique == "bdpt":
                skipped[(scene_key, method)] = "needs gradients, which multiplexed BDPT does not offer"
                say(f"{scene_key} {method}: skipped (no gradients with BDPT)")
                continue
            if method in GRADIENT_METHODS:
                try:
                    pss_target = PrimarySampleSpace(scene, russian_roulette=False)
                    pss_target.check_gradient_support()
                except UnsupportedSceneError as error:
                    skipped[(scene_key, method)] = str(error)
                    say(f"{scene_key} {method}: skipped ({error})")
                    continue
            for r in range(realisations):
                diagnostics: dict[str, float] = {}
                if method == "path":
                    image, spp, elapsed, curve = _native_run(scene, reference, seconds, max_depth, seed=r)
                    evaluations = spp * resolution[0] * resolution[1]
                    snapshots = []
                else:
                    stamps: list[tuple[float, float]] = []
                    images: list[np.ndarray] = []

                    def update(img, _statistics, stamps=stamps, images=images, reference=reference):
                        stamps.append((time.perf_counter(), relative_mse(img, reference)))
                        images.append(img)

                    result = render(
                        pss_target, make_renderer(method, tour_length=tour_length, p_large=p_large), key=jax.random.key(1000 * r + 7),
                        seconds=seconds, num_lanes=lanes_of[method], progress=progress, on_update=update,
                    )
                    shift = stamps[-1][0] - result.seconds if stamps else 0.0
                    curve = [(t - shift, e) for t, e in stamps]
                    snapshots = thin_snapshots([(t, image) for (t, _), image in zip(curve, images)])
                    image, elapsed, evaluations = result.image, result.seconds, result.evaluations
                    if isinstance(result.statistics, RestoreStatistics):
                        found = dict(result.statistics.as_dict(), finishing_seconds=result.finishing_seconds)
                        diagnostics = {k: float(found[k]) for k in DIAGNOSTICS}
                run = MethodRun(
                    scene_key, method, r, image, elapsed, evaluations, _metrics(image, reference), curve, diagnostics, snapshots
                )
                runs.append(run)
                say(f"{scene_key} {method} #{r}: {elapsed:.1f} s, {evaluations:,} paths, relative MSE {run.metrics['relative_mse']:.4g}")
    comparison = RenderComparison(
        tuple(Path(s).stem for s in scenes), tuple(methods), float(seconds), realisations, (resolution[0], resolution[1]), max_depth,
        references, runs, throughput, skipped, _settings(lanes_of, tour_length, p_large),
        technique=technique,
    )
    if out_dir is not None:
        write_comparison(comparison, Path(out_dir))
    return comparison


def _settings(lanes_of: dict[str, int], tour_length: float, p_large: float) -> dict[str, float]:
    """The settings line: `lanes` when every PSS method runs the same count, else `<method> lanes` each."""
    counts = set(lanes_of.values())
    by_method = {"lanes": counts.pop()} if len(counts) == 1 else {f"{m} lanes": n for m, n in lanes_of.items()}
    return {**by_method, "tour_length": tour_length, "p_large": p_large}


def _fmt(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.3g}"


def markdown(comparison: RenderComparison) -> str:
    """The results page: ratios, per-scene tables and figures."""
    from restore.bench._report import machine_description

    c = comparison
    lines = [
        "# Rendering comparison at equal time",
        "",
        f"{len(c.scenes)} scene(s) at {c.resolution[0]}x{c.resolution[1]}, max depth {c.max_depth}; every method "
        f"renders for {c.seconds:g} s (compilation excluded), {c.realisations} independent realisation(s). Errors "
        "against a cached high-spp reference of Mitsuba's `path` integrator; relative MSE uses eps = 0.01. "
        "The Restore methods then finish the tours still open (their seconds include that), so the ratios "
        "compare relative MSE x seconds (inverse efficiency). "
        + (
            "The PSS methods run on multiplexed BDPT (small steps keep the depth and strategy: pssmlt is MMLT)."
            if c.technique == "bdpt" else "The PSS methods run on the path-tracing target."
        ),
        "",
        "Settings: " + ", ".join(f"{k} {v:g}" for k, v in c.settings.items()) + ".",
        "",
        "## Ratios",
        "",
        "| ratio | scene | value (of means) | of medians | goal |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {name} | {scene} | **{_fmt(value)}** | {_fmt(median)} | {goal} |" for name, scene, value, goal, median in c._ratio_rows()]
    for scene in c.scenes:
        lines += [
            "",
            f"## {scene}",
            "",
            "| method | seconds (mean) | paths (mean) | relative MSE | MRSE | MAPE | L1 | MSE | variance across realisations |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for method in c.methods:
            runs = [r for r in c.runs if r.scene == scene and r.method == method]
            if not runs:
                if (scene, method) in c.skipped:
                    lines.append(f"| {method} | skipped: {c.skipped[(scene, method)]} | | | | | | | |")
                continue
            var = variance_across([r.image for r in runs]) if len(runs) > 1 else math.nan
            m = lambda k: float(np.mean([r.metrics[k] for r in runs]))  # noqa: B023, E731
            lines.append(
                f"| {method} | {np.mean([r.seconds for r in runs]):.1f} | {np.mean([r.evaluations for r in runs]):,.0f} | {_fmt(m('relative_mse'))} | {_fmt(m('mrse'))} | "
                f"{_fmt(m('mape'))} | {_fmt(m('l1'))} | {_fmt(m('mse'))} | {_fmt(var)} |"
            )
        lines += _tour_diagnostics(c, scene)
        if f"scene-{scene}" in c.files:
            lines += ["", f"![{scene}](scene-{scene}.png)"]
    lines += ["", "## Machine", "", "| | |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in machine_description().items()]
    return "\n".join(lines) + "\n"


def _tour_diagnostics(c: RenderComparison, scene: str) -> list[str]:
    """A sentence on Metropolis Restore's tours in `scene`: finishing time, tail shape and
    effective number of tours, per realisation."""
    runs = [r for r in c.runs if r.scene == scene and r.method == "restore" and r.diagnostics]
    if not runs:
        return []
    d = lambda k, f: ", ".join(f.format(r.diagnostics[k]) for r in runs)  # noqa: E731
    return [
        "",
        f"Metropolis Restore's tours, per realisation: finishing {d('finishing_seconds', '{:.1f}')} s after the "
        f"budget; tail shape of the tour durations k_hat {d('tour_k_hat', '{:.2f}')} (above 0.7 a few long tours "
        f"carry much of the light, and the render warns); effective tours {d('effective_tours', '{:,.0f}')} of "
        f"{d('tours_completed', '{:,.0f}')}.",
    ]


def _crop_window(reference: np.ndarray) -> tuple[slice, slice]:
    """A window a quarter of the image wide around the pixel with the largest local contrast."""
    h, w = reference.shape[:2]
    size = max(4, min(h, w) // 4)
    grad_y, grad_x = np.gradient(reference.mean(axis=2))
    contrast = np.abs(grad_y) + np.abs(grad_x)
    y, x = np.unravel_index(np.argmax(contrast), contrast.shape)
    y0, x0 = min(max(0, y - size // 2), h - size), min(max(0, x - size // 2), w - size)
    return slice(y0, y0 + size), slice(x0, x0 + size)


def plot_scene(comparison: RenderComparison, scene: str, path: Path) -> Path | None:
    """Reference and first-realisation images, zoomed crops, relative MSE against time (every
    realisation) and the variance across realisations against time (the PSS methods)."""
    matplotlib_for("the rendering comparison's figures")
    import matplotlib.patches
    import matplotlib.pyplot as plt

    from ._images import tonemap

    reference = comparison.references[scene]
    firsts = {r.method: r for r in comparison.runs if r.scene == scene and r.realisation == 0}
    if not firsts:
        return None
    panels = [("reference", reference)] + [(m, firsts[m].image) for m in comparison.methods if m in firsts]
    ys, xs = _crop_window(reference)
    fig = plt.figure(figsize=(2.2 * len(panels), 10.0), layout="constrained")
    grid = fig.add_gridspec(4, len(panels), height_ratios=(1, 1, 1.3, 1.3))
    for i, (name, image) in enumerate(panels):
        ax = fig.add_subplot(grid[0, i])
        ax.imshow(tonemap(image), interpolation="nearest")
        ax.add_patch(matplotlib.patches.Rectangle((xs.start - 0.5, ys.start - 0.5), xs.stop - xs.start, ys.stop - ys.start, fill=False, color="yellow"))
        title = name if name == "reference" else f"{name}\nrelMSE {firsts[name].metrics['relative_mse']:.3g}"
        ax.set_title(title, fontsize=8)
        ax.axis("off")
        crop = fig.add_subplot(grid[1, i])
        crop.imshow(tonemap(image[ys, xs]), interpolation="nearest")
        crop.axis("off")
    ax = fig.add_subplot(grid[2, :])
    for method in comparison.methods:
        for r in (r for r in comparison.runs if r.scene == scene and r.method == method):
            t, e = zip(*r.curve) if r.curve else ((), ())
            ax.plot(t, e, marker=".", alpha=0.8, color=f"C{comparison.methods.index(method)}", label=method if r.realisation == 0 else None)
    ax.set(xscale="log", yscale="log", xlabel="wall time (s, compilation excluded)", ylabel="relative MSE", title=f"{scene}: error against time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[3, :])
    for method in comparison.methods:
        curve = comparison.variance_curve(scene, method)
        if curve:
            t, v = zip(*curve)
            ax.plot(t, v, marker=".", color=f"C{comparison.methods.index(method)}", label=method)
    ax.set(xscale="log", yscale="log", xlabel="wall time (s, compilation excluded)", ylabel="relative variance",
           title=f"{scene}: variance across the {comparison.realisations} realisations against time")
    ax.grid(True, which="both", alpha=0.3)
    if ax.lines:
        ax.legend(fontsize=8)
    save_and_close(fig, path, dpi=110)
    return path


def write_comparison(comparison: RenderComparison, out: Path) -> dict[str, Path]:
    """Write `results.csv`, one figure per scene and `results.md` into `out`."""
    out.mkdir(parents=True, exist_ok=True)
    files = {"csv": out / "results.csv"}
    text = io.StringIO()
    writer = csv.writer(text)
    writer.writerow(CSV_COLUMNS + DIAGNOSTICS)
    for r in comparison.runs:
        writer.writerow(
            [r.scene, r.method, r.realisation, f"{r.seconds:.3f}", r.evaluations]
            + [f"{r.metrics[k]:.6g}" for k in CSV_COLUMNS[5:]]
            + [f"{r.diagnostics[k]:.6g}" if k in r.diagnostics else "" for k in DIAGNOSTICS]
        )
    write_text(files["csv"], text.getvalue(), newline="")
    for scene in comparison.scenes:
        path = plot_scene(comparison, scene, out / f"scene-{scene}.png")
        if path is not None:
            files[f"scene-{scene}"] = path
    comparison.files = files
    files["markdown"] = out / "results.md"
    write_text(files["markdown"], markdown(comparison))
    return files
