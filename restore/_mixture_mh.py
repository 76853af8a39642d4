"""The Metropolis-Hastings baseline with a mixture of small (local) and large (independent) steps."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._parts import check_parts
from ._point import Point
from ._sampler import AbstractSampler, StepInfo
from ._sparse_draws import draw_slots, draw_where
from ._validation import check_point
from .local import AbstractLocalKernel
from .local._base import metropolis_accept
from .regeneration import AbstractRegeneration


class MixtureMHState(NamedTuple):
    """State of one MH lane: the point (the target's log density and, for gradient kernels, its
    gradient; the local kernel's `geometry` where it keeps one)."""

    position: Float[Array, " d"]
    logdensity: Float[Array, ""]
    logdensity_grad: Float[Array, " d"] | None
    geometry: Any = None


class _LargeStep(NamedTuple):
    """What a large step needs beyond the target: a fresh draw `y ~ nu`, `log u(y)` and
    `log u(x)` at the lane's current position (computed where the step is taken, not kept
    in the state: a tenth of the lanes or fewer need them)."""

    fresh: Float[Array, " d"]
    log_u_fresh: Float[Array, ""]
    log_u_current: Float[Array, ""]


class MixtureMH(AbstractSampler):
    """Metropolis-Hastings with a mixture of local moves and independent large steps.

    With probability `large_step_probability` the step proposes a fresh draw `y ~ nu`
    and accepts it with probability `min(1, p(y) u(x) / (p(x) u(y)))`; otherwise it makes
    one move of the local kernel. Both kernels leave the target invariant, so their
    mixture does. This is the chain that jump Restore is compared with when both use the
    same local kernel and `nu` (the paper's section 6.1: MH tours end at accepted large
    steps). Each step costs one new density evaluation, like a jump-Restore step. Its lanes
    start at draws of `nu` with no burn-in: its (lane-based) estimates are marked unreliable
    while the two halves of the lanes' runs show that they have not forgotten their start.

    Arguments:
        logdensity: unnormalised log density of one point `(d,)`.
        local: the local (small-step) kernel.
        regeneration: the large-step distribution `nu`.
        large_step_probability: probability in `[0, 1]` of a large step.
    """

    logdensity: Callable[[Array], Array]
    local: AbstractLocalKernel
    regeneration: AbstractRegeneration
    large_step_probability: Float[Array, ""]
    _large_share: float = eqx.field(static=True)

    has_tours: ClassVar[bool] = False

    def __init__(self, logdensity, local, regeneration, large_step_probability: float = 0.1):
        message = f"large_step_probability must be a number in [0, 1], got {large_step_probability!r}"
        if isinstance(large_step_probability, (bool, str, bytes)) or large_step_probability is None:
            raise TypeError(message)
        try:
            q = float(large_step_probability)
        except (TypeError, ValueError) as err:
            raise TypeError(message) from err
        if not 0.0 <= q <= 1.0:
            raise ValueError(f"large_step_probability must be in [0, 1], got {large_step_probability!r}")
        check_parts(logdensity, local, regeneration)
        self.logdensity = logdensity
        self.local = local
        self.regeneration = regeneration
        self.large_step_probability = jnp.asarray(q)
        self._large_share = q

    @property
    def dim(self) -> int:
        return self.regeneration.dim

    @property
    def dtype(self) -> jnp.dtype:
        """The floating dtype of the chain: that of the regeneration distribution's draws (see
        `JumpRestore.dtype`)."""
        return jax.eval_shape(self.regeneration.sample, jax.random.key(0)).dtype

    def init(self, key: PRNGKeyArray, position: Array | None = None) -> MixtureMHState:
        """Start a chain at `position`, or at a draw of `nu` (the same start information as Restore)."""
        if position is None:
            position = self.regeneration.sample(key)
        else:
            position = check_point(position, self.dim, "position", finite=True)
        position = position.astype(self.dtype)
        point, _ = self.local.evaluate_point(self.logdensity, position)
        return MixtureMHState(point.position, point.logdensity, point.grad, point.geometry)

    def step_lanes(self, keys: PRNGKeyArray, states: MixtureMHState) -> tuple[MixtureMHState, StepInfo]:
        """`vmap(step)`, with the large-step draw and densities computed only for the lanes that take a large step."""
        slots = draw_slots(keys.shape[0], self._large_share)
        if slots is None:
            return super().step_lanes(keys, states)

        def decide(key, state):
            k_choice, _, _, k_regen = jax.random.split(key, 4)
            return self._large(k_choice, state), k_regen

        large, regen_keys = jax.vmap(decide)(keys, states)
        dim = self.dim
        packed = draw_where(lambda k, x: _pack(self._large_step(k, x)), large, slots, regen_keys, states.position)
        prepared = _LargeStep(packed[:, :dim], packed[:, dim], packed[:, dim + 1])
        return jax.vmap(self.step)(keys, states, prepared, large)

    def _large(self, key: PRNGKeyArray, state: MixtureMHState) -> Array:
        return jax.random.uniform(key, dtype=state.logdensity.dtype) < self.large_step_probability

    def _large_step(self, key: PRNGKeyArray, position: Array) -> _LargeStep:
        fresh = self.regeneration.sample(key).astype(position.dtype)
        log_u = jax.vmap(self.regeneration.log_prob)(jnp.stack([fresh, position])).astype(position.dtype)
        return _LargeStep(fresh, log_u[0], log_u[1])  # one traced density: a shorter compilation

    def step(
        self,
        key: PRNGKeyArray,
        state: MixtureMHState,
        prepared: _LargeStep | None = None,
        large: Array | None = None,
    ) -> tuple[MixtureMHState, StepInfo]:
        """One MH step: a large step with probability `q`, else a local move.

        `large` (whether this is a large step) and `prepared` (its fresh draw and the two
        regeneration densities) may be computed beforehand from this step's key, as the step
        would compute them: `step_lanes` decides for all lanes at once and prepares the large
        step only for the lanes that take one.
        """
        k_choice, k_propose, k_accept, k_regen = jax.random.split(key, 4)
        dtype = state.logdensity.dtype
        if large is None:
            large = self._large(k_choice, state)

        point = Point(state.position, state.logdensity, state.logdensity_grad, None, state.geometry)
        candidate, aux = self.local.propose(k_propose, point, self.logdensity)
        candidate = candidate.astype(state.position.dtype)
        if prepared is None:
            prepared = self._large_step(k_regen, state.position)
        evaluated, invalid = self.local.evaluate_point(self.logdensity, jnp.where(large, prepared.fresh, candidate))

        local_point, local_info = self.local.accept(k_accept, point, evaluated, aux)
        log_ratio = evaluated.logdensity - state.logdensity + prepared.log_u_current - prepared.log_u_fresh
        global_point, global_info = metropolis_accept(k_accept, point, evaluated, log_ratio)

        new_point = jax.tree.map(lambda a, b: jnp.where(large, a, b), global_point, local_point)
        accepted = jnp.where(large, global_info.accepted, local_info.accepted)
        one, no = jnp.ones((), dtype), jnp.zeros((), bool)
        info = StepInfo(
            position=state.position,
            holding_time=one,
            expected_holding_time=one,
            regenerated=no,
            accepted=accepted,
            acceptance_probability=jnp.where(
                large, global_info.acceptance_probability, local_info.acceptance_probability
            ).astype(dtype),
            invalid=invalid,
            uncovered=no,
            log_importance_weight=jnp.full((), -jnp.inf, dtype),
            start_drawn=no,
            negative_rate=no,
            bound_ratio=jnp.zeros((), dtype),
        )
        return MixtureMHState(new_point.position, new_point.logdensity, new_point.grad, new_point.geometry), info


def _pack(step: _LargeStep) -> Array:
    """One array `(d + 2,)` (what `draw_where` gathers and puts back)."""
    return jnp.concatenate([step.fresh, step.log_u_fresh[None], step.log_u_current[None]])
