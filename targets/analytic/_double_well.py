"""The one-dimensional double well `exp(-x^4 + 6 x^2 + x / 2)`: normaliser, moments, exact draws, CDF.

It is the non-Gaussian factor of the Many Well problem. Its constants come from adaptive
quadrature in float64 (computed once, on first use); draws come from exact rejection
sampling with a two-component Student-t (2 degrees of freedom) envelope whose bound is
the exact maximum of `log f - log envelope`, found from the roots of a polynomial.
"""

from __future__ import annotations

import functools
import itertools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.integrate
from jax.scipy.special import logsumexp
from jaxtyping import Array, Float, PRNGKeyArray

#: Coefficients of `h(x) = QUARTIC x^4 + QUADRATIC x^2 + LINEAR x`, the unnormalised log density.
QUARTIC, QUADRATIC, LINEAR = -1.0, 6.0, 0.5
#: Below `-SUPPORT` and above `SUPPORT` the density holds less than `exp(-80)` of the mass.
SUPPORT = 3.5
#: Widening of the envelope's scales over the Laplace standard deviations (tuned for acceptance).
ENVELOPE_WIDENING = 1.1
#: Gauss-Legendre panels and nodes per panel of the CDF quadrature.
CDF_PANELS, CDF_NODES = 64, 16


def log_unnormalised(x):
    """`h(x) = -x^4 + 6 x^2 + x / 2` (works on NumPy and JAX arrays)."""
    x2 = x * x
    return QUARTIC * x2 * x2 + QUADRATIC * x2 + LINEAR * x


class DoubleWellConstants(NamedTuple):
    """Exact constants of the double well (Python floats, float64 quadrature).

    `log_normaliser` is `log ∫ exp(h)`; `mean`, `second_moment` and `positive_probability`
    are `E[x]`, `E[x^2]` and `P(x > 0)` under the normalised density. The envelope is
    `g = sum_k w_k t_2(x; loc_k, scale_k)`; `log_bound` is `sup_x (h(x) - log g(x))` (made
    exact by the construction in `envelope`), so `exp(h) <= exp(log_bound) g` everywhere and
    proposals are accepted with probability `exp(log_normaliser - log_bound)`.
    """

    log_normaliser: float
    mean: float
    second_moment: float
    positive_probability: float
    locs: tuple[float, float]
    scales: tuple[float, float]
    log_weights: tuple[float, float]
    log_bound: float

    @property
    def acceptance(self) -> float:
        """Probability that one envelope proposal is accepted."""
        return math.exp(self.log_normaliser - self.log_bound)


def _quad(fn, lower: float, upper: float) -> float:
    # Split at the origin and at both wells, where the integrand changes shape fastest.
    points = (-SUPPORT - 1.0, -1.71, 0.0, 1.75, SUPPORT + 1.0)
    lo, hi = max(lower, points[0]), min(upper, points[-1])
    cuts = [lo] + [p for p in points[1:-1] if lo < p < hi] + [hi]
    pieces = (scipy.integrate.quad(fn, a, b, epsabs=0.0, epsrel=1e-13, limit=200)[0] for a, b in itertools.pairwise(cuts))
    return sum(pieces)


def _log_t2(x, loc: float, scale: float, xp=jnp):
    """Log density of a Student-t with 2 degrees of freedom; `xp` is `numpy` or `jax.numpy`."""
    z = (x - loc) / scale
    return -math.log(2.0 * math.sqrt(2.0)) - math.log(scale) - 1.5 * xp.log1p(0.5 * z * z)


def envelope() -> tuple[tuple[float, float], tuple[float, float], tuple[float, float], float]:
    """The rejection envelope: locations, scales, log weights and the exact log bound.

    Component 0 sits at the left well, component 1 at the right one, each with its
    Laplace scale widened by `ENVELOPE_WIDENING` and a weight proportional to its Laplace
    mass. Since `g >= w_k t_k`, `h - log g <= h - log(w_k t_k)`; the bound uses component 0
    on `x < 0` and component 1 on `x >= 0`. On each half-line `h(x) - log t_2(x)` is
    smooth, tends to `-inf` and is maximal at an end point (0) or where its derivative
    vanishes, i.e. at a real root of the quintic
    `h'(x) (2 s^2 + (x - m)^2) + 3 (x - m)`; the bound is the largest value at those points
    (plus `1e-9` for the rounding of the roots).
    """
    h_prime = np.poly1d([4.0 * QUARTIC, 0.0, 2.0 * QUADRATIC, LINEAR])
    roots = np.sort(h_prime.r.real[np.abs(h_prime.r.imag) < 1e-12])
    locs = (float(roots[0]), float(roots[-1]))
    curvature = [-(12.0 * QUARTIC * m * m + 2.0 * QUADRATIC) for m in locs]
    scales = (ENVELOPE_WIDENING / math.sqrt(curvature[0]), ENVELOPE_WIDENING / math.sqrt(curvature[1]))
    log_mass = np.array([log_unnormalised(m) + math.log(s) for m, s in zip(locs, scales)])
    first, second = (float(v) for v in log_mass - np.logaddexp(*log_mass))
    log_weights = (first, second)
    best = -math.inf
    for k, (lower, upper) in enumerate(((-math.inf, 0.0), (0.0, math.inf))):
        m, s = locs[k], scales[k]
        quintic = h_prime * np.poly1d([1.0, -2.0 * m, m * m + 2.0 * s * s]) + np.poly1d([3.0, -3.0 * m])
        candidates = [0.0] + [float(r.real) for r in quintic.r if abs(r.imag) < 1e-7 and lower <= r.real <= upper]
        for x in candidates:
            best = max(best, log_unnormalised(x) - log_weights[k] - _log_t2(np.float64(x), m, s, np))
    return locs, scales, log_weights, float(best) + 1e-9


