import jax

jax.config.update("jax_enable_x64", True)

import functools  # noqa: E402

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import scipy.stats as st  # noqa: E402
from jax.scipy.special import logsumexp  # noqa: E402

from restore.regeneration import (  # noqa: E402
    AbstractRegeneration,
    Gaussian,
    LaplaceModes,
    Mixture,
    ProductMixture,
    RotatedProductMixture,
    StudentT,
    TorusKernelMixture,
    UniformBox,
    UniformTorus,
    find_modes,
    laplace_mixture,
    mixture_from_modes,
)

KEY = jax.random.key(20240611)
PVAL = 1e-3
# One sample size and one number of test points throughout, so that jitted
# functions are compiled once per distribution structure and reused.
N = 40_000
NPTS = 50

COV3 = np.array([[2.0, 0.6, -0.3], [0.6, 1.0, 0.2], [-0.3, 0.2, 0.5]])
MEAN3 = np.array([1.0, -2.0, 0.5])


def _keys(n):
    return jax.random.split(KEY, n)


def _points(n, d, scale=3.0, seed=0):
    return np.random.default_rng(seed).normal(scale=scale, size=(n, d))


# Everything is evaluated through these jitted helpers (distributions are
# pytrees), which keeps compilation time, and so the test time, low.
@jax.jit
def _lp(dist, x):
    return dist.log_prob(x)


@jax.jit
def _lpv(dist, xs):
    return jax.vmap(dist.log_prob)(xs)


_grad = jax.jit(jax.grad(lambda dist, x: dist.log_prob(x), argnums=1))


@functools.partial(jax.jit, static_argnums=2)
def _sample(dist, key, n):
    return dist.sample(key, (n,))


def _batched_log_prob(dist, xs):
    return np.asarray(_lpv(dist, jnp.asarray(xs)))


def _grid_integral_2d(dist, lo, hi, n=401):
    g = np.linspace(lo, hi, n)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    pts = np.stack([xx.ravel(), yy.ravel()], axis=1)
    dens = np.exp(_batched_log_prob(dist, pts)).reshape(n, n)
    return np.trapezoid(np.trapezoid(dens, g, axis=1), g)


# --------------------------------------------------------------------- shapes


# All 3-D, with the same structures as used in the per-distribution tests below.
ALL_DISTS = {
    "gaussian": lambda: Gaussian(MEAN3, COV3),
    "student_t": lambda: StudentT(MEAN3, COV3, 5.0),
    "box": lambda: UniformBox(np.zeros(3), np.array([1.0, 2.0, 3.0])),
    "torus": lambda: UniformTorus(3),
    "torus_kernels": lambda: TorusKernelMixture([[0.1, 0.5, 0.95], [0.7, 0.2, 0.4]], 0.1, 0.3, [0.0, 1.0]),
    "mixture": lambda: Mixture(
        [Gaussian(MEAN3, COV3), StudentT(-MEAN3, 1.0, 3.0)], [0.3, 0.7]
    ),
    "mixture_same": lambda: Mixture([Gaussian(MEAN3, COV3), Gaussian(-MEAN3, 2.0)]),
    "rotated_product": lambda: RotatedProductMixture(
        ProductMixture(np.ones((3, 2)), np.array([[1.0, -1.0], [0.0, 2.0], [0.5, 0.5]]), np.ones((3, 2))), MEAN3, np.linalg.cholesky(COV3).T
    ),
}


