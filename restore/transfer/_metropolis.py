"""Random-walk Metropolis steps targeting the reference: any regeneration distribution, started at the exit."""

from __future__ import annotations

from typing import ClassVar, final

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import as_scale, check_integer, check_point, check_vector_dim
from ..regeneration import AbstractRegeneration
from ._base import AbstractTransfer


@final
class MetropolisTransfer(AbstractTransfer):
    """`num_steps` random-walk Metropolis steps targeting the reference, started at the exit point.

    Each step proposes `x' = x + scale * N(0, I)` and accepts it with probability
    `min(1, q(x') / q(x))`. Metropolis steps leave `q` invariant, so this turns any
    regeneration distribution `q` (it only needs `log_prob`) into an exit-dependent
    transfer whose next tour starts near the exit point; small `scale` and few steps keep
    it close. The kernel has an atom at the exit point (all proposals rejected), so it has
    no transition density.

    Arguments:
        reference: the invariant distribution `q`, any `restore.regeneration` distribution.
        scale: the proposal standard deviation, a positive scalar or one per coordinate
            `(d,)`; sets how far one step moves.
        num_steps: the number of Metropolis steps per transfer, a positive int (static);
            more steps forget more of the exit point.

    Raises:
        TypeError: if `reference` is not a `restore.regeneration` distribution, or
            `scale` or `num_steps` is not a number.
        ValueError: for a scale that is not positive and finite or has the wrong shape,
            or a `num_steps` that is not a positive integer.
    """

    reference: AbstractRegeneration
    scale: Float[Array, "*d"]
    num_steps: int = eqx.field(static=True)
    is_independent: ClassVar[bool] = False

    def __init__(self, reference: AbstractRegeneration, scale: ArrayLike, num_steps: int = 1):
        if not isinstance(reference, AbstractRegeneration):
            raise TypeError(f"reference must be a restore.regeneration distribution, got {type(reference).__name__}")
        scale = as_scale(scale, "MetropolisTransfer scale")
        check_vector_dim(scale, reference.dim, "MetropolisTransfer scale")
        self.reference = reference
        self.scale = scale
        self.num_steps = check_integer(num_steps, "num_steps")

    def sample(self, key: PRNGKeyArray, exit_position: Float[Array, " d"]) -> Float[Array, " d"]:
        """The point after `num_steps` Metropolis steps from the exit point, in its dtype.

        A proposal of zero reference density is always rejected; from an exit point of
        zero density (outside the support), any proposal of positive density is accepted.
        """
        x0 = check_point(exit_position, self.dim, "exit_position")
        dtype = x0.dtype
        log_q0 = jnp.asarray(self.reference.log_prob(x0))
        log_dtype = log_q0.dtype

        def step(key: PRNGKeyArray, x: Array, log_q: Array) -> tuple[Array, Array]:
            key_move, key_accept = jax.random.split(key)
            proposal = (x + self.scale * jax.random.normal(key_move, x.shape, dtype)).astype(dtype)
            log_q_new = jnp.asarray(self.reference.log_prob(proposal)).astype(log_dtype)
            log_ratio = log_q_new - log_q
            log_ratio = jnp.where(jnp.isnan(log_ratio) | (log_q_new == -jnp.inf), -jnp.inf, log_ratio)
            accept = jnp.log(jax.random.uniform(key_accept, dtype=log_dtype)) < log_ratio
            return jnp.where(accept, proposal, x), jnp.where(accept, log_q_new, log_q)

        if self.num_steps == 1:
            x, _ = step(key, x0, log_q0)
            return x
        keys = jax.random.split(key, self.num_steps)

        def body(i: Array, carry: tuple[Array, Array]) -> tuple[Array, Array]:
            return step(keys[i], *carry)

        x, _ = jax.lax.fori_loop(0, self.num_steps, body, (x0, log_q0))
        return x
