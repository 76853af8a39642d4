"""`PrimarySampleSpace`: a Mitsuba scene as a density on the unit hypercube.

A point `u` of `[0, 1)^D` determines one camera path (see `_path_tracer`); its RGB
contribution `f(u)` and pixel `j(u)` define the image `I_j = W H E_uniform[f(u) 1{j(u) = j}]`,
and the target density is `p(u) = luminance(f(u))` (unnormalised). Any sampler of
`pi = p / Z` estimates the image as `I_j = W H Z E_pi[f(u) / p(u) 1{j(u) = j}]`.
The primary sample space is a torus: coordinates are taken modulo 1.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from . import _jax_bridge
from ._llvm import load_mitsuba
from ._path_tracer import dimension, make_tracers
from ._scene_checks import check_gradient_support, check_tracer_support, path_settings
from ._scenes import DEFAULT_MAX_DEPTH, load_scene

DEFAULT_BATCH = 1 << 16  # paths per Dr.Jit call (bounds memory)


class PathSamples(NamedTuple):
    """Traced paths: `rgb (N, 3)` and `luminance (N,)` float32, `pixel (N,)` int32 (`y W + x`)."""

    rgb: np.ndarray
    luminance: np.ndarray
    pixel: np.ndarray


class PrimarySampleSpace:
    """A Mitsuba scene seen as the density `p(u) = luminance(f(u))` on `[0, 1)^D`.

    Arguments:
        scene_spec: a registry name (`SCENES`), a scene dictionary, an XML path, or an
            already loaded `mi.Scene` (then `resolution` must be `None`).
        resolution: `(width, height)` override of the film.
        max_depth: Mitsuba's maximum path depth; default: the scene's `path` integrator
            depth, else 8. It fixes `dim = 2 + 6 (max_depth - 1)`.
        variant: `"llvm_ad_rgb"`, `"cuda_ad_rgb"` or `None` (CUDA if available).
        russian_roulette: stop paths as Mitsuba's `path` integrator does. Turn it off for
            gradient-based methods: roulette makes `p` discontinuous. `evaluate` and
            `evaluate_with_grad` always trace the same function.
        batch_size: the most paths traced per Dr.Jit call.

    Attributes:
        dim: the number of primary samples `D` of a path.
        resolution: the film size `(W, H)`.
        num_pixels: `W * H`.
        scene: the loaded `mi.Scene`.
        max_depth: the maximum path depth.
        rr_depth: the depth at which Russian roulette starts.
        russian_roulette: whether paths are stopped by Russian roulette.
        batch_size: the most paths traced per Dr.Jit call.

    Raises:
        UnsupportedSceneError: for a camera or film the tracer cannot reproduce.
    """

    def __init__(
        self,
        scene_spec: str | Path | Mapping[str, Any] | Any,
        *,
        resolution: tuple[int, int] | None = None,
        max_depth: int | None = None,
        variant: str | None = None,
        russian_roulette: bool = True,
        batch_size: int = DEFAULT_BATCH,
    ) -> None:
        mi = load_mitsuba(variant)
        if isinstance(scene_spec, mi.Scene):
            if resolution is not None:
                raise ValueError("resolution cannot be changed on an already loaded mi.Scene; pass its dict or file")
            scene = scene_spec
        else:
            scene = load_scene(scene_spec, resolution, max_depth)
        check_tracer_support(scene)
        settings = path_settings(scene)
        if max_depth is None:
            max_depth = settings.max_depth if settings.max_depth is not None else DEFAULT_MAX_DEPTH
        if isinstance(max_depth, bool) or not isinstance(max_depth, (int, np.integer)) or max_depth < 1:
            raise ValueError(f"max_depth must be an integer >= 1, got {max_depth!r}")
        if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
            raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")

        self.scene = scene
        self.variant: str = mi.variant()
        self.max_depth = int(max_depth)
        self.rr_depth = settings.rr_depth
        self.russian_roulette = bool(russian_roulette)
        self.dim = dimension(self.max_depth)
        width, height = (int(v) for v in scene.sensors()[0].film().crop_size())
        self.resolution = (width, height)
        self.num_pixels = width * height
        self.batch_size = int(batch_size)
        self._evaluate, self._evaluate_with_grad = make_tracers(self.max_depth, self.rr_depth, self.russian_roulette)
        self._jax_values = _jax_bridge.values_callback(self.evaluate, self.dim)
        self._jax_values_and_grad = _jax_bridge.values_and_grad_callback(self.evaluate_with_grad, self.dim)
        self._jax_log_luminance = _jax_bridge.log_luminance_fn(self._jax_values, self._jax_values_and_grad)

    def __repr__(self) -> str:
        return (
            f"PrimarySampleSpace(dim={self.dim}, resolution={self.resolution}, max_depth={self.max_depth}, "
            f"russian_roulette={self.russian_roulette}, variant={self.variant!r})"
        )

    # ------------------------------------------------------------------ NumPy interface

    def evaluate(self, u: np.ndarray) -> PathSamples:
        """Trace the paths of `u (N, D)` (wrapped into `[0, 1)`); float32 throughout."""
        u = self._points(u)
        parts = [self._trace(u[s : s + self.batch_size]) for s in range(0, len(u), self.batch_size)]
        if not parts:
            return PathSamples(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int32))
        return PathSamples(*(np.concatenate(a) for a in zip(*parts)))

    def evaluate_with_grad(self, u: np.ndarray) -> tuple[PathSamples, np.ndarray]:
        """`evaluate(u)` and `d log(luminance) / du (N, D)` (0 where the luminance is 0).

        The derivative is exact for the traced function wherever it is differentiable;
        it ignores discontinuities (visibility, BSDF lobe choice, roulette, pixel edges).
        """
        u = self._points(u)
        parts = [self._trace_grad(u[s : s + self.batch_size]) for s in range(0, len(u), self.batch_size)]
        if not parts:
            empty = PathSamples(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int32))
            return empty, np.zeros((0, self.dim), np.float32)
        samples = PathSamples(*(np.concatenate([p[0][i] for p in parts]) for i in range(3)))
        return samples, np.concatenate([p[1] for p in parts])

    def check_gradient_support(self) -> None:
        """Raise `UnsupportedSceneError` if the scene has delta lights (point, spot, directional)."""
        check_gradient_support(self.scene)

    # ------------------------------------------------------------------ JAX interface

    def jax_evaluate(self, u: jax.Array) -> tuple[jax.Array, jax.Array]:
        """`(luminance (...), rgb (..., 3))` of points `u (..., D)`; works under `jit` and `vmap`."""
        return self._jax_values(u)

    def jax_evaluate_with_grad(self, u: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """`(luminance, rgb, d log(luminance) / du)` of points `u (..., D)`; works under `jit` and `vmap`."""
        return self._jax_values_and_grad(u)

    def jax_log_density(self, u: jax.Array) -> jax.Array:
        """`log p(u)` (`-inf` where `p = 0`), differentiable with `jax.grad` (custom VJP)."""
        return self._jax_log_luminance(u)

    def pixel_index(self, u: jax.Array) -> jax.Array:
        """Pixel `y W + x` (int32) of points `u (..., D)`, in pure JAX; equals the tracer's pixel."""
        return _jax_bridge.pixel_index_jax(u, *self.resolution)

    # ------------------------------------------------------------------ rendering

    def render_uniform(self, spp: int, seed: int = 0) -> np.ndarray:
        """The plain Monte Carlo image `(H, W, 3)` from uniform primary samples.

        Every pixel gets `spp` film positions uniform within it (stratified by pixel);
        the other coordinates are uniform. `I_j = sum of rgb over the samples in j / spp`,
        i.e. `W H E_u[f(u) 1{j(u) = j}]`. Processed in batches of `batch_size` paths.
        """
        if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
            raise ValueError(f"spp must be a positive integer, got {spp!r}")
        width, height = self.resolution
        rng = np.random.default_rng(seed)
        total = self.num_pixels * int(spp)
        sums = np.zeros((self.num_pixels, 3), dtype=np.float64)
        below_one = np.nextafter(np.float32(1), np.float32(0))
        for start in range(0, total, self.batch_size):
            n = min(self.batch_size, total - start)
            pixel = (start + np.arange(n)) % self.num_pixels
            u = rng.random((n, self.dim), dtype=np.float32)
            u[:, 0] = np.minimum(((pixel % width) + u[:, 0].astype(np.float64)) / width, below_one)
            u[:, 1] = np.minimum(((pixel // width) + u[:, 1].astype(np.float64)) / height, below_one)
            samples = self.evaluate(u)
            for c in range(3):
                sums[:, c] += np.bincount(samples.pixel, weights=samples.rgb[:, c], minlength=self.num_pixels)
        return (sums / spp).reshape(height, width, 3).astype(np.float32)

    def paths_per_second(self, n: int = DEFAULT_BATCH, repeats: int = 3, seed: int = 0) -> float:
        """Paths per second of `evaluate` on uniform points (best of `repeats`, after a warm-up)."""
        u = np.random.default_rng(seed).random((int(n), self.dim), dtype=np.float32)
        self.evaluate(u)
        best = np.inf
        for _ in range(max(1, int(repeats))):
            start = time.perf_counter()
            self.evaluate(u)
            best = min(best, time.perf_counter() - start)
        return n / best

    # ------------------------------------------------------------------ internals

    def _points(self, u: Any) -> np.ndarray:
        if isinstance(u, jax.core.Tracer):
            raise TypeError("evaluate() needs concrete values; inside jax.jit use jax_evaluate()")
        u = np.asarray(u)
        if u.ndim != 2 or u.shape[1] != self.dim:
            raise ValueError(f"points must have shape (N, {self.dim}), got {u.shape}")
        u = u.astype(np.float32, copy=False)
        if u.size == 0:
            return u
        lo, hi = u.min(), u.max()
        if not (np.isfinite(lo) and np.isfinite(hi)):
            raise ValueError("points must be finite")
        if lo >= 0 and hi < 1:
            return u  # already in [0, 1): nothing to wrap (`_to_drjit` copies)
        return _jax_bridge.wrap_unit_np(u)

    def _to_drjit(self, u: np.ndarray) -> list[Any]:
        """`D` Dr.Jit arrays owning their memory (copied from `u`, which is never shared)."""
        import drjit as dr
        import mitsuba as mi

        n = len(u)
        columns = np.array(u.T, dtype=np.float32, order="C", copy=True).reshape(-1)  # never the caller's memory
        flat = mi.Float(columns)
        index = dr.arange(mi.UInt32, n)
        out = [dr.gather(mi.Float, flat, index + k * n) for k in range(self.dim)]
        dr.eval(out)
        del flat, columns
        return out

    def _trace(self, u: np.ndarray) -> PathSamples:
        rgb, lum, pixel = self._evaluate(self.scene, self._to_drjit(u))
        return _samples(rgb, lum, pixel)

    def _trace_grad(self, u: np.ndarray) -> tuple[PathSamples, np.ndarray]:
        rgb, lum, pixel, grads = self._evaluate_with_grad(self.scene, self._to_drjit(u))
        grad = np.stack([np.array(g, dtype=np.float32) for g in grads], axis=1)
        return _samples(rgb, lum, pixel), grad


def _samples(rgb: Any, lum: Any, pixel: Any) -> PathSamples:
    return PathSamples(
        np.ascontiguousarray(np.array(rgb, dtype=np.float32).T),
        np.array(lum, dtype=np.float32),
        np.array(pixel).astype(np.int32),
    )