@pytest.mark.parametrize("name", sorted(ALL_DISTS))
def test_shapes_jit_vmap(name):
    dist = ALL_DISTS[name]()
    assert isinstance(dist, AbstractRegeneration)
    assert dist.dim == 3
    k = _keys(1)[0]
    xs = _sample(dist, k, N)
    assert xs.shape == (N, 3) and np.all(np.isfinite(xs))
    # Other shapes and vmap (checked by tracing only, to save compilation time).
    assert jax.eval_shape(lambda: dist.sample(k)).shape == (3,)
    assert jax.eval_shape(lambda: dist.sample(k, (2, 5))).shape == (2, 5, 3)
    assert jax.eval_shape(lambda: dist.sample(k, 4)).shape == (4, 3)
    assert jax.eval_shape(lambda: dist.sample(k, (0,))).shape == (0, 3)
    assert jax.eval_shape(jax.vmap(dist.sample), _keys(4)).shape == (4, 3)
    # jit + vmap of log_prob; the distribution passes through jit as a pytree.
    lp = _lpv(dist, xs[:NPTS])
    assert lp.shape == (NPTS,) and np.all(np.isfinite(lp))
    np.testing.assert_allclose(lp[0], _lp(dist, xs[0]), rtol=1e-10)
    # grad is finite inside the support.
    g = _grad(dist, xs[0])
    assert g.shape == (3,) and np.all(np.isfinite(g))
    with pytest.raises(ValueError, match="single point of shape"):
        dist.log_prob(xs[:2])


def test_eager_single_draw():
    dist = Gaussian(MEAN3, COV3)
    x = dist.sample(KEY)
    assert x.shape == (3,)
    assert np.isfinite(dist.log_prob(x))


@pytest.mark.parametrize("name", ["mixture", "box"])
def test_float32_preserved(name):
    # x64 is on in this file: float32 parameters must stay float32 (no hard-coded
    # dtypes). "mixture" covers Gaussian and StudentT.
    dist = ALL_DISTS[name]()
    dist32 = jax.tree_util.tree_map(
        lambda a: a.astype(jnp.float32) if eqx.is_inexact_array(a) else a, dist
    )

    @jax.jit
    def run(d, key):
        x = d.sample(key, (3,))
        return x, d.log_prob(x[0])

    x, lp = run(dist32, KEY)
    assert x.dtype == jnp.float32 and lp.dtype == jnp.float32
    assert np.isfinite(lp)
    g = Gaussian(np.zeros(2, np.float32), np.eye(2, dtype=np.float32))
    assert g.mean.dtype == g.scale_tril.dtype == jnp.float32


# ------------------------------------------------------------------- Gaussian


@pytest.mark.parametrize(
    "cov, full",
    [
        (COV3, COV3),
        (np.array([2.0, 1.0, 0.5]), np.diag([2.0, 1.0, 0.5])),
        (1.7, 1.7 * np.eye(3)),
    ],
    ids=["matrix", "diagonal", "scalar"],
)
def test_gaussian_log_prob_matches_scipy(cov, full):
    dist = Gaussian(MEAN3, cov)
    np.testing.assert_allclose(dist.cov, full, rtol=1e-12, atol=1e-14)
    xs = _points(NPTS, 3)
    ref = st.multivariate_normal(MEAN3, full).logpdf(xs)
    np.testing.assert_allclose(_batched_log_prob(dist, xs), ref, rtol=1e-10)
    # Analytic gradient.
    g = _grad(dist, jnp.asarray(xs[0]))
    np.testing.assert_allclose(g, -np.linalg.solve(full, xs[0] - MEAN3), rtol=1e-10)


def test_gaussian_normalised_2d():
    dist = Gaussian(np.array([0.3, -0.2]), np.array([[1.0, 0.4], [0.4, 0.8]]))
    assert abs(_grid_integral_2d(dist, -8, 8) - 1.0) < 1e-6


def test_gaussian_samples():
    dist = Gaussian(MEAN3, COV3)
    x = np.asarray(_sample(dist, KEY, N))
    np.testing.assert_allclose(x.mean(0), MEAN3, atol=0.03)
    np.testing.assert_allclose(np.cov(x.T), COV3, atol=0.05)
    for i in range(3):
        p = st.kstest(x[:, i], st.norm(MEAN3[i], np.sqrt(COV3[i, i])).cdf).pvalue
        assert p > PVAL


@pytest.mark.parametrize(
    "mean, cov, match",
    [
        (np.zeros((2, 2)), 1.0, "non-empty 1-D"),
        (np.zeros(3), np.ones((2, 2)), "must be a scalar, a \\(3,\\) diagonal"),
        (np.zeros(2), np.array([[1.0, 2.0], [2.0, 1.0]]), "positive definite"),
        (np.zeros(2), np.array([[1.0, 0.5], [0.0, 1.0]]), "symmetric"),
        (np.zeros(2), np.array([1.0, -1.0]), "strictly positive"),
        (np.zeros(2), 0.0, "strictly positive"),
        (np.zeros(2), np.array([[np.nan, 0.0], [0.0, 1.0]]), "non-finite"),
    ],
)
def test_gaussian_errors(mean, cov, match):
    with pytest.raises(ValueError, match=match):
        Gaussian(mean, cov)


