"""The registry of named benchmark problems: a target, its exact answers and per-problem tuning."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ._mmd import median_bandwidth


class Reference(NamedTuple):
    """Exact answers a sampler's output is compared against (numpy, float64)."""

    mode_weights: np.ndarray | None  # (k,) for mixtures (mode assignment by `assign_mode`), else None
    mean: np.ndarray  # (d,)
    second_moment: np.ndarray  # (d,) E[x_i^2]
    sd: np.ndarray  # (d,) marginal standard deviations, the unit of the moment errors
    draws: np.ndarray  # (n, d) exact independent draws for the distributional distance
    bandwidth: float  # Gaussian-kernel bandwidth, median heuristic on `draws`


class BuiltTarget:
    """The analytic target of a problem, built once from its `make_target`, and its dimension."""

    make_target: Callable[[], object]

    @functools.cached_property
    def target(self):
        """The analytic target (built once)."""
        return self.make_target()

    @property
    def dim(self) -> int:
        return int(self.target.dim)


@dataclass(frozen=True, eq=False)
class Problem(BuiltTarget):
    """One benchmark problem: a target with exact reference quantities and the tuning every sampler gets.

    The local-kernel parameters are fixed by hand per problem (documented in the results
    page) and shared: jump Restore, the MH baselines and BlackJAX RMH use the same
    random-walk scale. Starting points for mode finding are `start_scale * N(0, I)`.
    """

    name: str
    title: str
    make_target: Callable[[], object] = field(repr=False)
    start_scale: float
    rw_scale: float
    mala_step: float
    hmc_step: float
    hmc_steps: int
    num_starts: int = 64
    tour_length: float = 10.0

    @property
    def multimodal(self) -> bool:
        return hasattr(self.target, "assign_mode") and self.target.num_modes > 1

    @property
    def logdensity(self) -> Callable[[Float[Array, " d"]], Float[Array, ""]]:
        return self.target.logdensity

    @functools.cached_property
    def observables(self) -> dict[str, Callable[[Array], Array]]:
        """Streamed observables, built once so that compiled programs are reused across runs."""
        obs: dict[str, Callable[[Array], Array]] = {"x": _identity, "x**2": _square}
        if self.multimodal:
            target, k = self.target, self.target.num_modes
            obs["modes"] = lambda x: jax.nn.one_hot(target.assign_mode(x), k, dtype=x.dtype)
        return obs

    @functools.cached_property
    def batched_logdensity(self) -> Callable[[Array], Array]:
        """`jit(vmap(logdensity))`: what emcee calls and what raw throughput is measured on."""
        return jax.jit(jax.vmap(self.target.logdensity))

    @functools.cached_property
    def batched_assign_mode(self) -> Callable[[Array], Array]:
        """`jit(vmap(assign_mode))` for scoring draws of samplers that do not stream observables."""
        return jax.jit(jax.vmap(self.target.assign_mode))

    def mode_counts(self, draws: np.ndarray, block: int = 16384) -> np.ndarray:
        """How many of `draws` (n, d) `assign_mode` gives to each mode.

        Draws go through `jit(vmap(assign_mode))` in zero-padded blocks of one fixed
        size, so any number of draws costs one compilation per problem.
        """
        draws = np.asarray(draws, np.float64).reshape(-1, self.dim)
        k = self.target.num_modes
        counts = np.zeros(k)
        for i in range(0, len(draws), block):
            part = draws[i : i + block]
            padded = np.zeros((block, self.dim))
            padded[: len(part)] = part
            idx = np.asarray(self.batched_assign_mode(jnp.asarray(padded)))[: len(part)]
            counts += np.bincount(idx, minlength=k)
        return counts

    def reference(self, key: PRNGKeyArray, num_draws: int) -> Reference:
        """Exact reference quantities and `num_draws` exact draws (with their median-heuristic bandwidth)."""
        t = self.target
        cov = np.asarray(t.covariance, np.float64)
        mean = np.asarray(t.mean, np.float64)
        draws = np.asarray(t.sample(key, int(num_draws)), np.float64)
        return Reference(
            mode_weights=np.asarray(t.weights, np.float64) if self.multimodal else None,
            mean=mean,
            second_moment=np.diag(cov) + mean**2,
            sd=np.sqrt(np.diag(cov)),
            draws=draws,
            bandwidth=median_bandwidth(draws),
        )


