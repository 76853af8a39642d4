"""H2MC's proposal: the Gaussian of Hessian-Hamiltonian dynamics against a numerical integration of
those dynamics, its density against SciPy's, its draws against its moments, its input checks, and
each point's Gaussian built once, when the point is evaluated, and kept for the moves from it.
(Its invariance, with a negative control, is tested on the analytic image: tests/integration/test_render.py.)"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

import restore
from restore import Point
from restore.local import TorusH2MC, h2mc_gaussian
from restore.regeneration import UniformTorus


def flow(lam: float, g: float, momentum: float, time: float) -> float:
    """Position after `time` of `x'' = g + lam x` from `x = 0`, `x' = momentum`, integrated by SciPy."""
    solution = integrate.solve_ivp(lambda t, y: [y[1], g + lam * y[0]], (0.0, time), [0.0, momentum], rtol=1e-11, atol=1e-13)
    return float(solution.y[0, -1])


def dynamics_gaussian(lam: float, g: float, angle: float) -> tuple[float, float]:
    """Mean and variance of the move along one eigen-direction, from the flow itself: the flow
    is affine in the momentum, so two integrations give both. Curved directions run for the
    time that turns the angle (`sqrt|lam| t = angle`), flat ones for `angle`."""
    time = angle / math.sqrt(abs(lam)) if lam != 0 else angle
    mean = flow(lam, g, 0.0, time)
    return mean, (flow(lam, g, 1.0, time) - mean) ** 2


@pytest.mark.parametrize("angle", [math.pi / 2, 1.0])
def test_the_gaussian_is_the_flow_of_the_quadratic_model_times_the_prior(angle):
    """A Hessian with a peak (-40), a valley (+9) and a flat direction (0) under a rotation: per
    direction, the dynamics' Gaussian times `N(0, sigma^2)` (precisions add, means weighted)."""
    rotation, _ = np.linalg.qr(np.random.default_rng(0).standard_normal((3, 3)))
    lam, g = np.array([-40.0, 9.0, 0.0]), np.array([1.5, -2.0, 0.7])
    sigma = 0.3
    gaussian = h2mc_gaussian(jnp.asarray(rotation @ g), jnp.asarray(rotation @ np.diag(lam) @ rotation.T), sigma, angle)
    mean, covariance = np.zeros(3), np.zeros((3, 3))
    for i in range(3):
        m, v = dynamics_gaussian(lam[i], g[i], angle)
        precision = 1 / v + 1 / sigma**2
        mean += rotation[:, i] * (m / v) / precision
        covariance += np.outer(rotation[:, i], rotation[:, i]) / precision
    basis = np.asarray(gaussian.basis)
    np.testing.assert_allclose(basis @ np.asarray(gaussian.mean), mean, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(basis @ np.diag(1 / np.asarray(gaussian.precision)) @ basis.T, covariance, rtol=1e-7, atol=1e-12)


def test_density_and_draws_agree_with_the_gaussian_they_describe():
    rng = np.random.default_rng(1)
    a = rng.standard_normal((4, 4))
    gaussian = h2mc_gaussian(jnp.asarray(rng.standard_normal(4)), jnp.asarray(-(a @ a.T) - np.eye(4)), 0.5)
    basis, precision = np.asarray(gaussian.basis), np.asarray(gaussian.precision)
    mean, covariance = basis @ np.asarray(gaussian.mean), basis @ np.diag(1 / precision) @ basis.T
    moves = rng.standard_normal((5, 4))
    constant = 2 * math.log(2 * math.pi)  # the d log(2 pi) / 2 the density leaves out, d = 4
    expected = stats.multivariate_normal(mean, covariance).logpdf(moves) + constant
    np.testing.assert_allclose(np.asarray(jax.vmap(gaussian.log_density)(jnp.asarray(moves))), expected, rtol=1e-10)
    draws = np.asarray(jax.vmap(gaussian.sample)(jax.random.split(jax.random.key(0), 40_000)))
    np.testing.assert_allclose(draws.mean(0), mean, atol=4 * np.sqrt(np.diag(covariance).max() / 40_000))
    np.testing.assert_allclose(np.cov(draws.T), covariance, atol=0.03 * np.abs(covariance).max())


def test_a_gradient_or_hessian_that_is_not_finite_gives_the_prior():
    for grad, hessian in [(jnp.array([jnp.nan, 1.0]), -jnp.eye(2)), (jnp.ones(2), jnp.array([[jnp.inf, 0.0], [0.0, -1.0]]))]:
        gaussian = h2mc_gaussian(grad, hessian, 0.02)
        np.testing.assert_allclose(np.asarray(gaussian.mean), 0.0)
        np.testing.assert_allclose(np.asarray(gaussian.precision), 1 / 0.02**2)


def test_the_kernel_builds_its_hessian_from_gradients_and_keeps_moves_within_sigma():
    """On `log f = -|A (u - c)|^2 / 2` (Hessian `-A^T A`) the differences give the Hessian to
    the step's accuracy, and moves stay on the torus, a few sigma from the mean move."""
    a = jnp.array([[30.0, 5.0], [0.0, 10.0]])
    centre = jnp.array([0.5, 0.5])
    logdensity = lambda u: -0.5 * jnp.sum((a @ (u - centre)) ** 2)  # noqa: E731
    kernel = TorusH2MC(0.02, difference=1e-5)
    u = jnp.array([0.52, 0.47])
    point = Point(u, logdensity(u), jax.grad(logdensity)(u), None)
    built = kernel.gaussian(jax.grad(logdensity), u, point.grad)
    exact = h2mc_gaussian(point.grad, -(a.T @ a), 0.02)
    covariance = lambda g: g.basis @ jnp.diag(1 / g.precision) @ g.basis.T  # noqa: E731
    np.testing.assert_allclose(np.asarray(covariance(built)), np.asarray(covariance(exact)), rtol=1e-4)
    np.testing.assert_allclose(np.asarray(built.basis @ built.mean), np.asarray(exact.basis @ exact.mean), rtol=1e-4)
    moves, log_ratios = jax.vmap(lambda k: kernel.propose(k, point, logdensity))(jax.random.split(jax.random.key(2), 2000))
    assert np.all((np.asarray(moves) >= 0) & (np.asarray(moves) < 1)) and np.all(np.isfinite(np.asarray(log_ratios)))
    assert np.abs(np.asarray(moves) - np.asarray(u + exact.basis @ exact.mean)).max() < 6 * 0.02


def test_the_kernel_refuses_bad_settings_and_a_missing_log_density():
    for kwargs, match in [({"sigma": 0.2}, "sigma"), ({"sigma": 0.0}, "sigma"), ({"angle": 4.0}, "angle"), ({"difference": 0.5}, "difference")]:
        with pytest.raises(ValueError, match=match):
            TorusH2MC(**kwargs)
    point = Point(jnp.array([0.2, 0.3]), jnp.array(0.0), jnp.zeros(2), None)
    with pytest.raises(ValueError, match="needs the log density"):
        TorusH2MC().propose(jax.random.key(0), point, None)


A = jnp.array([[30.0, 5.0, 0.0], [0.0, 10.0, 2.0], [1.0, 0.0, 20.0]])
CENTRE = jnp.array([0.5, 0.45, 0.55])


def quadratic(u):
    return -0.5 * jnp.sum((A @ (u - CENTRE)) ** 2)


def counted_quadratic(rows: list):
    """`quadratic` whose value and gradient come from a host callback that records how many
    points each call evaluates (as a renderer's tracer is called), differentiable once."""

    def host(u):
        u = np.asarray(u, np.float64)
        rows.append(u.reshape(-1, 3).shape[0])
        r = (u - np.asarray(CENTRE)) @ np.asarray(A).T
        return (-0.5 * np.sum(r**2, -1)).astype(np.float32), (-(r @ np.asarray(A))).astype(np.float32)

    def both(u):
        shapes = (jax.ShapeDtypeStruct(u.shape[:-1], jnp.float32), jax.ShapeDtypeStruct(u.shape, jnp.float32))
        return jax.pure_callback(host, shapes, u, vmap_method="expand_dims")

    @jax.custom_vjp
    def f(u):
        return both(u)[0]

    def fwd(u):
        value, grad = both(u)
        return value, grad

    f.defvjp(fwd, lambda grad, cotangent: (cotangent * grad,))
    return f


def test_evaluating_a_point_builds_its_gaussian_in_one_batch_and_moves_reuse_it():
    """`evaluate_point` gives the value, the gradient and the Gaussian `gaussian` builds, from
    one call of the log density's gradients (`dim + 1` points); a jump-Restore step then
    evaluates the candidate alone, once: the current point's Gaussian travels with the state."""
    kernel = TorusH2MC(0.02, difference=1e-4)
    u = jnp.array([0.52, 0.47, 0.5], jnp.float32)
    rows: list = []
    point, invalid = jax.jit(lambda x: kernel.evaluate_point(counted_quadratic(rows), x))(u)
    assert rows == [4] and not bool(invalid)
    np.testing.assert_allclose(float(point.logdensity), float(quadratic(u)), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(point.grad), np.asarray(jax.grad(quadratic)(u)), rtol=1e-4)
    built = kernel.gaussian(jax.grad(quadratic), u, jax.grad(quadratic)(u))
    covariance = lambda g: g.basis @ jnp.diag(1 / g.precision) @ g.basis.T  # noqa: E731
    np.testing.assert_allclose(np.asarray(covariance(point.geometry)), np.asarray(covariance(built)), rtol=2e-3)

    rows.clear()
    sampler = restore.JumpRestore(counted_quadratic(rows), kernel, UniformTorus(3), log_rate=-3.0)
    state = jax.jit(lambda k, x: sampler.init(k, x))(jax.random.key(0), u)
    assert rows == [4] and state.geometry is not None
    rows.clear()
    new_state, _ = jax.jit(lambda k, s: sampler.step(k, s))(jax.random.key(1), state)
    assert rows == [4]  # the candidate (or a fresh tour start) and its differences; nothing at the current point
    assert jax.tree.structure(new_state) == jax.tree.structure(state)


def test_h2mc_refuses_a_candidate_evaluated_without_its_gaussian():
    kernel = TorusH2MC()
    u = jnp.array([0.5, 0.45, 0.55])
    point, _ = kernel.evaluate_point(quadratic, u)
    candidate, aux = kernel.propose(jax.random.key(0), point, quadratic)
    plain = restore.Point(candidate, quadratic(candidate), jax.grad(quadratic)(candidate), None)
    with pytest.raises(ValueError, match="candidate's Gaussian"):
        kernel.accept(jax.random.key(1), point, plain, aux)


def test_two_phases_with_different_h2mc_kernels_are_refused():
    dynamics = (restore.dynamics.Jump(TorusH2MC(0.01)), restore.dynamics.Jump(TorusH2MC(0.02)))
    with pytest.raises(ValueError, match="geometry"):
        restore.Restore(quadratic, dynamics, restore.transfer.Independent(UniformTorus(3)), tour_length=(1.0, 1.0))


def test_mixture_mh_carries_the_h2mc_gaussian_in_its_state():
    """`MixtureMH` evaluates its points with the kernel too: after local and large steps, accepted
    and rejected, the state holds the Gaussian of its own position."""
    kernel = TorusH2MC(0.02)
    mh = restore.MixtureMH(quadratic, kernel, UniformTorus(3), large_step_probability=0.5)
    state = jax.jit(lambda k: mh.init(k))(jax.random.key(0))
    step = jax.jit(lambda k, s: mh.step(k, s))
    accepted = 0
    for i in range(12):
        new_state, info = step(jax.random.key(i + 1), state)
        assert jax.tree.structure(new_state) == jax.tree.structure(state)
        state, accepted = new_state, accepted + int(info.accepted)
        own = kernel.evaluate_point(quadratic, state.position)[0].geometry
        np.testing.assert_allclose(np.asarray(state.geometry.mean_move()), np.asarray(own.mean_move()), rtol=1e-6, atol=1e-9)
    assert 0 < accepted < 12