# ------------------------------------------------------------------ Student-t


@pytest.mark.parametrize("df", [1.0, 3.0, 30.0])
def test_student_t_log_prob_matches_scipy(df):
    dist = StudentT(MEAN3, COV3, df)
    np.testing.assert_allclose(dist.scale, COV3, rtol=1e-12)
    xs = _points(NPTS, 3)
    ref = st.multivariate_t(MEAN3, COV3, df=df).logpdf(xs)
    np.testing.assert_allclose(_batched_log_prob(dist, xs), ref, rtol=1e-10)


def test_student_t_normalised_2d():
    # df = 6 so that the mass outside the grid is small.
    dist = StudentT(np.zeros(2), np.array([[1.0, 0.3], [0.3, 0.6]]), 6.0)
    assert abs(_grid_integral_2d(dist, -60, 60, n=801) - 1.0) < 2e-3


@pytest.mark.parametrize("df", [0.7, 5.0])
def test_student_t_samples(df):
    dist = StudentT(MEAN3, COV3, df)
    x = np.asarray(_sample(dist, KEY, N))
    assert np.all(np.isfinite(x))
    for i in range(3):
        ref = st.t(df, loc=MEAN3[i], scale=np.sqrt(COV3[i, i]))
        assert st.kstest(x[:, i], ref.cdf).pvalue > PVAL
    if df > 4:
        np.testing.assert_allclose(np.cov(x.T), COV3 * df / (df - 2), atol=0.15)


def test_student_t_heavier_tails_than_gaussian():
    far = jnp.array([30.0, -30.0, 30.0])
    assert _lp(StudentT(MEAN3, COV3, 4.0), far) > _lp(Gaussian(MEAN3, COV3), far) + 100


@pytest.mark.parametrize(
    "scale, df, match",
    [
        (1.0, 0.0, "`df` must be finite and strictly positive"),
        (1.0, -2.0, "`df` must be finite and strictly positive"),
        (1.0, np.nan, "`df` must be finite and strictly positive"),
        (1.0, np.ones(2), "`df` must be a scalar"),
        (np.array([[1.0, 3.0], [3.0, 1.0]]), 4.0, "positive definite"),
        (np.ones(3), 4.0, "`scale` must be a scalar"),
    ],
)
def test_student_t_errors(scale, df, match):
    with pytest.raises(ValueError, match=match):
        StudentT(np.zeros(2), scale, df)


# -------------------------------------------------------------------- Uniform


def test_uniform_box():
    low, high = np.array([-1.0, 0.0, 2.0]), np.array([1.0, 0.5, 5.0])
    dist = UniformBox(low, high)
    log_vol = np.log(2.0 * 0.5 * 3.0)
    assert np.isclose(_lp(dist, jnp.array([0.0, 0.25, 3.0])), -log_vol)
    assert np.isclose(_lp(dist, jnp.asarray(low)), -log_vol)  # closed box
    assert np.isclose(_lp(dist, jnp.asarray(high)), -log_vol)
    for bad in ([1.5, 0.25, 3.0], [0.0, -1e-9, 3.0], [0.0, 0.25, np.inf], [np.nan, 0.2, 3.0]):
        lp = _lp(dist, jnp.array(bad))
        assert lp == -np.inf and not np.isnan(lp)
    assert np.all(_grad(dist, jnp.array([2.0, 0.2, 3.0])) == 0)
    x = np.asarray(_sample(dist, KEY, N))
    assert np.all((x >= low) & (x <= high))
    for i in range(3):
        ref = st.uniform(low[i], high[i] - low[i])
        assert st.kstest(x[:, i], ref.cdf).pvalue > PVAL


