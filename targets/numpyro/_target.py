"""A NumPyro model and its data as a target on the unconstrained space."""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, ArrayLike, PRNGKeyArray
from numpyro import handlers
from numpyro.infer import Predictive
from numpyro.infer.util import constrain_fn, potential_energy, unconstrain_fn

from restore.regeneration import StudentT

#: Degrees of freedom of the Student-t that `NumPyroTarget.prior` fits to the model's prior.
PRIOR_DF = 3.0


class NumPyroTarget:
    """A NumPyro model conditioned on its data, as a log density on the unconstrained space.

    NumPyro's own utilities (a traced run of the model, then `numpyro.infer.util`'s
    `unconstrain_fn`, `potential_energy` and `constrain_fn`) find the latent sample sites
    and the bijections that map each site's support to the real line; a point `x` of
    the target is the concatenation of all unconstrained latent values (`dim` numbers, in
    the order of `names`). `logdensity(x)` is minus NumPyro's potential energy: the log joint
    density of the latent values and the data, with the log Jacobians of the transforms
    added. Every site's log probability is normalised, so the normalising constant `Z` of
    this density is the model evidence `p(data)`, and Restore's `log Z` estimates it.

    Draws and estimates go back to the constrained parameters by name: `constrain` maps
    points (any leading axes) to a dict of constrained values, deterministic sites
    included; `observables("mu", "tau")` makes observables of constrained values for
    `restore.sample`/`restore.autosample`; `draws`, `estimate_draws` and `to_arviz` read a
    result's stored draws by name.

    Models with discrete latent sites are not supported: marginalise them in the model
    (e.g. with `numpyro.distributions.MixtureSameFamily`).

    Attributes:
        model: the NumPyro model (a callable with `numpyro.sample` statements).
        model_args: its positional arguments.
        model_kwargs: its keyword arguments (the data).
        dim: the dimension `d` of the unconstrained space.
        names: the latent sample sites, in the order of the flat vector.
        shapes: each latent site's constrained shape.
        sites: every site `constrain` returns (latent and deterministic), with its shape.
    """

    def __init__(self, model: Callable[..., Any], *model_args: Any, **model_kwargs: Any):
        """Arguments:
            model: a NumPyro model.
            model_args: positional arguments of the model (e.g. the data).
            model_kwargs: keyword arguments of the model (e.g. `y=observations`).

        Raises:
            TypeError: if `model` is not callable.
            ValueError: if the model has no continuous latent sites or has discrete ones.
        """
        if not callable(model):
            raise TypeError(f"model must be a NumPyro model (a callable), got {type(model).__name__}")
        self.model, self.model_args, self.model_kwargs = model, tuple(model_args), dict(model_kwargs)
        # The model runs abstractly (shapes only, nothing compiled): the latent sites, their
        # shapes and the layout of the unconstrained vector are all static.
        sites: dict[str, dict] = {}

        def latent_values(key):
            sites.update(handlers.trace(handlers.seed(model, key)).get_trace(*self.model_args, **self.model_kwargs))
            latent = {n: s["value"] for n, s in sites.items() if s["type"] == "sample" and not s["is_observed"]}
            return latent, self._free(latent) if latent else {}

        try:
            latent, free = jax.eval_shape(latent_values, jax.random.key(0))
        except Exception as err:
            raise ValueError(f"NumPyro could not run the model {getattr(model, '__name__', model)!r}: {err}") from err
        discrete = [n for n in latent if _is_discrete(sites[n])]
        if discrete:
            raise ValueError(f"the model has discrete latent sites {discrete}: marginalise them in the model")
        if not latent:
            raise ValueError("the model has no latent sample sites to sample")
        self.names: tuple[str, ...] = tuple(sorted(latent))
        self.shapes: dict[str, tuple[int, ...]] = {n: tuple(latent[n].shape) for n in self.names}
        flat, self._unravel = ravel_pytree({n: jnp.zeros(free[n].shape, free[n].dtype) for n in self.names})
        self.dim: int = int(flat.shape[0])
        self._dtype = flat.dtype
        self._x64 = bool(jax.config.read("jax_enable_x64"))  # the precision the data and transforms were built in
        self.sites: dict[str, tuple[int, ...]] = {n: tuple(v.shape) for n, v in jax.eval_shape(self._constrain_one, flat).items()}
        # Compiled once: running a model op by op compiles every operation separately.
        self._log_joint = jax.jit(lambda x: -potential_energy(self.model, self.model_args, self.model_kwargs, self._unravel(x)))
        self._constrain_many = jax.jit(jax.vmap(self._constrain_one))
        self._unconstrain_one = jax.jit(lambda latent: ravel_pytree(self._free(latent))[0])

    # ------------------------------------------------------------------ the density
    def logdensity(self, x: Array) -> Array:
        """Log joint density of the unconstrained point `x` `(d,)` and the data (Jacobians included)."""
        return self._log_joint(self._point(x))

    def _point(self, x: Array) -> Array:
        self._check_precision()
        x = jnp.asarray(x)
        if x.shape != (self.dim,):
            raise ValueError(f"x must be one unconstrained point of shape ({self.dim},), got {x.shape}")
        return x

    def _check_precision(self) -> None:
        """Refuse to run in another precision than the one the target was built in (the model's
        data and transforms keep their dtype: float32 numbers mixed into a float64 run fail deep
        inside JAX with a dtype mismatch)."""
        if bool(jax.config.read("jax_enable_x64")) != self._x64:
            now, then = ("float64", "float32") if not self._x64 else ("float32", "float64")
            raise RuntimeError(
                f"this NumPyroTarget was built in {then} and JAX now computes in {now} (jax_enable_x64 was "
                "switched after it was built): build the target after jax.config.update('jax_enable_x64', ...)"
            )

    # ------------------------------------------------------------------ constrained values
    def constrain(self, x: ArrayLike) -> dict[str, Array]:
        """The constrained values of every site (latent and deterministic) at points `x` `(..., d)`.

        Returns a dict from site name to an array of shape `(..., *site_shape)`. Traceable,
        so it can be used inside observables.
        """
        self._check_precision()
        x = jnp.asarray(x)
        if x.ndim == 0 or x.shape[-1] != self.dim:
            raise ValueError(f"x must have a last axis of length {self.dim} (unconstrained points), got shape {x.shape}")
        lead = x.shape[:-1]
        values = self._constrain_many(x.reshape(-1, self.dim))
        return {name: v.reshape(lead + v.shape[1:]) for name, v in values.items()}

    def _constrain_one(self, x: Array) -> dict[str, Array]:
        return constrain_fn(self.model, self.model_args, self.model_kwargs, self._unravel(x), return_deterministic=True)

    def _free(self, latent: Mapping[str, Array]) -> dict[str, Array]:
        return unconstrain_fn(self.model, self.model_args, self.model_kwargs, dict(latent))

    def unconstrain(self, params: Mapping[str, ArrayLike]) -> Array:
        """The unconstrained point `(d,)` of one set of constrained latent values (a dict by site name)."""
        missing = [n for n in self.names if n not in params]
        if missing:
            raise ValueError(f"params must give every latent site {list(self.names)}; missing {missing}")
        return self._unconstrain_one({n: jnp.asarray(params[n]) for n in self.names})

    def observables(self, *names: str, **functions: Callable[[dict[str, Array]], Array]) -> dict[str, Callable[[Array], Array]]:
        """Observables of constrained values, for `restore.sample` or `restore.autosample`.

        Arguments:
            names: sites (latent or deterministic) whose constrained value is observed under
                its own name, e.g. `observables("mu", "tau")`.
            functions: more observables, each a function of the dict of constrained values,
                e.g. `tau_squared=lambda p: p["tau"] ** 2`.

        Returns:
            A dict from name to a function of one unconstrained point.
        """
        unknown = [n for n in names if n not in self.sites]
        if unknown:
            raise ValueError(f"unknown sites {unknown}; the model's sites are {list(self.sites)}")
        out: dict[str, Callable[[Array], Array]] = {}
        for name in names:
            out[name] = functools.partial(self._site, name)
        for label, fn in functions.items():
            if not callable(fn):
                raise TypeError(f"observable {label!r} must be a function of the dict of constrained values")
            out[label] = functools.partial(self._through, fn)
        if not out:
            raise ValueError("give at least one site name or function")
        return out

    # ------------------------------------------------------------------ the prior
    def _site(self, name: str, x: Array) -> Array:
        return self.constrain(x)[name]

    def _through(self, fn: Callable[[dict[str, Array]], Array], x: Array) -> Array:
        return fn(self.constrain(x))

    def prior_draws(self, key: PRNGKeyArray, num_draws: int = 4096) -> Array:
        """Unconstrained points `(num_draws, d)` drawn from the model's prior (NumPyro's `Predictive`)."""
        prior = Predictive(self.model, num_samples=int(num_draws), return_sites=list(self.names))
        draws = prior(key, *self.model_args, **self.model_kwargs)
        return jax.vmap(self._unconstrain_one)({n: draws[n] for n in self.names})

    def prior(self, key: PRNGKeyArray | None = None, num_draws: int = 4096, df: float = PRIOR_DF) -> StudentT:
        """A Student-t on the unconstrained space that covers the model's prior.

        Its location is the coordinate-wise median of prior draws and its (diagonal) scale the
        coordinate-wise median absolute deviation (scaled to a normal's standard deviation),
        so heavy-tailed priors such as a half-Cauchy do not blow it up. Pass it as
        `restore.autosample(..., prior=target.prior())`: seeding starts are drawn from it and
        it is the defensive component of every regeneration.

        Arguments:
            key: a JAX PRNG key for the prior draws (default `jax.random.key(0)`).
            num_draws: how many prior draws to summarise.
            df: the Student-t's degrees of freedom.
        """
        self._check_precision()
        key = jax.random.key(0) if key is None else key
        draws = np.asarray(self.prior_draws(key, num_draws), np.float64)
        draws = draws[np.all(np.isfinite(draws), axis=1)]
        if len(draws) < 10:
            raise ValueError("fewer than 10 prior draws were finite on the unconstrained space")
        loc = np.median(draws, axis=0)
        scale = 1.4826 * np.median(np.abs(draws - loc), axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        dtype = self._dtype
        return StudentT(jnp.asarray(loc, dtype), jnp.asarray(scale**2, dtype), df)

    # ------------------------------------------------------------------ results
    def draws(self, result) -> dict[str, np.ndarray]:
        """A result's stored draws as constrained values by site: `(slots, lanes, *site_shape)`.

        The draws are weighted: `result.draw_weights` `(slots, lanes)` are their weights.
        """
        run = getattr(result, "result", result)
        return {name: np.asarray(v) for name, v in self.constrain(run.draws).items()}

    def estimate_draws(self, result, name: str, fn: Callable[[Array], Array] | None = None):
        """Post-hoc estimate of `E[site]` (or `E[fn(site)]`) from a result's stored, weighted draws.

        Arguments:
            result: a `restore.SampleResult` (or `AutoResult`) of this target.
            name: a site name.
            fn: optional function of the site's constrained value.
        """
        if name not in self.sites:
            raise ValueError(f"unknown site {name!r}; the model's sites are {list(self.sites)}")
        apply = (lambda v: v) if fn is None else fn
        run = getattr(result, "result", result)
        return run.estimate_draws(lambda x: np.asarray(apply(self.constrain(x)[name])))

    def to_arviz(self, result, resample: bool = True, seed: int = 0, chains: int | None = None):
        """A result's stored draws in ArviZ, one variable per site (constrained), lanes grouped into chains.

        See `restore.SampleResult.to_arviz`.
        """
        run = getattr(result, "result", result)
        return run.to_arviz(resample=resample, seed=seed, transform=self.constrain, chains=chains)

    def __repr__(self) -> str:
        sites = ", ".join(f"{n}{list(s) if s else ''}" for n, s in self.shapes.items())
        name = getattr(self.model, "__name__", type(self.model).__name__)
        return f"NumPyroTarget({name}: {sites}; {self.dim} unconstrained dimensions)"


def _is_discrete(site) -> bool:
    fn = site["fn"]
    return bool(getattr(fn, "is_discrete", False)) or bool(getattr(getattr(fn, "support", None), "is_discrete", False))

