"""The evidence benchmark's problems: targets with an exact `log Z` that no sampler can guess, and their boxes."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .._observables import position, square
from ._problems import BuiltTarget


class EvidenceReference(NamedTuple):
    """Exact answers a run is scored against (NumPy, float64)."""

    log_z: float  # log ∫ exp(problem.logdensity)
    mean: np.ndarray  # (d,)
    second_moment: np.ndarray  # (d,) E[x_i^2]
    sd: np.ndarray  # (d,) marginal standard deviations, the unit of the moment errors
    positive_probability: float | None  # Many Well: P(x_{2i} > 0); None elsewhere
    outside_share: float  # share of exact draws outside the box (the mass a box-bound method cannot see)


@dataclass(frozen=True, eq=False)
class EvidenceProblem(BuiltTarget):
    """A target, a known offset added to its log density, and the box a user would state.

    The log density every method sees is `target.logdensity(x) + offset`, so its exact
    `log Z` is `target.log_normalising_constant + offset`: never 0, and not the value of
    any published normalised form. The box `[-half_widths, half_widths]` is "what the user
    knows": the nested sampler's uniform prior, tempered SMC's prior and the region of
    Restore's uniform starts. It holds all but a negligible share of the mass
    (`EvidenceReference.outside_share` measures it on exact draws).

    Attributes:
        name: short name, e.g. `"manywell32"`.
        title: one line for the report.
        make_target: builds the analytic target (called once).
        offset: added to the target's log density.
        half_widths: one value for every coordinate, or one per coordinate.
        hmc_steps: leapfrog steps of tempered SMC's HMC moves.
    """

    name: str
    title: str
    make_target: Callable[[], object] = field(repr=False)
    offset: float
    half_widths: tuple[float, ...]
    hmc_steps: int = 10

    @functools.cached_property
    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """`(lower, upper)`, each of shape `(d,)`."""
        widths = np.broadcast_to(np.asarray(self.half_widths, np.float64), (self.dim,)).copy()
        return -widths, widths

    @property
    def log_box_volume(self) -> float:
        lower, upper = self.box
        return float(np.sum(np.log(upper - lower)))

    @property
    def log_normalising_constant(self) -> float:
        """The exact `log ∫ exp(logdensity)`."""
        return float(self.target.log_normalising_constant) + self.offset

    @functools.cached_property
    def logdensity(self) -> Callable[[Float[Array, " d"]], Float[Array, ""]]:
        """`target.logdensity + offset`, one function object so that compiled programs are reused."""
        target, offset = self.target, self.offset
        return lambda x: target.logdensity(x) + offset

    @property
    def has_wells(self) -> bool:
        """Whether the problem reports the right-well probability `P(x_{2i} > 0)` (Many Well)."""
        return hasattr(self.target, "positive_probability")

    @functools.cached_property
    def observables(self) -> dict[str, Callable[[Array], Array]]:
        """Streamed observables: `x`, `x**2` and, for Many Well, the share of pairs in the right well."""
        obs: dict[str, Callable[[Array], Array]] = {"x": position, "x**2": square}
        if self.has_wells:
            obs["positive"] = _right_well_share
        return obs

    def reference(self, key: PRNGKeyArray, num_draws: int = 65536) -> EvidenceReference:
        """Exact answers, and the share of `num_draws` exact draws that fall outside the box."""
        t = self.target
        mean = np.asarray(t.mean, np.float64)
        var = np.diag(np.asarray(t.covariance, np.float64))
        draws = np.asarray(t.sample(key, int(num_draws)), np.float64)
        lower, upper = self.box
        outside = float(np.mean(np.any((draws < lower) | (draws > upper), axis=1)))
        return EvidenceReference(
            log_z=self.log_normalising_constant,
            mean=mean,
            second_moment=var + mean**2,
            sd=np.sqrt(var),
            positive_probability=float(t.positive_probability) if self.has_wells else None,
            outside_share=outside,
        )

    def uniform_points(self, key: PRNGKeyArray, n: int) -> Array:
        """`n` points uniform in the box, shape `(n, d)`."""
        lower, upper = self.box
        return jax.random.uniform(key, (int(n), self.dim), minval=jnp.asarray(lower), maxval=jnp.asarray(upper))


def _right_well_share(x: Array) -> Array:
    return jnp.mean((x[0::2] > 0).astype(x.dtype))


def _many_well():
    from targets.analytic import ManyWell

    return ManyWell(32)


def _spread_mixture():
    from targets.analytic import spread_gaussian_mixture

    return spread_gaussian_mixture(2, 40, half_width=40.0)


def _funnel():
    from targets.analytic import Funnel

    return Funnel(10, scale=3.0)


def _rotated_gaussian():
    """50-d, variances 1e-2 .. 1e2 along random orthogonal directions, mean uniform in [-3, 3]^50."""
    from targets.analytic import GaussianMixture, random_rotation

    d = 50
    q = random_rotation(d, 11)
    covariance = q @ np.diag(np.logspace(-2, 2, d)) @ q.T
    mean = np.random.default_rng(12).uniform(-3, 3, d)
    return GaussianMixture(mean[None], covariance[None])


def _rotated_many_well():
    from targets.analytic import ManyWell, Rotated, random_rotation

    return Rotated(ManyWell(16), random_rotation(16, 21))


def _banana():
    from targets.analytic import Banana

    return Banana(10, curvature=0.1, scale=10.0)


EVIDENCE_PROBLEMS: dict[str, EvidenceProblem] = {
    p.name: p
    for p in (
        EvidenceProblem(
            "manywell32", "32-d Many Well (16 double-well pairs, 2^16 modes), unnormalised literature form",
            _many_well, offset=0.0, half_widths=(5.0,),
        ),
        EvidenceProblem(
            "gmm40", "2-d mixture of 40 unit Gaussians, means uniform in [-40, 40]^2, log density shifted by -12.4",
            _spread_mixture, offset=-12.4, half_widths=(50.0,),
        ),
        EvidenceProblem(
            "funnel10", "10-d Neal's funnel (scale 3), log density shifted by +3.7",
            _funnel, offset=3.7, half_widths=(15.0,) + (300.0,) * 9,
        ),
        EvidenceProblem(
            "gauss50r", "50-d Gaussian, condition number 1e4, random orthogonal directions, log density shifted by +2.5",
            _rotated_gaussian, offset=2.5, half_widths=(40.0,),
        ),
        EvidenceProblem(
            "manywell16r", "16-d Many Well (8 double-well pairs, 256 modes) under a random rotation",
            _rotated_many_well, offset=0.0, half_widths=(8.0,),
        ),
        EvidenceProblem(
            "banana10", "10-d banana (Haario's twisted Gaussian, b = 0.1, scale 10), log density shifted by -1.3",
            _banana, offset=-1.3, half_widths=(50.0, 150.0) + (50.0,) * 8,
        ),
    )
}
"""The registered evidence problems by name: `manywell32`, `gmm40`, `funnel10`, and the geometry classes
`gauss50r` (ill-conditioned and correlated), `manywell16r` (multimodal along turned axes), `banana10` (curved)."""


def get_evidence_problem(name: str) -> EvidenceProblem:
    """The registered evidence problem `name`; raises `ValueError` listing the names on a miss."""
    try:
        return EVIDENCE_PROBLEMS[name]
    except KeyError:
        raise ValueError(f"unknown evidence problem {name!r}; choose from {sorted(EVIDENCE_PROBLEMS)}") from None