def test_uniform_box_normalised_2d():
    dist = UniformBox(np.array([-1.0, 0.0]), np.array([1.0, 2.5]))
    g = np.linspace(-2, 3, 2001)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    dens = np.exp(_batched_log_prob(dist, np.stack([xx.ravel(), yy.ravel()], 1)))
    assert abs(dens.sum() * (g[1] - g[0]) ** 2 - 1.0) < 5e-3


@pytest.mark.parametrize(
    "low, high, match",
    [
        (np.zeros(2), np.ones(3), "same shape"),
        (np.zeros((2, 2)), np.ones((2, 2)), "non-empty 1-D"),
        (np.zeros(2), np.array([1.0, 0.0]), "low < high .* indices \\[1\\]"),
        (np.zeros(2), np.array([1.0, -1.0]), "low < high"),
        (np.zeros(2), np.array([1.0, np.inf]), "finite"),
    ],
)
def test_uniform_box_errors(low, high, match):
    with pytest.raises(ValueError, match=match):
        UniformBox(low, high)


def test_uniform_torus():
    dist = UniformTorus(3)
    assert _lp(dist, jnp.array([0.0, 0.999, 0.5])) == 0.0
    for bad in ([1.0, 0.5, 0.5], [-1e-12, 0.5, 0.5], [0.5, 2.0, 0.5], [np.nan, 0.5, 0.5]):
        lp = _lp(dist, jnp.array(bad))
        assert lp == -np.inf and not np.isnan(lp)
    x = np.asarray(_sample(dist, KEY, N))
    assert np.all((x >= 0) & (x < 1))
    for i in range(3):
        assert st.kstest(x[:, i], st.uniform().cdf).pvalue > PVAL
    for bad_dim in (0, -1, 2.5):
        with pytest.raises(ValueError, match="positive int"):
            UniformTorus(bad_dim)
    with pytest.raises(TypeError, match="positive int"):  # a boolean is not a count
        UniformTorus(True)


def test_torus_kernel_mixture_draws_follow_its_density():
    """Kernels that wrap around the torus's edges; the draws' 2-d histogram against the density
    integrated over each cell (chi-squared), the density's integral, and its support."""
    dist = TorusKernelMixture([[0.02, 0.5], [0.9, 0.97]], 0.08, 0.3, np.log([0.7, 0.3]))
    x = np.asarray(_sample(dist, KEY, N))
    assert np.all((x >= 0) & (x < 1))
    bins, sub = 10, 8
    counts, _, _ = np.histogram2d(x[:, 0], x[:, 1], bins=bins, range=[[0, 1], [0, 1]])
    g = (np.arange(bins * sub) + 0.5) / (bins * sub)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    density = np.exp(_batched_log_prob(dist, np.stack([xx.ravel(), yy.ravel()], axis=1))).reshape(bins * sub, bins * sub)
    cells = density.reshape(bins, sub, bins, sub).mean(axis=(1, 3)) / bins**2
    assert abs(cells.sum() - 1) < 1e-3  # the midpoint rule's error
    expected = N * cells / cells.sum()
    assert st.chi2.sf(np.sum((counts - expected) ** 2 / expected), bins * bins - 1) > PVAL
    # the uniform share bounds the density below; outside the torus it is -inf
    assert density.min() >= 0.3 * (1 - 1e-12)
    for bad in ([1.0, 0.5], [-1e-12, 0.5], [np.nan, 0.5]):
        lp = _lp(dist, jnp.array(bad))
        assert lp == -np.inf and not np.isnan(lp)


@pytest.mark.parametrize(
    "args, match",
    [
        (([0.1, 0.2], 0.1), "shape"),
        (([[0.1, 1.2]], 0.1), r"\[0, 1\)"),
        (([[0.1, 0.2]], 0.0), "bandwidth"),
        (([[0.1, 0.2]], 0.6), "bandwidth"),
        (([[0.1, 0.2]], 0.1, 1.0), "uniform_share"),
        (([[0.1, 0.2]], 0.1, 0.5, [0.0, 0.0]), "log_weights"),
    ],
)
def test_torus_kernel_mixture_errors(args, match):
    with pytest.raises(ValueError, match=match):
        TorusKernelMixture(*args)


