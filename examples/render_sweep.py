"""Sweep of the exploration settings behind the renderers' defaults, at equal time.

Metropolis Restore's mean tour length `L` and lane count, and PSSMLT's large-step
probability and lane count, each varied alone on hard scenes; every render runs for the
same wall time (compilation excluded; Restore's finishing of open tours included in its
time and normalised away by comparing relative MSE x seconds). Prints one table and
writes `sweep.md`, `sweep.csv` and `sweep.png` into `--out`.

    python examples/render_sweep.py --scenes door_gap,pool --seconds 10 --realisations 3 --out docs/rendering
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

from restore._io import matplotlib_for, save_and_close, write_csv, write_text
from restore.render import PSSMLT, MetropolisRestore, relative_mse, render
from restore.render._methods import LANES, P_LARGE, TOUR_LENGTH

#: (method, setting, value, lanes): one at a time away from the defaults
GRID = (
    [("restore", "tour_length", v, LANES) for v in (0.25, 1.0, 4.0, 32.0)]
    + [("restore", "lanes", TOUR_LENGTH, n) for n in (512, 16384)]
    + [("pssmlt", "p_large", v, LANES) for v in (0.03, 0.1, 0.3)]
    + [("pssmlt", "lanes", P_LARGE, n) for n in (512, 16384)]
)


def make(method: str, setting: str, value: float):
    if method == "restore":
        return MetropolisRestore(tour_length=value if setting == "tour_length" else TOUR_LENGTH)
    return PSSMLT(p_large=value if setting == "p_large" else P_LARGE)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="door_gap,pool")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--realisations", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=6)
    parser.add_argument("--reference-spp", type=int, default=65536)
    parser.add_argument("--out", type=Path, default=Path("render-sweep"))
    args = parser.parse_args()
    from targets.mitsuba import PrimarySampleSpace, load_scene, reference_image

    scenes = [s for s in args.scenes.split(",") if s]
    resolution = (args.resolution, args.resolution)
    rows = []
    for scene_name in scenes:
        reference = reference_image(scene_name, args.reference_spp, resolution=resolution, max_depth=args.max_depth)
        target = PrimarySampleSpace(load_scene(scene_name, resolution, args.max_depth))
        for method, setting, value, lanes in GRID:
            for r in range(args.realisations):
                start = time.perf_counter()
                result = render(target, make(method, setting, value), key=jax.random.key(1000 * r + 7),
                                seconds=args.seconds, num_lanes=lanes, progress=False)
                error = relative_mse(result.image, reference)
                rows.append(dict(scene=scene_name, method=method, setting=setting, value=value, lanes=lanes,
                                 realisation=r, seconds=result.seconds, evaluations=result.evaluations,
                                 finishing_steps=result.finishing_steps, relative_mse=error))
                print(f"{scene_name} {method} {setting}={value:g} lanes={lanes} #{r}: relMSE {error:.4g}, "
                      f"{result.seconds:.1f} s ({result.finishing_steps} finishing steps), "
                      f"{result.evaluations / result.seconds:.3g} paths/s; wall {time.perf_counter() - start:.0f} s",
                      flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(args.out / "sweep.csv", rows)
    table = summary(rows, scenes)
    write_text(args.out / "sweep.md", table)
    plot(rows, scenes, args.out / "sweep.png")
    print(table)


def _groups(rows, scene):
    keys = []
    for row in rows:
        key = (row["method"], row["setting"], row["value"], row["lanes"])
        if row["scene"] == scene and key not in keys:
            keys.append(key)
    for key in keys:
        runs = [r for r in rows if r["scene"] == scene and (r["method"], r["setting"], r["value"], r["lanes"]) == key]
        error = np.mean([r["relative_mse"] for r in runs])
        seconds = np.mean([r["seconds"] for r in runs])
        yield key, runs, error, seconds


def summary(rows, scenes) -> str:
    lines = ["| scene | method | setting | lanes | seconds | paths/s | finishing steps | relative MSE | relative MSE x s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for scene in scenes:
        for (method, setting, value, lanes), runs, error, seconds in _groups(rows, scene):
            rate = np.mean([r["evaluations"] / r["seconds"] for r in runs])
            finishing = np.mean([r["finishing_steps"] for r in runs])
            shown = f"{setting} {value:g}" if setting != "lanes" else "defaults"
            lines.append(f"| {scene} | {method} | {shown} | {lanes} | {seconds:.1f} | {rate:.3g} | {finishing:.0f} | "
                         f"{error:.4g} | {error * seconds:.4g} |")
    return "\n".join(lines) + "\n"


def plot(rows, scenes, path: Path) -> None:
    matplotlib_for("the sweep's figure")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 3.6), layout="constrained", squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        for method, setting, marker in (("restore", "tour_length", "o"), ("pssmlt", "p_large", "s")):
            points = sorted((v, e * s) for (m, st, v, n), _, e, s in _groups(rows, scene) if m == method and st == setting)
            if points:
                x, y = zip(*points)
                ax.plot(x, y, marker=marker, label=f"{method}: {setting}")
        ax.set(xscale="log", yscale="log", title=scene, xlabel="setting value", ylabel="relative MSE x seconds")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    save_and_close(fig, path, dpi=110)


if __name__ == "__main__":
    main()
