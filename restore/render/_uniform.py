"""Plain path tracing in primary sample space: the sanity baseline."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PRNGKeyArray

from .._point import Point
from ._film import empty_film, splat
from ._pss import check_target, contributions, empty_points, evaluate_points, luminance, pixels
from ._renderer import AbstractRenderer, RenderStatistics, check_lanes, ratio


class UniformParams(NamedTuple):
    lanes: Float[Array, ""]


class UniformTally(NamedTuple):
    """Sums: film of `rgb` (weight `lum` times `rgb / lum`), samples drawn, zero-luminance samples."""

    film: Float[Array, "P 3"]
    samples: Int[Array, ""]
    black: Int[Array, ""]


@dataclasses.dataclass(frozen=True)
class UniformStatistics(RenderStatistics):
    """`UniformSampler`'s diagnostics.

    Attributes:
        samples: points drawn (each one target evaluation).
        black_fraction: the fraction of them with zero luminance (paths that found no light).
    """

    samples: int
    black_fraction: float


class UniformState(NamedTuple):
    """The last batch drawn (zeros before the first step), constants and sums."""

    point: Point
    params: UniformParams
    tally: UniformTally


class UniformSampler(AbstractRenderer):
    """Independent uniform points `u`, each splatting `rgb(u)` (density 1 on the torus).

    Estimator: `I_j = W H F_j / N` with `F_j = sum rgb(u) 1{pixel(u) = j}` over `N` draws:
    `E[rgb(u) 1{pixel = j}] = ∫ rgb 1{pixel = j} du = I_j / (W H)`. Unbiased.
    """

    def init_cost(self, lanes: int) -> int:
        return 0

    def step_cost(self, lanes: int) -> int:
        return lanes

    def init(self, target, key: PRNGKeyArray, lanes: int) -> UniformState:
        check_target(target)
        lanes = check_lanes(lanes)
        point = empty_points(target, lanes)
        i0 = jnp.zeros((), jnp.int32)
        tally = UniformTally(empty_film(target.num_pixels), i0, i0)
        return UniformState(point, UniformParams(jnp.asarray(lanes, jnp.float32)), tally)

    def step(self, target, key: PRNGKeyArray, state: UniformState) -> UniformState:
        n = state.point.position.shape[0]
        point = evaluate_points(target, jax.random.uniform(key, (n * target.dim,), jnp.float32).reshape(n, target.dim))
        lum, tally = luminance(point), state.tally
        tally = UniformTally(
            film=splat(tally.film, pixels(target, point.position, point.aux), lum, contributions(point.aux)),  # = rgb
            samples=tally.samples + jnp.int32(n),
            black=tally.black + jnp.sum(lum == 0, dtype=jnp.int32),
        )
        return UniformState(point, state.params, tally)

    def scale(self, target, params: UniformParams, tally: UniformTally):
        """`W H / N`."""
        return ratio(target.num_pixels, tally.samples)

    def statistics(self, params: UniformParams, tally: UniformTally, state=None) -> UniformStatistics:
        return UniformStatistics(samples=int(tally.samples), black_fraction=float(ratio(tally.black, tally.samples)))