# -------------------------------------------------------------------- Mixture


def test_mixture_heterogeneous():
    # Same structure as ALL_DISTS["mixture"] (Gaussian + StudentT, 3-D).
    scale_t = np.array([0.25, 2.0, 1.0])
    mix = Mixture(
        [
            Gaussian(np.array([-4.0, 0.0, 0.0]), 1.0),
            StudentT(np.array([3.0, 1.0, 0.0]), scale_t, 3.0),
        ],
        weights=[1.0, 3.0],
    )
    w = np.array([0.25, 0.75])
    np.testing.assert_allclose(mix.weights, w, rtol=1e-12)
    xs = _points(NPTS, 3)
    ref = np.logaddexp(
        np.log(w[0]) + st.multivariate_normal([-4.0, 0.0, 0.0], np.eye(3)).logpdf(xs),
        np.log(w[1]) + st.multivariate_t([3.0, 1.0, 0.0], np.diag(scale_t), df=3.0).logpdf(xs),
    )
    np.testing.assert_allclose(_batched_log_prob(mix, xs), ref, rtol=1e-10)
    x = np.asarray(_sample(mix, KEY, N))

    def cdf(t):
        return w[0] * st.norm(-4.0, 1.0).cdf(t) + w[1] * st.t(3.0, loc=3.0, scale=0.5).cdf(t)

    assert st.kstest(x[:, 0], cdf).pvalue > PVAL
    assert abs(np.mean(x[:, 0] < 0) - w[0]) < 0.01


def test_mixture_homogeneous_stacked():
    # Same structure as ALL_DISTS["mixture_same"] (two 3-D Gaussians).
    means = np.array([[-5.0, 0.0, 1.0], [6.0, 1.0, 0.0]])
    sds = np.array([1.0, 2.0])
    w = np.array([0.3, 0.7])
    mix = Mixture([Gaussian(m, s**2) for m, s in zip(means, sds)], w)
    xs = _points(NPTS, 3)
    ref = logsumexp(
        np.log(w)[:, None]
        + np.stack([st.multivariate_normal(m, s**2).logpdf(xs) for m, s in zip(means, sds)]),
        axis=0,
    )
    np.testing.assert_allclose(_batched_log_prob(mix, xs), ref, rtol=1e-10)
    x = np.asarray(_sample(mix, KEY, N))

    def cdf(t):
        return sum(wk * st.norm(m[0], s).cdf(t) for wk, m, s in zip(w, means, sds))

    assert st.kstest(x[:, 0], cdf).pvalue > PVAL


def test_mixture_normalised_2d():
    mix = Mixture(
        [
            Gaussian(np.array([-2.0, 0.0]), 0.5),
            StudentT(np.ones(2), np.array([[1.0, 0.2], [0.2, 0.5]]), 8.0),
        ],
        [0.4, 0.6],
    )
    assert abs(_grid_integral_2d(mix, -40, 40, n=801) - 1.0) < 2e-3


def test_mixture_outside_support_is_minus_inf_with_zero_grad():
    mix = Mixture(
        [UniformBox(np.zeros(2), np.ones(2)), UniformBox(np.full(2, 2.0), np.full(2, 4.0))]
    )
    inside = _lp(mix, jnp.array([3.0, 3.0]))
    assert np.isclose(inside, np.log(0.5 / 4.0))
    for bad in ([1.5, 1.5], [np.nan, 0.5]):
        lp = _lp(mix, jnp.array(bad))
        assert lp == -np.inf and not np.isnan(lp)
    g = _grad(mix, jnp.array([1.5, 1.5]))
    assert np.all(g == 0)


