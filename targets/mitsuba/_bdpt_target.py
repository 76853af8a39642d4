"""`MultiplexedBDPT`: a Mitsuba scene as a density for multiplexed bidirectional path tracing.

A point `x = (v, u)` of `[0, 1)^(1 + D)` picks the depth and strategy `(k, s)` from `v`
with probability `q(k, s) = pmf[k] / (k + 1)` (`_multiplex`) and traces strategy `s`
from the primary samples `u` (`_bdpt`), which gives the MIS-weighted contribution
`g(x) = w_s C_s(u)` and its pixel `j(x)`. The target's colour and density are

    rgb(x) = g(x) / q(k, s),    p(x) = luminance(rgb(x)).

Normalisation: `q` is the length of the `v`-cell of `(k, s)`, so
`∫ p dx = sum_{k,s} ∫ luminance(w_s C_s(u)) du = Z`, and for each pixel `j`

    I_j = W H E_uniform[rgb(x) 1{j(x) = j}] = W H Z E_{p/Z}[rgb(x) / p(x) 1{j(x) = j}],

the image of Mitsuba's `path` integrator with `max_depth = M`: the same estimators as
`PrimarySampleSpace` (`Z` is the mean over pixels of the image's luminance).

Small steps must keep `v` (the depth and strategy) fixed, as in MMLT: `q` changes from
cell to cell, and a move across cells would need the other strategy's density. Move
only the coordinates `x[1:]` (`restore.local` kernels with `frozen=1`; the renderers of
`restore.render` read `frozen_coordinates = 1`); regenerations / large steps draw all of
`x` uniformly.

The pixel of a light-tracing strategy (`t = 1`) comes from the traced connection, not
from `u[0:2]`: `pixel_from_evaluation` is `True`, and `jax_evaluate_with_pixel` returns
it with the values. `pixel_index` traces the points again to find it.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np

from . import _jax_bridge
from ._bdpt import make_bdpt_tracer
from ._bdpt_checks import check_bdpt_support
from ._bdpt_mis import HEURISTICS
from ._bdpt_walk import dimension
from ._llvm import load_mitsuba
from ._multiplex import depth_pmf, select_pairs, strategy_pairs, strategy_pmf
from ._scene_checks import path_settings
from ._scenes import DEFAULT_MAX_DEPTH, load_scene
from ._target import DEFAULT_BATCH, PathSamples

#: Deliberate defects for negative controls in tests: name -> (weights, dropped strategy).
_DEFECTS: dict[str, tuple[str, int | None]] = {
    "unit_weights": ("unit", None),
    "unnormalised_power": ("unnormalised_power", None),
    "drop_s0": ("balance", 0),
    "drop_light_tracing": ("balance", -1),
}


class MultiplexedBDPT:
    """Multiplexed BDPT in primary sample space (see the module docstring for the maths).

    Arguments:
        scene_spec: a registry name, scene dictionary, XML path or loaded `mi.Scene`
            (then `resolution` must be `None`).
        resolution: `(width, height)` override of the film.
        max_depth: the most path segments `M`; default: the scene's `path` setting, else 8.
        depth_pmf: the pmf over depths `1..M`; default: estimated by `bootstrap` uniform
            strategy evaluations per depth (`estimate_depth_pmf`).
        bootstrap: evaluations per depth for the default pmf.
        heuristic: `"balance"` (pbrt's) or `"power"` MIS weights.
        variant: the Mitsuba variant, as for `PrimarySampleSpace`.
        batch_size: the most paths traced per Dr.Jit call.
        seed: seed of the bootstrap.

    Attributes:
        dim: `1 + D`; coordinate 0 is `v`.
        strategy_dim: `D`, the primary samples of one strategy.
        pairs: `(k, s)` int32 arrays of the multiplexed pairs; `q`: their probabilities.
        pmf: the depth pmf. `pixel_from_evaluation`: always `True`.
        frozen_coordinates: 1 (`v`, which small steps keep).

    Raises:
        UnsupportedSceneError: for a scene the bidirectional tracer cannot reproduce.

    Validated against Mitsuba's `path` image (uniform points, per pixel, block and in
    total) on the Cornell box, a glossy Cornell box, the glass-sphere caustic, a large
    light and `door_gap`. On the built-in `pool` (light reaching a diffuse floor only
    through a refracting water surface) each depth's strategies sum to Mitsuba's image of
    that depth, but the multiplexed estimate is heavy-tailed: at 16x16 and 2048 samples per
    pixel, independent images' totals range from 0.85 to 1.36 of the true one (at 16384:
    0.93 to 1.11), so few replicas give misleading standard errors.
    """

    pixel_from_evaluation = True
    frozen_coordinates = 1

    def __init__(
        self,
        scene_spec: str | Path | Mapping[str, Any] | Any,
        *,
        resolution: tuple[int, int] | None = None,
        max_depth: int | None = None,
        depth_pmf: np.ndarray | None = None,
        bootstrap: int = 10_000,
        heuristic: str = "balance",
        variant: str | None = None,
        batch_size: int = DEFAULT_BATCH,
        seed: int = 0,
        _defect: str | None = None,
    ) -> None:
        mi = load_mitsuba(variant)
        if isinstance(scene_spec, mi.Scene):
            if resolution is not None:
                raise ValueError("resolution cannot be changed on an already loaded mi.Scene; pass its dict or file")
            scene = scene_spec
        else:
            scene = load_scene(scene_spec, resolution, max_depth)
        check_bdpt_support(scene)
        if max_depth is None:
            max_depth = path_settings(scene).max_depth or DEFAULT_MAX_DEPTH
        if isinstance(max_depth, bool) or not isinstance(max_depth, (int, np.integer)) or max_depth < 1:
            raise ValueError(f"max_depth must be an integer >= 1, got {max_depth!r}")
        if heuristic not in HEURISTICS:
            raise ValueError(f"heuristic must be one of {sorted(HEURISTICS)}, got {heuristic!r}")
        if _defect is not None and _defect not in _DEFECTS:
            raise ValueError(f"unknown defect {_defect!r}; one of {sorted(_DEFECTS)}")
        if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
            raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
        self.scene = scene
        self.variant: str = mi.variant()
        self.max_depth = int(max_depth)
        self.heuristic = heuristic
        self.strategy_dim = dimension(self.max_depth)
        self.dim = 1 + self.strategy_dim
        width, height = (int(v) for v in scene.sensors()[0].film().crop_size())
        self.resolution = (width, height)
        self.num_pixels = width * height
        self.batch_size = int(batch_size)
        weights, dropped = _DEFECTS[_defect] if _defect is not None else (heuristic, None)
        self._trace = make_bdpt_tracer(self.max_depth, weights, dropped)
        self.pairs = strategy_pairs(self.max_depth)
        if depth_pmf is None:
            depth_pmf = self.estimate_depth_pmf(bootstrap, seed)
        self.set_depth_pmf(depth_pmf)
        self._jax_values = _jax_bridge.values_callback(self.evaluate, self.dim)
        self._jax_values_pixel = _jax_bridge.values_pixel_callback(self.evaluate, self.dim)

    def __repr__(self) -> str:
        return (
            f"MultiplexedBDPT(dim={self.dim}, resolution={self.resolution}, max_depth={self.max_depth}, "
            f"heuristic={self.heuristic!r}, variant={self.variant!r})"
        )

    def set_depth_pmf(self, pmf: np.ndarray) -> None:
        """Use `pmf` (length `max_depth`, positive, summing to 1) to choose depths."""
        pmf = np.asarray(pmf, np.float64)
        if pmf.shape != (self.max_depth,):
            raise ValueError(f"the depth pmf must have {self.max_depth} entries, got shape {pmf.shape}")
        self.q = strategy_pmf(pmf)
        self.pmf = pmf

    # ------------------------------------------------------------------ evaluation

    def evaluate_strategies(self, k: np.ndarray, s: np.ndarray, u: np.ndarray) -> PathSamples:
        """`w_s C_s(u)` (not divided by `q`), its luminance and pixel for `u (N, D)` in `[0, 1)`."""
        u = _jax_bridge.wrap_unit_np(np.asarray(u, np.float32))
        if u.ndim != 2 or u.shape[1] != self.strategy_dim:
            raise ValueError(f"u must have shape (N, {self.strategy_dim}), got {u.shape}")
        k, s = np.broadcast_to(np.asarray(k, np.int32), len(u)), np.broadcast_to(np.asarray(s, np.int32), len(u))
        parts = [
            self._trace_batch(k[a : a + self.batch_size], s[a : a + self.batch_size], u[a : a + self.batch_size])
            for a in range(0, len(u), self.batch_size)
        ]
        if not parts:
            return PathSamples(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int32))
        return PathSamples(*(np.concatenate(a) for a in zip(*parts)))

    def evaluate(self, x: np.ndarray) -> PathSamples:
        """`rgb(x) = w_s C_s / q`, `p(x)` and the pixel of points `x (N, 1 + D)` (wrapped into `[0, 1)`)."""
        if isinstance(x, jax.core.Tracer):
            raise TypeError("evaluate() needs concrete values; inside jax.jit use jax_evaluate()")
        x = np.asarray(x, np.float32)
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise ValueError(f"points must have shape (N, {self.dim}), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("points must be finite")
        x = _jax_bridge.wrap_unit_np(x)
        pair = select_pairs(x[:, 0], self.q)
        out = self.evaluate_strategies(self.pairs[0][pair], self.pairs[1][pair], x[:, 1:])
        inv_q = (1.0 / self.q[pair]).astype(np.float32)
        return PathSamples(out.rgb * inv_q[:, None], out.luminance * inv_q, out.pixel)

    def jax_evaluate(self, x: jax.Array) -> tuple[jax.Array, jax.Array]:
        """`(p (...), rgb (..., 3))` of points `x (..., 1 + D)`; works under `jit` and `vmap`."""
        return self._jax_values(x)

    def jax_evaluate_with_pixel(self, x: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """`(p, rgb, pixel)` of points `x (..., 1 + D)` from one trace; works under `jit` and `vmap`."""
        return self._jax_values_pixel(x)

    def pixel_index(self, x: jax.Array) -> jax.Array:
        """The pixel (int32) of points `x (..., 1 + D)`, by tracing them (see the module docstring)."""
        return self._jax_values_pixel(x)[2]

    # ------------------------------------------------------------------ images

    def render_uniform(self, spp: int, seed: int = 0) -> np.ndarray:
        """The plain Monte Carlo image `(H, W, 3)` from `W H spp` uniform points `x`.

        The film coordinates are stratified by pixel and `v` by `N` equal strata in random
        order (so each pair gets `q N` points up to one); `I_j = W H / N sum rgb 1{j}`.
        """
        n = self._count(spp)
        rng = np.random.default_rng(seed)
        x = np.empty((n, self.dim), np.float32)
        x[:, 0] = _strata(rng.permutation(n), rng.random(n), n)
        x[:, 1:] = self._film_stratified(rng, n)
        return self._image(self.evaluate(x), n)

    def strategy_images(self, spp: int, seed: int = 0) -> np.ndarray:
        """Images `(P, H, W, 3)` of each pair `(k, s)` alone: `W H E_u[w_s C_s(u) 1{j}]`.

        `spp` samples per pixel per pair (film stratified by pixel). Their sum over `s` is
        the depth-`k` image; their sum over all pairs the full image.
        """
        n = self._count(spp)
        rng = np.random.default_rng(seed)
        pair = np.repeat(np.arange(len(self.q)), n)
        u = self._film_stratified(rng, n * len(self.q))
        out = self.evaluate_strategies(self.pairs[0][pair], self.pairs[1][pair], u)
        images = [self._image(_subset(out, pair == i), n) for i in range(len(self.q))]
        return np.stack(images)

    def estimate_depth_pmf(self, n_per_depth: int, seed: int = 0, floor: float = 0.01) -> np.ndarray:
        """The depth pmf from `n_per_depth` uniform evaluations per depth (strategy uniform).

        Depth `k`'s mean luminance is `(k + 1)` times the mean of `luminance(w_s C_s)`
        over uniform `s` and `u`; see `_multiplex.depth_pmf` for the floor.
        """
        if isinstance(n_per_depth, bool) or not isinstance(n_per_depth, (int, np.integer)) or n_per_depth < 1:
            raise ValueError(f"n_per_depth must be a positive integer, got {n_per_depth!r}")
        rng = np.random.default_rng(seed)
        ks = np.repeat(np.arange(1, self.max_depth + 1, dtype=np.int32), n_per_depth)
        ss = np.floor(rng.random(len(ks)) * (ks + 1)).astype(np.int32)
        lum = self.evaluate_strategies(ks, ss, rng.random((len(ks), self.strategy_dim), dtype=np.float32)).luminance
        means = lum.astype(np.float64).reshape(self.max_depth, n_per_depth).mean(1) * np.arange(2, self.max_depth + 2)
        return depth_pmf(means, floor)

    def paths_per_second(self, n: int = DEFAULT_BATCH, repeats: int = 3, seed: int = 0) -> float:
        """Strategy evaluations per second of `evaluate` on uniform points (best of `repeats`)."""
        x = np.random.default_rng(seed).random((int(n), self.dim), dtype=np.float32)
        self.evaluate(x)
        best = np.inf
        for _ in range(max(1, int(repeats))):
            start = time.perf_counter()
            self.evaluate(x)
            best = min(best, time.perf_counter() - start)
        return n / best

    # ------------------------------------------------------------------ internals

    def _count(self, spp: int) -> int:
        if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
            raise ValueError(f"spp must be a positive integer, got {spp!r}")
        return self.num_pixels * int(spp)

    def _film_stratified(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """`n` uniform points of `[0, 1)^D` whose film coordinates cycle through the pixels."""
        width, height = self.resolution
        pixel = np.arange(n) % self.num_pixels
        u = rng.random((n, self.strategy_dim), dtype=np.float32)
        u[:, 0] = _strata(pixel % width, u[:, 0], width)
        u[:, 1] = _strata(pixel // width, u[:, 1], height)
        return u

    def _image(self, samples: PathSamples, n: int) -> np.ndarray:
        sums = np.stack(
            [np.bincount(samples.pixel, weights=samples.rgb[:, c], minlength=self.num_pixels) for c in range(3)], 1
        )
        width, height = self.resolution
        return (sums * (self.num_pixels / n)).reshape(height, width, 3).astype(np.float32)

    def _trace_batch(self, k: np.ndarray, s: np.ndarray, u: np.ndarray) -> PathSamples:
        import drjit as dr
        import mitsuba as mi

        n = len(u)
        columns = np.array(u.T, dtype=np.float32, order="C", copy=True).reshape(-1)  # owned by Dr.Jit below
        flat = mi.Float(columns)
        index = dr.arange(mi.UInt32, n)
        cols = [dr.gather(mi.Float, flat, index + i * n) for i in range(self.strategy_dim)]
        k_np, s_np = np.array(k, np.int32), np.array(s, np.int32)  # alive until the trace returns
        kk, ss = mi.Int32(k_np), mi.Int32(s_np)
        dr.eval(cols)
        rgb, lum, pixel = _without_gc(self._trace, self.scene, kk, ss, cols)
        return PathSamples(
            np.ascontiguousarray(np.array(rgb, dtype=np.float32).T),
            np.array(lum, dtype=np.float32),
            np.array(pixel).astype(np.int32),
        )


def _without_gc(fn: Callable[..., Any], *args: Any) -> Any:
    """`fn(*args)` with Python's cyclic garbage collector paused.

    Collecting an unreachable Mitsuba scene frees Dr.Jit memory through a host callback,
    which aborts the process ("enqueue_host_func(): this function cannot be recorded")
    if it happens while a frozen function is being recorded.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        return fn(*args)
    finally:
        if enabled:
            gc.enable()


def _strata(index: np.ndarray, jitter: np.ndarray, count: int) -> np.ndarray:
    """`(index + jitter) / count` in float32, kept below 1."""
    below_one = np.nextafter(np.float32(1), np.float32(0))
    return np.minimum((index + jitter.astype(np.float64)) / count, below_one).astype(np.float32)


def _subset(samples: PathSamples, keep: np.ndarray) -> PathSamples:
    return PathSamples(samples.rgb[keep], samples.luminance[keep], samples.pixel[keep])

