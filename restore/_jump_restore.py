"""Jump Restore: a pi-invariant Markov kernel embedded in continuous time, killed and regenerated."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from ._point import Point, evaluate
from ._rate import (
    PilotEstimate,
    check_finite,
    check_positive,
    kill_log_probability,
    log_kill_rate,
    log_total_rate,
    pilot_log_z,
)
from ._validation import check_parts, check_position
from .local import AbstractLocalKernel
from .regeneration import AbstractRegeneration


class JumpRestoreState(NamedTuple):
    """State of one jump-Restore lane.

    Attributes:
        position: current state `x`.
        logdensity: `log p(x)` (`-inf` for zero density).
        logdensity_grad: gradient of `log p` at `x`, or `None` if the kernel needs none.
        log_kill_rate: `log gamma(x) = log c_tilde + log u(x) - log p(x)`.
    """

    position: Float[Array, " d"]
    logdensity: Float[Array, ""]
    logdensity_grad: Float[Array, " d"] | None
    log_kill_rate: Float[Array, ""]


class JumpRestoreInfo(NamedTuple):
    """What one step did, for the state held *before* the step.

    Attributes:
        holding_time: sampled holding time `Exp(r + gamma(x))`.
        expected_holding_time: its mean `1 / (r + gamma(x))` (Rao-Blackwellised weight).
        regenerated: the tour ended: the next state is a fresh draw of the regeneration.
        accepted: a local move was proposed and accepted.
        acceptance_probability: of the local move (0 when the tour ended).
        invalid: the new evaluation returned NaN or `+inf` (treated as zero density).
        uncovered: the new state has positive target density but zero regeneration
            density, so it can never be killed (a sign of a too-narrow regeneration).
        log_importance_weight: `log p(y) - log u(y)` of the regeneration draw `y`
            (`-inf` when the tour did not end): the importance-sampling estimate of `Z`
            comes free with the run.
    """

    holding_time: Float[Array, ""]
    expected_holding_time: Float[Array, ""]
    regenerated: Bool[Array, ""]
    accepted: Bool[Array, ""]
    acceptance_probability: Float[Array, ""]
    invalid: Bool[Array, ""]
    uncovered: Bool[Array, ""]
    log_importance_weight: Float[Array, ""]


class JumpRestore(eqx.Module):
    """Jump Restore sampler (Algorithm 7.1 of the seed paper), one lane at a time.

    Local dynamics: the Markov kernel `local`, embedded in continuous time at rate
    `local_rate` (exponential holding times). Killing: at rate
    `gamma(x) = c_tilde * u(x) / p(x)`, where `u` is the density of `regeneration`; a
    killed tour restarts at a fresh draw of `regeneration`. The state at any fixed time
    is distributed as the target once it was. Each step costs one new density
    evaluation (plus the kernel's internal ones, e.g. HMC's trajectory), shared between
    the local candidate and the regeneration draw.

    Give exactly one of `log_rate` (`log c_tilde`, the raw constant) or `tour_length`
    (the mean tour duration `T = 1/c`, in units of local-move time). A tour length is
    turned into `log c_tilde = log Z_hat - log T` by `calibrate` with an importance
    sampling pilot estimate of the normalising constant `Z`; `restore.sample` does it
    for you and reports the pilot.

    Arguments:
        logdensity: unnormalised log density of one point `(d,)`, returning a scalar.
            NaN or `+inf` values are treated as zero density and counted.
        local: the local kernel, e.g. `restore.local.RandomWalk(0.5)`.
        regeneration: the regeneration distribution `nu`, e.g.
            `restore.regeneration.laplace_mixture(logdensity, starts)`.
        log_rate: `log c_tilde`.
        tour_length: mean tour duration `T > 0`.
        local_rate: rate `r > 0` of local moves (default 1).
        pilot_size: number of regeneration draws of the pilot estimate of `Z`.
    """

    logdensity: Callable[[Array], Array]
    local: AbstractLocalKernel
    regeneration: AbstractRegeneration
    log_rate: Float[Array, ""] | None
    tour_length: float | None = eqx.field(static=True)
    local_rate: float = eqx.field(static=True)
    pilot_size: int = eqx.field(static=True)
    pilot: PilotEstimate | None = eqx.field(static=True)

    is_regenerative: ClassVar[bool] = True

    def __init__(
        self,
        logdensity: Callable[[Array], Array],
        local: AbstractLocalKernel,
        regeneration: AbstractRegeneration,
        *,
        log_rate: float | None = None,
        tour_length: float | None = None,
        local_rate: float = 1.0,
        pilot_size: int = 4096,
        pilot: PilotEstimate | None = None,
    ):
        if (log_rate is None) == (tour_length is None):
            raise ValueError("give exactly one of log_rate (log c_tilde) or tour_length (mean tour duration)")
        check_parts(logdensity, local, regeneration)
        self.logdensity = logdensity
        self.local = local
        self.regeneration = regeneration
        self.log_rate = check_finite(log_rate, "log_rate")
        self.tour_length = check_positive(tour_length, "tour_length")
        self.local_rate = check_positive(local_rate, "local_rate")
        if int(pilot_size) != pilot_size or pilot_size < 2:
            raise ValueError(f"pilot_size must be an integer >= 2, got {pilot_size!r}")
        self.pilot_size = int(pilot_size)
        self.pilot = pilot

    @property
    def dim(self) -> int:
        return self.regeneration.dim

    def calibrate(self, key: PRNGKeyArray) -> JumpRestore:
        """Return a copy with `log_rate` set from `tour_length` by a pilot estimate of `Z`.

        A sampler that already has a `log_rate` is returned unchanged.
        """
        if self.log_rate is not None:
            return self
        pilot = pilot_log_z(key, self.logdensity, self.regeneration, self.pilot_size)
        return JumpRestore(
            self.logdensity,
            self.local,
            self.regeneration,
            log_rate=pilot.log_z - math.log(self.tour_length),
            local_rate=self.local_rate,
            pilot_size=self.pilot_size,
            pilot=pilot,
        )

    def _require_rate(self) -> Array:
        if self.log_rate is None:
            raise ValueError(
                "this sampler has a tour_length but no log_rate yet: call sampler.calibrate(key) "
                "first (restore.sample does it for you)"
            )
        return self.log_rate

    def _state(self, point: Point, log_rate: Array) -> JumpRestoreState:
        log_u = self.regeneration.log_prob(point.position)
        return JumpRestoreState(point.position, point.logdensity, point.grad, log_kill_rate(log_rate, log_u, point.logdensity))

    def init(self, key: PRNGKeyArray, position: Array | None = None) -> JumpRestoreState:
        """Start a lane at `position`, or at a draw of the regeneration distribution (a tour start)."""
        log_rate = self._require_rate()
        if position is None:
            position = self.regeneration.sample(key)
        else:
            position = check_position(position, self.dim)
        point, _ = evaluate(self.logdensity, position, self.local.uses_gradient)
        return self._state(point, log_rate)

    def step(self, key: PRNGKeyArray, state: JumpRestoreState) -> tuple[JumpRestoreState, JumpRestoreInfo]:
        """Hold the current state for an exponential time, then move locally or regenerate."""
        log_rate = self._require_rate()
        k_event, k_hold, k_propose, k_accept, k_regen = jax.random.split(key, 5)
        dtype = state.logdensity.dtype
        log_r = jnp.log(jnp.asarray(self.local_rate, dtype))
        log_gamma = state.log_kill_rate

        killed = jnp.log(jax.random.uniform(k_event, dtype=dtype)) < kill_log_probability(log_gamma, log_r)
        mean_hold = jnp.exp(-log_total_rate(log_gamma, log_r))
        hold = jax.random.exponential(k_hold, dtype=dtype) * mean_hold

        point = Point(state.position, state.logdensity, state.logdensity_grad)
        candidate, aux = self.local.propose(k_propose, point, self.logdensity)
        fresh = self.regeneration.sample(k_regen).astype(candidate.dtype)
        evaluated, invalid = evaluate(self.logdensity, jnp.where(killed, fresh, candidate), self.local.uses_gradient)
        moved, local_info = self.local.accept(k_accept, point, evaluated, aux)
        new_point = jax.tree.map(lambda a, b: jnp.where(killed, a, b), evaluated, moved)

        log_u = self.regeneration.log_prob(new_point.position)
        new_state = JumpRestoreState(
            new_point.position, new_point.logdensity, new_point.grad, log_kill_rate(log_rate, log_u, new_point.logdensity)
        )
        uncovered = (log_u == -jnp.inf) & jnp.isfinite(new_point.logdensity)
        log_weight = jnp.where(killed, new_point.logdensity - log_u, -jnp.inf)
        log_weight = jnp.where(jnp.isnan(log_weight), -jnp.inf, log_weight)
        info = JumpRestoreInfo(
            holding_time=hold,
            expected_holding_time=mean_hold,
            regenerated=killed,
            accepted=local_info.accepted & ~killed,
            acceptance_probability=jnp.where(killed, 0.0, local_info.acceptance_probability).astype(dtype),
            invalid=invalid,
            uncovered=uncovered,
            log_importance_weight=log_weight,
        )
        return new_state, info