def test_nested_mixture():
    inner = Mixture([Gaussian(np.zeros(1), 1.0), Gaussian(np.ones(1), 2.0)])
    outer = Mixture([inner, Gaussian(np.full(1, -1.0), 0.5)], [0.5, 0.5])
    x = jnp.array([0.3])
    ref = np.log(
        0.25 * st.norm(0, 1).pdf(0.3)
        + 0.25 * st.norm(1, np.sqrt(2)).pdf(0.3)
        + 0.5 * st.norm(-1, np.sqrt(0.5)).pdf(0.3)
    )
    assert np.isclose(_lp(outer, x), ref, rtol=1e-10)
    x = np.asarray(_sample(outer, KEY, N))[:, 0]

    def cdf(t):
        return (
            0.25 * st.norm(0, 1).cdf(t)
            + 0.25 * st.norm(1, np.sqrt(2)).cdf(t)
            + 0.5 * st.norm(-1, np.sqrt(0.5)).cdf(t)
        )

    assert st.kstest(x, cdf).pvalue > PVAL


@pytest.mark.parametrize(
    "components, weights, match",
    [
        ([], None, "at least one"),
        ([Gaussian(np.zeros(2)), Gaussian(np.zeros(3))], None, "same dim"),
        ([Gaussian(np.zeros(2)), "not a distribution"], None, "not an AbstractRegeneration"),
        ([Gaussian(np.zeros(2)), Gaussian(np.ones(2))], [1.0, 0.0], "strictly positive"),
        ([Gaussian(np.zeros(2)), Gaussian(np.ones(2))], [1.0, -1.0], "strictly positive"),
        ([Gaussian(np.zeros(2)), Gaussian(np.ones(2))], [1.0, np.nan], "strictly positive"),
        ([Gaussian(np.zeros(2)), Gaussian(np.ones(2))], [1.0, 1.0, 1.0], "shape \\(2,\\)"),
    ],
)
def test_mixture_errors(components, weights, match):
    with pytest.raises(ValueError, match=match):
        Mixture(components, weights)


# --------------------------------------------------------------------- Laplace


MEANS_2D = np.array([[-8.0, 0.0], [0.0, 8.0], [8.0, 0.0]])
WEIGHTS_2D = np.array([0.2, 0.3, 0.5])


def logdensity_2d(x):
    sq = jnp.sum((x - MEANS_2D) ** 2, axis=-1)
    return logsumexp(jnp.log(WEIGHTS_2D) - 0.5 * sq) - jnp.log(2 * jnp.pi)


@pytest.fixture(scope="module")
def starts_2d():
    return jax.random.uniform(jax.random.key(1), (64, 2), minval=-12.0, maxval=12.0)


@pytest.fixture(scope="module")
def modes_2d(starts_2d):
    return find_modes(logdensity_2d, starts_2d)


def _match_modes(locations, means):
    """Index of the true mean closest to each found location."""
    dist = np.linalg.norm(np.asarray(locations)[:, None] - means[None], axis=-1)
    return dist.argmin(axis=1), dist.min(axis=1)


def test_find_modes_2d(modes_2d, starts_2d):
    assert isinstance(modes_2d, LaplaceModes)
    assert modes_2d.num_modes == 3
    idx, err = _match_modes(modes_2d.locations, MEANS_2D)
    assert sorted(idx.tolist()) == [0, 1, 2]
    assert np.all(err < 1e-3)
    eye = np.broadcast_to(np.eye(2), (3, 2, 2))
    np.testing.assert_allclose(modes_2d.covariances, eye, atol=1e-2)
    # Sorted by decreasing log density; counts account for every good start.
    assert np.all(np.diff(np.asarray(modes_2d.log_densities)) <= 0)
    assert int(modes_2d.counts.sum()) + modes_2d.num_failed == starts_2d.shape[0]
    np.testing.assert_allclose(
        modes_2d.log_densities, jax.vmap(logdensity_2d)(modes_2d.locations), rtol=1e-12
    )


