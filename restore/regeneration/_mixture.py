"""Finite mixtures of regeneration distributions."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import as_float_array, check_point, check_shape, is_concrete
from ._base import AbstractRegeneration


def _stack(components: tuple[AbstractRegeneration, ...]) -> AbstractRegeneration | None:
    """Stack identically structured components into one batched module.

    Returns `None` unless all components have the same pytree structure
    (same class and static fields) and array leaves of equal shape and dtype.
    """
    treedefs = [jax.tree_util.tree_structure(c) for c in components]
    if len(set(treedefs)) > 1:
        return None
    leaves = [jax.tree_util.tree_leaves(c) for c in components]
    for leaf_group in zip(*leaves):
        if not all(eqx.is_array(leaf) for leaf in leaf_group):
            return None
        if any(
            (leaf.shape, leaf.dtype) != (leaf_group[0].shape, leaf_group[0].dtype)
            for leaf in leaf_group
        ):
            return None
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *components)


@final
class Mixture(AbstractRegeneration):
    """Finite mixture `sum_k w_k p_k` of regeneration distributions.

    Components may be of different types (e.g. a `Gaussian` and a `StudentT`)
    but must share the dimension. When all components have the same structure
    (same class and parameter shapes) they are stacked and evaluated with one
    `vmap`, and sampling draws only from the selected component per point;
    otherwise every component draws a full batch and the selected draw is kept.
    Both paths are exact and work under `jit`/`vmap`.

    Attributes:
        components: the mixture components.
        log_weights: normalised log mixture weights, shape `(k,)`.
        dim: the common dimension `d` (static).
    """

    components: tuple[AbstractRegeneration, ...]
    log_weights: Float[Array, " k"]
    dim: int = eqx.field(static=True)

    def __init__(
        self,
        components: Sequence[AbstractRegeneration],
        weights: ArrayLike | None = None,
    ):
        """Arguments:
            components: a non-empty sequence of `AbstractRegeneration`
                instances of the same dimension.
            weights: positive (unnormalised) weights, shape `(k,)`; they are
                normalised to sum to one. `None` means equal weights.

        Raises:
            ValueError: for an empty sequence, non-regeneration components,
                components of different dimensions, weights of the wrong shape,
                or weights that are not finite and strictly positive.
        """
        message = "`components` must be a sequence (list or tuple) of regeneration distributions, got "
        if isinstance(components, (AbstractRegeneration, str, bytes)):
            raise TypeError(message + type(components).__name__)
        try:
            components = tuple(components)
        except TypeError as err:
            raise TypeError(message + type(components).__name__) from err
        if len(components) == 0:
            raise ValueError("`components` must contain at least one distribution.")
        for i, c in enumerate(components):
            if not isinstance(c, AbstractRegeneration):
                raise ValueError(
                    f"Component {i} is a {type(c).__name__}, not an "
                    "AbstractRegeneration."
                )
        dims = [c.dim for c in components]
        if len(set(dims)) != 1:
            raise ValueError(f"All components must have the same dim, got dims {dims}.")
        k = len(components)
        # The mixture computes in its components' dtype (a float32 mixture stays float32).
        key = jax.random.key(0)
        dtype = jnp.result_type(*(jax.eval_shape(c.sample, key).dtype for c in components))
        if weights is None:
            log_weights = jnp.asarray(np.full((k,), -math.log(k)), dtype)
        else:
            weights = as_float_array(weights, "weights")
            if weights.shape != (k,):
                raise ValueError(
                    f"`weights` must have shape ({k},) (one per component), got "
                    f"{weights.shape}."
                )
            if is_concrete(weights):
                w = np.asarray(weights, dtype=np.float64)
                if not (np.all(np.isfinite(w)) and np.all(w > 0)):
                    raise ValueError(
                        f"`weights` must be finite and strictly positive, got {w}."
                    )
                log_w = np.log(w) - np.log(np.sum(w))
                log_weights = jnp.asarray(log_w, dtype)
            else:
                log_weights = (jnp.log(weights) - jnp.log(jnp.sum(weights))).astype(dtype)
        self.components = components
        self.log_weights = log_weights
        self.dim = dims[0]

    @property
    def weights(self) -> Float[Array, " k"]:
        """The normalised mixture weights."""
        return jnp.exp(self.log_weights)

    def sample(
        self, key: PRNGKeyArray, shape: tuple[int, ...] = ()
    ) -> Float[Array, "*shape d"]:
        """Exact draws: a component index from `categorical(log_weights)`, then
        a draw from that component.

        Arguments:
            key: a JAX PRNG key.
            shape: batch shape; the result has shape `(*shape, d)`.
        """
        shape = check_shape(shape)
        key_idx, key_draw = jax.random.split(key)
        idx = jax.random.categorical(key_idx, self.log_weights, shape=shape)
        stacked = _stack(self.components)
        if stacked is not None:
            n = math.prod(shape)
            keys = jax.random.split(key_draw, n)

            def draw_one(k, i):
                component = jax.tree_util.tree_map(lambda leaf: leaf[i], stacked)
                return component.sample(k)

            draws = jax.vmap(draw_one)(keys, idx.reshape(n))
            return draws.reshape(shape + (self.dim,))
        keys = jax.random.split(key_draw, len(self.components))
        draws = [c.sample(k, shape) for c, k in zip(self.components, keys)]
        dtype = jnp.result_type(*draws)
        out = draws[0].astype(dtype)
        for i, d in enumerate(draws[1:], start=1):
            out = jnp.where((idx == i)[..., None], d.astype(dtype), out)
        return out

    def component_log_probs(self, x: Float[Array, " d"]) -> Float[Array, " k"]:
        """Log densities `log p_k(x)` of every component at one point (no weights)."""
        x = check_point(x, self.dim, "x")
        stacked = _stack(self.components)
        if stacked is not None:
            return jax.vmap(lambda c: c.log_prob(x))(stacked)
        return jnp.stack([c.log_prob(x) for c in self.components])

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        """`logsumexp_k(log w_k + log p_k(x))`; exactly `-inf` (with zero gradient)
        where every component is `-inf`."""
        terms = self.log_weights + self.component_log_probs(x)
        dead = jnp.all(terms == -jnp.inf)
        safe = jnp.where(dead, jnp.zeros_like(terms), terms)
        return jnp.where(dead, -jnp.inf, jax.scipy.special.logsumexp(safe))
