"""Two classic NumPyro models for the examples: eight schools and a mixture of normals."""

from __future__ import annotations

import jax.numpy as jnp
import numpyro
import numpyro.distributions as dist
from jaxtyping import ArrayLike


def eight_schools(sigma: ArrayLike, y: ArrayLike | None = None) -> None:
    """The eight-schools hierarchical model, non-centred (as in NumPyro's documentation).

    `mu ~ Normal(0, 5)`, `tau ~ HalfCauchy(5)`, `theta_tilde_j ~ Normal(0, 1)`,
    `theta_j = mu + tau theta_tilde_j` (a deterministic site), `y_j ~ Normal(theta_j, sigma_j)`.
    The latent space is 10-dimensional (`tau` is sampled as `log tau`).

    Arguments:
        sigma: the standard errors of the schools' estimates, shape `(J,)`.
        y: the estimates, shape `(J,)` (`None` samples them: the prior predictive).
    """
    sigma = jnp.asarray(sigma)
    mu = numpyro.sample("mu", dist.Normal(0.0, 5.0))
    tau = numpyro.sample("tau", dist.HalfCauchy(5.0))
    with numpyro.plate("school", sigma.shape[0]):
        theta_tilde = numpyro.sample("theta_tilde", dist.Normal(0.0, 1.0))
        theta = numpyro.deterministic("theta", mu + tau * theta_tilde)
        numpyro.sample("obs", dist.Normal(theta, sigma), obs=y)


def normal_mixture(data: ArrayLike, num_components: int = 2, observed: bool = True) -> None:
    """A one-dimensional mixture of `K` normals with unordered means (label switching).

    `weights ~ Dirichlet(1, ..., 1)`, and for each component `mu_k ~ Normal(m, R)` and
    `sigma_k ~ InverseGamma(2, R / 4)`, with `m` the midrange and `R` the range of the data
    (the data-scaled priors of Richardson and Green, 1997); each point is drawn from the
    mixture. Nothing orders the components, so the posterior is invariant under the `K!`
    permutations of their labels: it has `K!` symmetric copies ("labellings"), each holding
    exactly `1 / K!` of the mass.

    Arguments:
        data: the observations, shape `(N,)`.
        num_components: `K`, at least 2.
        observed: condition on `data` (`False` samples new data of the same size: the prior
            predictive).
    """
    if int(num_components) < 2:
        raise ValueError(f"num_components must be at least 2, got {num_components!r}")
    data = jnp.asarray(data)
    if data.ndim != 1 or data.shape[0] < 2:
        raise ValueError(f"data must be a 1-d array of at least 2 observations, got shape {data.shape}")
    centre, spread = 0.5 * (data.min() + data.max()), data.max() - data.min()
    weights = numpyro.sample("weights", dist.Dirichlet(jnp.ones(num_components)))
    with numpyro.plate("component", num_components):
        mu = numpyro.sample("mu", dist.Normal(centre, spread))
        sigma = numpyro.sample("sigma", dist.InverseGamma(2.0, spread / 4.0))
    with numpyro.plate("data", data.shape[0]):
        mixture = dist.MixtureSameFamily(dist.Categorical(weights), dist.Normal(mu, sigma))
        numpyro.sample("obs", mixture, obs=data if observed else None)