def _identity(x: Array) -> Array:
    return x


def _square(x: Array) -> Array:
    return x**2


def _gaussian_control(dim: int):
    """A correlated unimodal Gaussian: random rotation, variances log-spaced in [1/3, 3]."""
    from targets.analytic import GaussianMixture

    rng = np.random.default_rng(20240611)
    q, r = np.linalg.qr(rng.standard_normal((dim, dim)))
    q = q * np.sign(np.diag(r))
    cov = (q * np.logspace(-np.log10(3.0), np.log10(3.0), dim)) @ q.T
    return GaussianMixture(jnp.zeros((1, dim)), jnp.asarray(0.5 * (cov + cov.T))[None])


def _gmm(dim: int):
    from targets.analytic import well_separated_gaussian_mixture

    return well_separated_gaussian_mixture(dim, 3, separation=8.0)


def _tmix(dim: int):
    from targets.analytic import well_separated_student_t_mixture

    return well_separated_student_t_mixture(dim, 3, separation=10.0, df=5.0)


def _banana():
    from targets.analytic import Banana

    return Banana(2, curvature=0.1, scale=10.0)


def _funnel():
    from targets.analytic import Funnel

    return Funnel(5, scale=1.5)


def _mixture_tuning(dim: int) -> dict:
    # Unit-scale components: optimal-scaling rules for a standard Gaussian in `dim` dimensions.
    return dict(rw_scale=2.38 / np.sqrt(dim), mala_step=0.8 * dim ** (-1 / 3), hmc_step=0.9 * dim ** (-1 / 4), hmc_steps=5)


PROBLEMS: dict[str, Problem] = {
    p.name: p
    for p in (
        Problem("gmm2", "2-d mixture of 3 Gaussians, weights 1/6, 2/6, 3/6", functools.partial(_gmm, 2), 6.0, **_mixture_tuning(2)),
        Problem("gmm10", "10-d mixture of 3 Gaussians, weights 1/6, 2/6, 3/6", functools.partial(_gmm, 10), 6.0, **_mixture_tuning(10)),
        Problem("gmm50", "50-d mixture of 3 Gaussians, weights 1/6, 2/6, 3/6", functools.partial(_gmm, 50), 6.0, **_mixture_tuning(50)),
        Problem("tmix5", "5-d mixture of 3 Student-t (df 5), weights 1/6, 2/6, 3/6", functools.partial(_tmix, 5), 6.0, **_mixture_tuning(5)),
        Problem("banana2", "2-d banana (Haario, b = 0.1, scale 10)", _banana, 10.0, rw_scale=1.0, mala_step=0.2, hmc_step=0.25, hmc_steps=10),
        Problem("funnel5", "5-d Neal's funnel (scale 1.5)", _funnel, 2.0, rw_scale=0.5, mala_step=0.05, hmc_step=0.1, hmc_steps=10),
        Problem("gauss10", "10-d correlated Gaussian (unimodal control)", functools.partial(_gaussian_control, 10), 6.0, **_mixture_tuning(10)),
    )
}
"""The registered problems by name: `gmm2`, `gmm10`, `gmm50`, `tmix5`, `banana2`, `funnel5`, `gauss10`."""


def get_problem(name: str) -> Problem:
    """The registered problem `name`; raises `ValueError` listing the names on a miss."""
    try:
        return PROBLEMS[name]
    except KeyError:
        raise ValueError(f"unknown problem {name!r}; choose from {sorted(PROBLEMS)}") from None
