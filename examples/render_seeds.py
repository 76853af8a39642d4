"""Seed robustness: the spread of PSSMLT's and Metropolis Restore's images across seeds and bootstrap sizes.

On a scene with separated bright path families (the caustic: light reaches the floor
directly and, much brighter per path, focused through the glass sphere) each method renders
`--seeds` independent images for each bootstrap size, at equal time. PSSMLT starts its
chains at the bootstrap resampled by luminance, so a few very bright bootstrap paths can
hold many chains for the whole render; Metropolis Restore's complete tours start at uniform
draws and use the bootstrap only for `c`. Prints one table and writes `seeds.md`,
`seeds.csv` and `seeds.png` into `--out`.

    python examples/render_seeds.py --scene caustic --seconds 10 --seeds 5 --out docs/rendering
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

from restore._io import matplotlib_for, save_and_close, write_csv, write_text
from restore.render import PSSMLT, MetropolisRestore, relative_mse, render

METHODS = {"pssmlt": PSSMLT, "restore": MetropolisRestore}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="caustic")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--bootstrap", default="4096,65536,1048576", help="bootstrap sizes, comma-separated")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--max-depth", type=int, default=6)
    parser.add_argument("--lanes", type=int, default=2048)
    parser.add_argument("--reference-spp", type=int, default=16384)
    parser.add_argument("--out", type=Path, default=Path("render-seeds"))
    args = parser.parse_args()
    from targets.mitsuba import PrimarySampleSpace, load_scene, reference_image

    sizes = [int(s) for s in args.bootstrap.split(",") if s]
    resolution = (args.resolution, args.resolution)
    reference = reference_image(args.scene, args.reference_spp, resolution=resolution, max_depth=args.max_depth)
    target = PrimarySampleSpace(load_scene(args.scene, resolution, args.max_depth))
    rows = []
    for size in sizes:
        for method, make in METHODS.items():
            for seed in range(args.seeds):
                start = time.perf_counter()
                result = render(target, make(n_bootstrap=size), key=jax.random.key(1000 * seed + 11),
                                seconds=args.seconds, num_lanes=args.lanes, progress=False)
                error = relative_mse(result.image, reference)
                rows.append(dict(scene=args.scene, method=method, bootstrap=size, seed=seed, seconds=result.seconds,
                                 evaluations=result.evaluations, relative_mse=error))
                print(f"{args.scene} {method} bootstrap={size} seed={seed}: relMSE {error:.4g}, {result.seconds:.1f} s; "
                      f"wall {time.perf_counter() - start:.0f} s", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(args.out / "seeds.csv", rows)
    table = summary(rows, sizes)
    write_text(args.out / "seeds.md", table)
    plot(rows, sizes, args.out / "seeds.png", args.scene)
    print(table)


def _errors(rows, method: str, size: int) -> np.ndarray:
    return np.array([r["relative_mse"] for r in rows if r["method"] == method and r["bootstrap"] == size])


def summary(rows, sizes) -> str:
    lines = ["| method | bootstrap | seeds | relative MSE: mean | median | best | worst | worst / best | seconds |",
             "|---|---|---|---|---|---|---|---|---|"]
    for method in METHODS:
        for size in sizes:
            e = _errors(rows, method, size)
            seconds = np.mean([r["seconds"] for r in rows if r["method"] == method and r["bootstrap"] == size])
            lines.append(f"| {method} | {size} | {len(e)} | {e.mean():.4g} | {np.median(e):.4g} | {e.min():.4g} | "
                         f"{e.max():.4g} | {e.max() / e.min():.2f} | {seconds:.1f} |")
    return "\n".join(lines) + "\n"


def plot(rows, sizes, path: Path, scene: str) -> None:
    matplotlib_for("the seed figure")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6), layout="constrained")
    for offset, (method, marker) in zip((-0.08, 0.08), (("pssmlt", "s"), ("restore", "o"))):
        for i, size in enumerate(sizes):
            e = _errors(rows, method, size)
            ax.scatter(np.full(len(e), i + offset), e, marker=marker, color=f"C{0 if method == 'pssmlt' else 1}",
                       label=method if i == 0 else None, alpha=0.8)
    ax.set(xticks=range(len(sizes)), xticklabels=[f"{s:,}" for s in sizes], yscale="log", xlabel="bootstrap size",
           ylabel="relative MSE (one dot per seed)", title=f"{scene}: spread across seeds")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    save_and_close(fig, path, dpi=110)


if __name__ == "__main__":
    main()
