"""More than 16384 lanes in float64: every matrix-vector product of the core stays right.

With jax 0.10.2 on the CPU, `jit(vmap(lambda r: jnp.sum(A @ r)))` over more than 16384 rows
returns wrong float64 values for the rows past 16384 (an XLA bug in a matrix-vector product
followed by a reduction); `r @ A.T` is right. The core's densities, transfers and diffusions
are checked here over 20000 lanes against NumPy and SciPy.
"""

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from restore.dynamics import Diffusion
from restore.regeneration import Gaussian, StudentT
from restore.transfer import AutoregressiveGaussian

N = 20_000
MEAN = np.array([0.5, -1.0, 2.0])
COV = np.array([[2.0, 0.6, -0.3], [0.6, 1.0, 0.2], [-0.3, 0.2, 0.5]])


def points():
    return jnp.asarray(np.random.default_rng(0).normal(size=(N, 3)) * 2.0)


def test_the_form_the_core_uses_is_right():
    a = jnp.asarray(np.random.default_rng(1).normal(size=(3, 3)))
    exact = np.sum((np.asarray(points()) @ np.asarray(a).T) ** 2, axis=1)
    right = jax.jit(jax.vmap(lambda r: jnp.sum((r @ a.T) ** 2)))(points())
    np.testing.assert_allclose(right, exact, rtol=1e-12)


def test_gaussian_and_student_t_densities_over_many_lanes():
    x = points()
    gaussian = jax.jit(jax.vmap(Gaussian(MEAN, COV).log_prob))(x)
    np.testing.assert_allclose(gaussian, stats.multivariate_normal(MEAN, COV).logpdf(np.asarray(x)), rtol=1e-10)
    student = jax.jit(jax.vmap(StudentT(MEAN, COV, df=5.0).log_prob))(x)
    np.testing.assert_allclose(student, stats.multivariate_t(MEAN, COV, df=5.0).logpdf(np.asarray(x)), rtol=1e-10)


def test_autoregressive_transfer_over_many_lanes():
    transfer = AutoregressiveGaussian(MEAN, COV, 0.5)
    keys = jax.random.split(jax.random.key(0), N)
    x = points()
    moved = jax.jit(jax.vmap(transfer.sample))(keys, x)
    eps = jax.vmap(lambda k, p: jax.random.normal(k, p.shape, p.dtype))(keys, x)
    tril = np.linalg.cholesky(COV)
    exact = MEAN + 0.5 * (np.asarray(x) - MEAN) + np.sqrt(0.75) * np.asarray(eps) @ tril.T
    np.testing.assert_allclose(moved, exact, rtol=1e-10, atol=1e-12)


def test_diffusion_noise_with_a_matrix_over_many_lanes():
    matrix = jnp.asarray(COV)
    dynamics = Diffusion(lambda x: -x, matrix, 0.1)
    z = points()
    noise = jax.jit(jax.vmap(dynamics._noise))(z)
    np.testing.assert_allclose(noise, np.asarray(z) @ np.asarray(dynamics.noise_factor).T, rtol=1e-10, atol=1e-12)