def test_laplace_mixture_2d_weights_and_log_prob(starts_2d):
    mix = laplace_mixture(logdensity_2d, starts_2d, weights="laplace")
    assert isinstance(mix, Mixture) and mix.dim == 2
    assert all(isinstance(c, Gaussian) for c in mix.components)
    locs = np.stack([np.asarray(c.mean) for c in mix.components])
    idx, _ = _match_modes(locs, MEANS_2D)
    np.testing.assert_allclose(np.asarray(mix.weights), WEIGHTS_2D[idx], atol=1e-2)
    # The target is a well separated Gaussian mixture: the Laplace mixture is ~ exact.
    xs = np.concatenate([MEANS_2D + 0.5, MEANS_2D - 1.0])
    np.testing.assert_allclose(
        _batched_log_prob(mix, xs), jax.vmap(logdensity_2d)(jnp.asarray(xs)), atol=1e-3
    )
    # Student-t tails (same locations and scale matrices): heavier tails.
    heavy = laplace_mixture(logdensity_2d, starts_2d, weights="laplace", tails="student_t", df=4.0)
    assert all(isinstance(c, StudentT) for c in heavy.components)
    for c_t, c_g in zip(heavy.components, mix.components):
        np.testing.assert_allclose(c_t.loc, c_g.mean)
        np.testing.assert_allclose(c_t.scale, c_g.cov)
    for far in ([40.0, 40.0], [-100.0, 0.0], [0.0, -60.0]):
        lp_t, lp_g = _lp(heavy, jnp.array(far)), _lp(mix, jnp.array(far))
        assert np.isfinite(lp_t) and lp_t > lp_g + 50


def test_find_modes_drops_saddles():
    # Two maxima at (+-3, 0) and a saddle at the origin. Starts on the symmetry
    # line x0 = 0 converge to the saddle (zero gradient, indefinite Hessian) and
    # must be dropped.
    def logdensity(x):
        return jnp.logaddexp(
            -0.5 * jnp.sum((x - jnp.array([3.0, 0.0])) ** 2),
            -0.5 * jnp.sum((x + jnp.array([3.0, 0.0])) ** 2),
        )

    starts = np.array([[0.0, 0.0], [0.0, 2.0], [1.0, 1.0], [-0.5, 2.0]])
    modes = find_modes(logdensity, starts)
    assert modes.num_failed == 2 and modes.num_modes == 2
    locs = np.asarray(modes.locations)
    np.testing.assert_allclose(locs[np.argsort(locs[:, 0])], [[-3.0, 0.0], [3.0, 0.0]], atol=1e-6)


def test_mixture_from_modes_options(modes_2d):
    equal = mixture_from_modes(modes_2d)
    np.testing.assert_allclose(equal.weights, np.full(3, 1 / 3), rtol=1e-12)
    wide = mixture_from_modes(modes_2d, scale=2.0)
    np.testing.assert_allclose(wide.components[0].cov, 4 * modes_2d.covariances[0], rtol=1e-12)

    gauss = mixture_from_modes(modes_2d, tails="gaussian")
    heavy = mixture_from_modes(modes_2d, tails="student_t", df=3.0)
    assert all(isinstance(c, StudentT) for c in heavy.components)
    assert all(float(c.df) == 3.0 for c in heavy.components)
    np.testing.assert_allclose(heavy.components[1].loc, gauss.components[1].mean)
    np.testing.assert_allclose(heavy.components[1].scale, gauss.components[1].cov)
    far = jnp.array([60.0, -60.0])
    assert _lp(heavy, far) > _lp(gauss, far) + 100
    assert np.isfinite(_lp(heavy, far))

    defended = mixture_from_modes(modes_2d, weights="laplace", defensive=0.1)
    assert len(defended.components) == 4
    w = np.asarray(defended.weights)
    assert np.isclose(w[-1], 0.1) and np.isclose(w.sum(), 1.0)
    broad = defended.components[-1]
    lw = np.asarray(mixture_from_modes(modes_2d, weights="laplace").weights)
    mbar = lw @ np.asarray(modes_2d.locations)
    np.testing.assert_allclose(broad.mean, mbar, atol=1e-8)
    r = np.asarray(modes_2d.locations) - mbar
    ref_cov = np.einsum("k,ki,kj->ij", lw, r, r) + np.einsum("k,kij->ij", lw, modes_2d.covariances)
    np.testing.assert_allclose(broad.cov, ref_cov, rtol=1e-8)
    # Draws work through jit.
    draws = _sample(defended, KEY, 100)
    assert draws.shape == (100, 2) and np.all(np.isfinite(draws))


def test_merge_tol_zero_keeps_every_start(starts_2d):
    modes = find_modes(logdensity_2d, starts_2d, merge_tol=0.0)
    assert modes.num_modes == starts_2d.shape[0] - modes.num_failed > 3
    assert np.all(np.asarray(modes.counts) == 1)