@functools.cache
def constants() -> DoubleWellConstants:
    """The double well's exact constants (computed once per process, a few milliseconds)."""
    unnormalised = lambda x: math.exp(log_unnormalised(x))  # noqa: E731
    z = _quad(unnormalised, -math.inf, math.inf)
    mean = _quad(lambda x: x * unnormalised(x), -math.inf, math.inf) / z
    second = _quad(lambda x: x * x * unnormalised(x), -math.inf, math.inf) / z
    positive = _quad(unnormalised, 0.0, math.inf) / z
    log_z = math.log(z)
    locs, scales, log_weights, log_bound = envelope()
    return DoubleWellConstants(log_z, mean, second, positive, locs, scales, log_weights, log_bound)


def log_envelope(x: Float[Array, ...], c: DoubleWellConstants) -> Float[Array, ...]:
    """`log g(x)`, the log density of the envelope mixture."""
    parts = [w + _log_t2(x, m, s) for w, m, s in zip(c.log_weights, c.locs, c.scales)]
    return logsumexp(jnp.stack(parts), axis=0)


def sample(key: PRNGKeyArray, n: int, dtype) -> Float[Array, " n"]:
    """`n` exact independent draws of the double well, by vectorised rejection sampling.

    Every entry proposes from the envelope (component by weight, then a Student-t with 2
    degrees of freedom by inversion, `t = (2u - 1) / sqrt(2 u (1 - u))`) and accepts with
    probability `exp(h(x) - log_bound - log g(x))`, round after round in a
    `jax.lax.while_loop`, until every entry has accepted (about 3 in 4 per round).
    A proposal at `u = 0` is not finite and is rejected, like any other rejection.
    """
    c = constants()
    first = jnp.asarray(math.exp(c.log_weights[0]), dtype)
    locs, scales = jnp.asarray(c.locs, dtype), jnp.asarray(c.scales, dtype)

    def redraw(state: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
        key, x, accepted = state
        key, sub = jax.random.split(key)
        u = jax.random.uniform(sub, (3, n), dtype)
        k = (u[0] >= first).astype(jnp.int32)
        t = (2.0 * u[1] - 1.0) / jnp.sqrt(2.0 * u[1] * (1.0 - u[1]))
        proposal = locs[k] + scales[k] * t
        log_ratio = log_unnormalised(proposal) - c.log_bound - log_envelope(proposal, c)
        ok = jnp.isfinite(proposal) & (jnp.log1p(-u[2]) < log_ratio)
        return key, jnp.where(accepted, x, proposal), accepted | ok

    init = (key, jnp.zeros((n,), dtype), jnp.zeros((n,), bool))
    return jax.lax.while_loop(lambda state: ~jnp.all(state[2]), redraw, init)[1]


def cdf(t: Float[Array, ...]) -> Float[Array, ...]:
    """`P(x <= t)`, by composite Gauss-Legendre quadrature from `-SUPPORT` to `t` (about 1e-13 accurate)."""
    c = constants()
    nodes, weights = np.polynomial.legendre.leggauss(CDF_NODES)
    lower = -SUPPORT
    upper = jnp.clip(t, lower, SUPPORT)
    width = (upper - lower) / CDF_PANELS
    # Panel j covers [lower + j width, lower + (j + 1) width]; nodes mapped from [-1, 1].
    offsets = (np.arange(CDF_PANELS)[:, None] + 0.5 * (nodes[None, :] + 1.0)).ravel()
    x = lower + width[..., None] * jnp.asarray(offsets, t.dtype)
    values = jnp.exp(log_unnormalised(x) - c.log_normaliser)
    w = jnp.asarray(np.tile(weights, CDF_PANELS) * 0.5, t.dtype)
    return jnp.clip(width * jnp.sum(values * w, axis=-1), 0.0, 1.0)