def test_laplace_mixture_10d():
    d = 10
    means = np.zeros((4, d))
    means[0, 0], means[1, 0], means[2, 1], means[3, 2] = 7.0, -7.0, 7.0, -7.0
    w = np.array([0.4, 0.1, 0.3, 0.2])
    # A shared, correlated covariance (shared, so that far-away starts are not
    # all attracted by the broadest mode).
    a = np.random.default_rng(3).normal(size=(d, d)) / np.sqrt(d)
    cov = 0.3 * a @ a.T + 0.7 * np.eye(d)
    prec = np.linalg.inv(cov)

    def logdensity(x):
        r = x - means
        return logsumexp(jnp.log(w) - 0.5 * jnp.einsum("ki,ij,kj->k", r, prec, r))

    starts = jax.random.uniform(jax.random.key(2), (64, d), minval=-10.0, maxval=10.0)
    modes = find_modes(logdensity, starts)
    assert modes.num_modes == 4
    idx, err = _match_modes(modes.locations, means)
    assert sorted(idx.tolist()) == [0, 1, 2, 3]
    assert np.all(err < 1e-3)
    np.testing.assert_allclose(modes.covariances, np.broadcast_to(cov, (4, d, d)), atol=1e-2)
    mix = mixture_from_modes(modes, weights="laplace")
    np.testing.assert_allclose(mix.weights, w[idx], atol=1e-2)


def test_laplace_single_start_float32():
    # float32 starts are supported (default solver tolerance adapts to the dtype).
    def logdensity(x):
        mean = jnp.array([1.0, 2.0], x.dtype)
        var = jnp.array([1.0, 4.0], x.dtype)
        return -0.5 * jnp.sum((x - mean) ** 2 / var)

    mix = laplace_mixture(logdensity, np.array([[5.0, -5.0]], np.float32))
    comp = mix.components[0]
    assert comp.mean.dtype == jnp.float32
    np.testing.assert_allclose(comp.mean, [1.0, 2.0], atol=1e-3)
    np.testing.assert_allclose(comp.cov, np.diag([1.0, 4.0]), atol=1e-2)


def test_laplace_errors(starts_2d, modes_2d):
    with pytest.raises(ValueError, match="shape \\(n, d\\)"):
        laplace_mixture(logdensity_2d, np.zeros(2))
    with pytest.raises(ValueError, match="shape \\(n, d\\)"):
        laplace_mixture(logdensity_2d, np.zeros((0, 2)))
    with pytest.raises(ValueError, match="real floating scalar"):
        laplace_mixture(lambda x: -x**2, starts_2d)
    # A linear log density has no maximum: every start fails.
    with pytest.raises(ValueError, match="Widen the spread of `starts`"):
        laplace_mixture(lambda x: jnp.sum(x), starts_2d[:4], max_steps=16)
    with pytest.raises(ValueError, match="merge_tol"):
        find_modes(logdensity_2d, starts_2d, merge_tol=-1.0)
    with pytest.raises(ValueError, match="max_steps"):
        find_modes(logdensity_2d, starts_2d, max_steps=0)
    with pytest.raises(TypeError, match="solver"):
        find_modes(logdensity_2d, starts_2d, solver="bfgs")
    with pytest.raises(TypeError, match="LaplaceModes"):
        mixture_from_modes(np.zeros((3, 2)))
    for kwargs, match in [
        ({"tails": "cauchy"}, "tails"),
        ({"weights": "uniform"}, "weights"),
        ({"scale": 0.0}, "scale"),
        ({"df": -1.0}, "df"),
        ({"defensive": 1.0}, "defensive"),
        ({"defensive": 0.0}, "defensive"),
    ]:
        with pytest.raises(ValueError, match=match):
            mixture_from_modes(modes_2d, **kwargs)

    # Options are checked before any optimisation (no logdensity call at all).
    def boom(x):
        raise AssertionError("logdensity must not be called")

    with pytest.raises(ValueError, match="tails"):
        laplace_mixture(boom, starts_2d, tails="normal")
