"""PSS renderers against the exact image of `AnalyticImage`; metrics; input checks; the driver.

Convergence checks: `R` independent realisations (fixed keys) of each renderer; per
2x2-pixel block and channel, a t-test of the mean of the realisations against the exact
block mean, Bonferroni-corrected over the blocks. Negative controls (Restore with a
constant kill rate; a learned regeneration left out of the kill rate) must fail the same check.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import restore.render as rr
from restore.local import KelemenMutation, TorusH2MC, TorusMALA, WrappedGaussianMutation, metropolis_accept
from restore.regeneration import AbstractRegeneration
from restore.render._driver import _programs
from restore.render._renderer import host_params, host_tally
from targets import AnalyticImage

TARGET = AnalyticImage.default(dim=3, resolution=(8, 8), num_bumps=3)
EXACT = TARGET.exact_image()
R = 24  # independent realisations
ALPHA = 1e-3  # family-wise level of the block test


def realisations(renderer, lanes, steps, seed=0, target=TARGET, r=R):
    """`r` independent renders of `steps // 4` and of `steps` steps (fixed keys; one
    compilation: the step count is traced), and the statistics of the longer ones, each
    field as an array over the realisations."""

    @jax.jit
    def one(key, n):
        k_init, k_run, k_finish = jax.random.split(key, 3)
        state = renderer.run(target, k_run, renderer.init(target, k_init, lanes), n)
        state, _ = renderer.finish(target, k_finish, state)  # Restore's open tours (others: nothing)
        return renderer.image(target, state), (state.params, state.tally)

    keys = jax.random.split(jax.random.key(seed), r)
    early = np.stack([np.asarray(one(k, steps // 4)[0], np.float64) for k in keys])
    late, sums = zip(*(one(k, steps) for k in keys))
    records = [renderer.statistics(host_params(params), host_tally(tally)).as_dict() for params, tally in sums]
    statistics = {name: np.array([float(s[name]) for s in records]) for name in records[0]}
    return early, np.stack([np.asarray(im, np.float64) for im in late]), statistics


def blocks(images):
    """Sum 2x2 pixel blocks: `(..., 8, 8, 3) -> (..., 4, 4, 3)`."""
    shape = images.shape[:-3] + (4, 2, 4, 2, 3)
    return images.reshape(shape).sum(axis=(-4, -2))


def block_test(images, exact=EXACT):
    """Bonferroni-corrected p-value and the largest |t| of the block means against the truth."""
    b, truth = blocks(images), blocks(exact)
    t = (b.mean(0) - truth) / (b.std(0, ddof=1) / math.sqrt(len(b)))
    p = 2 * stats.t.sf(np.abs(t), df=len(b) - 1)
    return min(1.0, p.min() * p.size), float(np.abs(t).max())


def relative_error(images, exact=EXACT):
    return float(np.mean(np.sqrt(np.sum((images - exact) ** 2, axis=(1, 2, 3)) / np.sum(exact**2))))


LEARNED = rr.LearnedRegeneration(components=64, bandwidth=0.05)  # kernels about as wide as the bumps
RENDERERS = {  # (renderer, lanes, steps): a few million evaluations over the R realisations
    "metropolis_restore": (lambda: rr.MetropolisRestore(n_bootstrap=16384), 128, 640),  # complete tours, L = 1
    "metropolis_restore_learned": (lambda: rr.MetropolisRestore(n_bootstrap=16384, learned=LEARNED), 128, 640),
    "metropolis_restore_learned_open": (  # a stationary start, from the bootstrap weighted by lum + c q
        lambda: rr.MetropolisRestore(n_bootstrap=16384, learned=LEARNED, finish_tours=False), 128, 640,
    ),
    "mala_restore": (lambda: rr.MALARestore(2e-4, n_bootstrap=16384), 128, 320),
    "h2mc_restore": (lambda: rr.H2MCRestore(n_bootstrap=16384), 128, 320),
    "pssmlt": (lambda: rr.PSSMLT(n_bootstrap=16384), 128, 640),
    "mala": (lambda: rr.PSSMLT(TorusMALA(2e-4), n_bootstrap=16384), 128, 640),
    "h2mc": (lambda: rr.PSSMLT(TorusH2MC(), n_bootstrap=16384), 128, 320),
    "erpt": (lambda: rr.ERPT(chain_length=16), 128, 32),
    "uniform": (lambda: rr.UniformSampler(), 256, 320),
}


@pytest.fixture(scope="module")
def runs():
    return {}


def _run(runs, name):
    if name not in runs:
        make, lanes, steps = RENDERERS[name]
        runs[name] = realisations(make(), lanes, steps)
    return runs[name]


# ---------------------------------------------------------------------- the analytic image
def test_analytic_image_is_consistent():
    lum_weights = np.array([0.2126, 0.7152, 0.0722])
    # the image averages to the integral of rgb, whose luminance is Z
    assert np.isclose(EXACT.mean(axis=(0, 1)) @ lum_weights, TARGET.Z, rtol=1e-6)  # colours are float32
    u = jax.random.uniform(jax.random.key(0), (4096, 3), jnp.float32)
    lum, rgb, grad = jax.jit(lambda v: TARGET.jax_evaluate_with_grad(v))(u)
    assert lum.dtype == jnp.float32 and rgb.shape == (4096, 3) and grad.shape == (4096, 3)
    np.testing.assert_allclose(np.asarray(rgb) @ lum_weights, np.asarray(lum), rtol=1e-5)
    # gradient of log luminance against central differences (float64 evaluation by hand)
    x, e = np.asarray(u[:8], np.float64), 1e-3 * np.eye(3)
    log_lum = jax.jit(jax.vmap(lambda v: jnp.log(TARGET.jax_evaluate(v)[0])))
    fd = (log_lum(x[None] + e[:, None]) - log_lum(x[None] - e[:, None])) / 2e-3  # (D, 8)
    np.testing.assert_allclose(np.asarray(grad[:8]), np.asarray(fd).T, rtol=2e-2, atol=2e-2)
    draws = np.asarray(jax.jit(lambda k: TARGET.sample(k, 100_000))(jax.random.key(1)))
    assert draws.dtype == np.float32 and draws.min() >= 0 and draws.max() < 1
    counts = np.bincount(np.asarray(TARGET.pixel_index(draws)), minlength=64)
    expected = 100_000 * (EXACT @ lum_weights).ravel() / (64 * TARGET.Z)  # luminance per pixel / Z
    assert stats.chi2.sf(np.sum((counts - expected) ** 2 / expected), df=63) > ALPHA
    corners = jnp.array([[0.0, 0.0, 0.5], [0.99, 0.0, 0.5], [0.0, 0.99, 0.5], [0.13, 0.26, 0.0]])
    pix = np.asarray(TARGET.pixel_index(corners))
    np.testing.assert_array_equal(pix, [0, 7, 56, 1 + 8 * 2])


def test_analytic_image_rejects_bad_arguments():
    with pytest.raises(ValueError, match="widths"):
        AnalyticImage([[0.2, 0.3]], 0.3)
    with pytest.raises(ValueError, match="means"):
        AnalyticImage([0.2, 0.3], 0.1)
    with pytest.raises(ValueError, match="weights"):
        AnalyticImage([[0.2, 0.3]], 0.1, weights=[-1.0])
    with pytest.raises(ValueError, match="floor"):
        AnalyticImage([[0.2, 0.3]], 0.1, floor=-0.1)
    with pytest.raises(ValueError, match="resolution"):
        AnalyticImage([[0.2, 0.3]], 0.1, resolution=(0, 4))
    with pytest.raises(ValueError, match="separated"):
        AnalyticImage.default(num_bumps=8)


# ---------------------------------------------------------------------- convergence
@pytest.mark.parametrize("name", list(RENDERERS))
def test_renderer_converges_to_the_exact_image(runs, name):
    early, late, st = _run(runs, name)
    if name == "erpt":  # whole rounds: 128 seeds and chains each, 32 rounds
        assert np.all(st["seeds"] == 128 * 32) and np.all(st["chains"] == 128 * 32)
    p_value, t_max = block_test(late)
    assert p_value > ALPHA, f"{name}: Bonferroni p = {p_value:.2g}, max |t| = {t_max:.2f}"
    e_early, e_late = relative_error(early), relative_error(late)
    assert e_late < 0.7 * e_early, f"{name}: relative error {e_early:.4f} -> {e_late:.4f} with 4x the steps"


def test_restore_tour_length_and_normalising_constant_agree_with_theory(runs):
    _, _, st = _run(runs, "metropolis_restore")
    # mean tour duration (local moves per tour) is Z / c, so c times it estimates Z
    z = st["z_estimate"]
    t = (z.mean() - TARGET.Z) / (z.std(ddof=1) / math.sqrt(R))
    assert abs(t) < 4.0, f"Z estimate {z.mean():.4f} vs {TARGET.Z:.4f} (t = {t:.2f})"
    ratio = st["mean_tour_length"] * st["rate"] / TARGET.Z  # measured / theoretical Z / c
    assert abs(ratio.mean() - 1) < 0.03
    # c = Z_hat / L (L = 1): tours last L moves up to the bootstrap error of Z_hat
    np.testing.assert_allclose(st["rate"], st["z_bootstrap"], rtol=1e-5)
    # complete tours: every tour started was finished; about 640 / 2 tours per lane
    np.testing.assert_array_equal(st["tours_started"], st["tours_completed"])
    assert np.all(st["tours_per_lane"] > 250) and np.all(st["acceptance_rate"] > 0.5)


def test_pssmlt_estimates_z_from_its_bootstrap_and_large_steps(runs):
    _, _, st = _run(runs, "pssmlt")
    z = st["z_hat"]
    t = (z.mean() - TARGET.Z) / (z.std(ddof=1) / math.sqrt(R))
    assert abs(t) < 4.0, f"Z estimate {z.mean():.4f} vs {TARGET.Z:.4f} (t = {t:.2f})"
    # 128 lanes x 640 steps x 0.3 large steps = 24576 more uniform draws than the 16384 of the bootstrap
    assert np.all(st["z_hat_relative_error"] < 0.7 * st["z_bootstrap_relative_error"])
    assert z.std() < 0.8 * st["z_bootstrap"].std()


class MislabelledTorus(AbstractRegeneration):
    """Uniform draws on the torus whose claimed density is `lum / Z` instead of 1."""

    dim: int

    def sample(self, key, shape=()):
        return jax.random.uniform(key, tuple(shape) + (self.dim,), jnp.float32)

    def log_prob(self, x):
        return jnp.log(TARGET.jax_evaluate(x[None])[0][0] / TARGET.Z)


class ConstantRateRestore(rr.MetropolisRestore):
    """Negative control: a regeneration density that does not match its draws turns the kill
    rate `c q / p = c / lum` into the constant `c / Z`."""

    def regeneration(self, target, params):
        return MislabelledTorus(target.dim)


class KernelDrawsUniformDensity(AbstractRegeneration):
    """Draws of a learned regeneration whose claimed density is the uniform's: the kill rate
    leaves `q` out."""

    drawn: AbstractRegeneration
    dim: int

    def sample(self, key, shape=()):
        return self.drawn.sample(key, shape)

    def log_prob(self, x):
        return jnp.zeros((), x.dtype)


class LearnedDrawsUniformKill(rr.MetropolisRestore):
    """Negative control: tours start at the learned regeneration's draws but are killed at the
    uniform's rate `c / lum`."""

    def regeneration(self, target, params):
        return KernelDrawsUniformDensity(drawn=super().regeneration(target, params), dim=target.dim)


def test_negative_control_constant_kill_rate_is_rejected():
    _, late, _ = realisations(ConstantRateRestore(tour_length=16, n_bootstrap=16384), 128, 320, r=12)
    p_value, t_max = block_test(late)
    assert p_value < 1e-6, f"the wrong kill rate passed: p = {p_value:.2g}, max |t| = {t_max:.1f}"


def test_negative_control_learned_regeneration_left_out_of_the_kill_rate_is_rejected():
    _, late, _ = realisations(LearnedDrawsUniformKill(n_bootstrap=16384, learned=LEARNED), 128, 640)
    p_value, t_max = block_test(late)
    assert p_value < 1e-6, f"a kill rate without q passed: p = {p_value:.2g}, max |t| = {t_max:.1f}"


def test_restore_renders_run_a_sampler_that_knows_its_tour_length():
    """With `c = Z_hat / L` the core sampler is made from `L` (so at `L = 1` it draws the next
    tours' starts for all lanes at once) and has the render's `log c` bit for bit; with `c`
    given it has that `c` and no tour length."""
    cases = [
        (rr.MetropolisRestore(KelemenMutation(), tour_length=1.0), (1.0,), 0.5),
        (rr.MetropolisRestore(KelemenMutation(), rate=0.5), None, None),
    ]
    for renderer, length, kill_share in cases:
        params = renderer.init(TARGET, jax.random.key(0), 64).params
        sampler = renderer.sampler(TARGET, params)
        assert sampler.tour_length == length
        assert sampler._kill_fraction() == kill_share
        assert np.asarray(sampler.log_rate).tobytes() == np.asarray(params.log_rate).tobytes()


def test_open_tours_from_a_uniform_start_show_their_finite_run_bias():
    """Starting every lane at a tour start (uniform draw) and stopping at the budget leaves a
    bias of order (bright-region sojourn) / (steps per lane): long tours in bright bumps are
    still running when the budget ends. Finishing them (complete tours, the default, as in
    `RENDERERS`) removes it; the block test must see the difference."""
    renderer = rr.MetropolisRestore(tour_length=16, n_bootstrap=16384, start="uniform", finish_tours=False)
    _, late, st = realisations(renderer, 128, 640, r=12)
    p_value, t_max = block_test(late)
    assert p_value < 1e-6 and late.mean(0).sum() < 0.9 * EXACT.sum(), (p_value, t_max)


class UncorrectedMALA(TorusMALA):
    """Negative control: torus MALA without its Hastings term."""

    def accept(self, key, point, candidate, aux):
        return metropolis_accept(key, point, candidate, candidate.logdensity - point.logdensity)


class H2MCWithoutReverse(TorusH2MC):
    """Negative control: H2MC accepted on the luminance alone, the reverse move's Gaussian left out."""

    def accept(self, key, point, candidate, aux):
        return metropolis_accept(key, point, candidate, candidate.logdensity - point.logdensity)


def pixel_law_p_value(kernel, n=8192, moves=30):
    """From exact draws, `moves` moves of `kernel` on every point; the chi-squared p-value of
    the final pixel histogram against the exact luminance-per-pixel law."""
    logdensity = lambda u: rr.pss_logdensity(TARGET)(u)[0]  # noqa: E731

    @jax.jit
    def final_pixels(key):
        def step(i, x):
            k_move, k_accept = jax.random.split(jax.random.fold_in(key, i))
            keys_move, keys_accept = jax.random.split(k_move, n), jax.random.split(k_accept, n)
            candidates, aux = jax.vmap(lambda k, p: kernel.propose(k, p, logdensity))(keys_move, x)
            y = rr.evaluate_points(TARGET, candidates, kernel=kernel)
            return jax.vmap(lambda k, p, q, a: kernel.accept(k, p, q, a)[0])(keys_accept, x, y, aux)

        start = rr.evaluate_points(TARGET, TARGET.sample(jax.random.fold_in(key, 10**6), n), kernel=kernel)
        return TARGET.pixel_index(jax.lax.fori_loop(0, moves, step, start).position)

    counts = np.bincount(np.asarray(final_pixels(jax.random.key(0))), minlength=64)
    expected = n * (EXACT @ [0.2126, 0.7152, 0.0722]).ravel() / (64 * TARGET.Z)
    return stats.chi2.sf(np.sum((counts - expected) ** 2 / expected), df=63)


@pytest.mark.parametrize("kernel, passes", [(TorusMALA(0.01), True), (UncorrectedMALA(0.01), False)])
def test_wrapped_mala_kernel_leaves_the_luminance_invariant(kernel, passes):
    """30 MALA moves with a step (sqrt(2h) = 0.14) large enough to wrap around the torus
    must keep exact draws on the exact luminance-per-pixel law."""
    p_value = pixel_law_p_value(kernel)
    assert (p_value > ALPHA) if passes else (p_value < 1e-10), p_value


@pytest.mark.parametrize(
    "kernel, passes",
    [(TorusH2MC(0.05), True), (TorusH2MC(0.01), True), (H2MCWithoutReverse(0.05), False), (H2MCWithoutReverse(0.01), False)],
)
def test_h2mc_kernel_leaves_the_luminance_invariant(kernel, passes):
    """30 H2MC moves, at its authors' bound (sigma = 0.01) and at the largest one allowed,
    must keep exact draws on the exact law; without the reverse move's Gaussian they must not."""
    p_value = pixel_law_p_value(kernel)
    assert (p_value > ALPHA) if passes else (p_value < 1e-10), p_value


# ---------------------------------------------------------------------- metrics
def test_metrics_on_hand_computed_arrays():
    reference = np.array([[1.0, 2.0], [0.0, 4.0]])
    image = np.array([[2.0, 2.0], [1.0, 2.0]])
    assert rr.l1(image, reference) == pytest.approx((1 + 0 + 1 + 2) / 4)
    assert rr.mse(image, reference) == pytest.approx((1 + 0 + 1 + 4) / 4)
    expected = (1 / (1 + 0.01) + 0 + 1 / 0.01 + 4 / (16 + 0.01)) / 4
    assert rr.relative_mse(image, reference) == pytest.approx(expected)
    assert rr.relative_mse(image, reference, eps=1.0) == pytest.approx((1 / 2 + 0 + 1 + 4 / 17) / 4)
    # strict relative metrics leave the zero reference pixel out
    assert rr.mrse(image, reference) == pytest.approx((1 + 0 + 0.25) / 3)
    assert rr.mape(image, reference) == pytest.approx(100 * (1 + 0 + 0.5) / 3)
    stack = np.stack([image, reference, 2 * image])
    assert rr.variance_across(stack) == pytest.approx(np.mean(np.var(stack, axis=0, ddof=1)))
    assert rr.variance_across([[1.0, 3.0], [3.0, 5.0]]) == pytest.approx(2.0)
    # the variance relative to the reference: [[1, 3], [3, 5]] has variance 2 per element
    assert rr.relative_variance([[1.0, 3.0], [3.0, 5.0]], [1.0, 0.0]) == pytest.approx((2 / 1.01 + 2 / 0.01) / 2)
    with pytest.raises(ValueError, match="two realisations"):
        rr.relative_variance(image[None], reference)
    with pytest.raises(ValueError, match="zero"):
        rr.mrse(image, np.zeros_like(reference))
    with pytest.raises(ValueError, match="shapes"):
        rr.mse(image, reference[0])
    with pytest.raises(ValueError, match="two realisations"):
        rr.variance_across(image[None])
    with pytest.raises(ValueError, match="eps"):
        rr.relative_mse(image, reference, eps=0.0)


# ---------------------------------------------------------------------- inputs
def test_bad_inputs_raise_clear_errors():
    key = jax.random.key(0)
    with pytest.raises(ValueError, match="tour_length"):
        rr.MetropolisRestore(tour_length=0)
    with pytest.raises(ValueError, match="tour_length"):
        rr.MALARestore(tour_length=-3.0)
    with pytest.raises(ValueError, match="rate"):
        rr.MetropolisRestore(rate=0.0)
    with pytest.raises(ValueError, match="start"):
        rr.MetropolisRestore(start="somewhere")
    with pytest.raises(ValueError, match="p_large"):
        rr.PSSMLT(p_large=0.0)
    with pytest.raises(ValueError, match="p_large"):
        rr.PSSMLT(p_large=1.5)
    with pytest.raises(ValueError, match="n_bootstrap"):
        rr.PSSMLT(n_bootstrap=1)
    with pytest.raises(ValueError, match="chain_length"):
        rr.ERPT(chain_length=0)
    with pytest.raises(ValueError, match="chains_per_seed"):
        rr.ERPT(chains_per_seed=-1)
    with pytest.raises(ValueError, match="s1 < s2"):
        KelemenMutation(s1=0.1, s2=0.01)
    with pytest.raises(ValueError, match="sigma"):
        WrappedGaussianMutation(0.0)
    with pytest.raises(ValueError, match="step_size"):
        rr.MALARestore(step_size=1.0)
    renderer = rr.UniformSampler()
    with pytest.raises(ValueError, match="seconds"):
        rr.render(TARGET, renderer, key=key, seconds=-1.0)
    with pytest.raises(ValueError, match="budget"):
        rr.render(TARGET, renderer, key=key)
    with pytest.raises(ValueError, match="lanes"):
        rr.render(TARGET, renderer, key=key, evaluations=100, num_lanes=0)
    with pytest.raises(ValueError, match="evaluations"):
        rr.render(TARGET, renderer, key=key, evaluations=0)
    with pytest.raises(ValueError, match="chunk"):
        rr.render(TARGET, renderer, key=key, evaluations=100, chunk=0)
    with pytest.raises(ValueError, match="does not cover"):
        rr.render(TARGET, rr.PSSMLT(n_bootstrap=4096), key=key, evaluations=4096, num_lanes=64)
    with pytest.raises(TypeError, match="not a PSS target"):
        rr.render(object(), renderer, key=key, evaluations=100)
    with pytest.raises(TypeError, match="renderer"):
        rr.render(TARGET, object(), key=key, evaluations=100)


def test_black_target_is_reported_not_rendered_as_nan():
    black = AnalyticImage([[0.5, 0.5, 0.5]], 0.01, floor=0.0)  # lum underflows to 0 far from the bump
    tiny = rr.MetropolisRestore(n_bootstrap=2)
    state = jax.jit(lambda k: tiny.init(black, k, 2))(jax.random.key(3))
    with pytest.raises(ValueError, match="zero luminance"):
        tiny.check(host_params(state.params))
    # zero-luminance lanes are killed at once, splat nothing and never produce NaN
    renderer = rr.MetropolisRestore(rate=1.0, start="uniform")
    run = jax.jit(lambda k: renderer.run(black, k, renderer.init(black, k, 64), 20))
    tally = run(jax.random.key(0)).tally
    assert np.all(np.isfinite(np.asarray(tally.film))) and int(tally.kills) > 0.9 * 64 * 20


# ---------------------------------------------------------------------- the driver
def test_driver_stops_on_the_evaluation_budget_and_reports_progress():
    updates = []
    renderer = rr.MetropolisRestore(tour_length=8, n_bootstrap=1000, finish_tours=False)
    lanes = 256
    budget = renderer.init_cost(lanes) + 37 * lanes
    result = rr.render(
        TARGET, renderer, key=jax.random.key(0), evaluations=budget, num_lanes=lanes, chunk=10, progress=False,
        on_update=lambda image, st: updates.append((image.shape, st.tours_completed)),
    )
    assert result.evaluations == budget and result.steps == 37
    assert len(updates) == 4 and all(shape == (8, 8, 3) for shape, _ in updates)
    assert [t for _, t in updates] == sorted(t for _, t in updates)  # progressive: tours accumulate
    assert result.image.shape == (8, 8, 3) and result.image.dtype == np.float32
    assert np.all(np.isfinite(result.image)) and result.compile_seconds > 0 and result.seconds > 0
    assert isinstance(result.statistics, rr.RestoreStatistics) and result.statistics.tours_completed == updates[-1][1]
    # a budget that is not a whole number of steps is never exceeded
    odd = rr.render(TARGET, rr.UniformSampler(), key=jax.random.key(1), evaluations=1000, num_lanes=64, progress=False)
    assert odd.evaluations == 960 and odd.steps == 15


@pytest.mark.parametrize("lanes, speculative", [(512, True), (4096, True), (512, False)])
def test_driver_finishes_every_open_tour_in_smaller_batches(lanes, speculative, monkeypatch):
    """Complete tours: after the budget no tour starts, the open ones run on (each finishing
    step evaluating a quarter of the lanes' worth of points, or less once few tours are
    open: down to 256 for speculative steps, to 8 for plain steps of the open lanes) and
    every tour started is counted once, finished."""
    import restore.render._driver as driver

    used = []

    def rung(finishers, still_open):
        chosen = driver_rung(finishers, still_open)
        used.append((still_open, chosen[0]))
        return chosen

    driver_rung = driver._rung
    monkeypatch.setattr(driver, "_rung", rung)
    if speculative:
        renderer = rr.MetropolisRestore(tour_length=8, n_bootstrap=1000)
    else:
        renderer = rr.MALARestore(2e-4, tour_length=8, n_bootstrap=1000)
    updates: list[float] = []
    budget = renderer.init_cost(lanes) + 40 * lanes
    result = rr.render(TARGET, renderer, key=jax.random.key(3), evaluations=budget, num_lanes=lanes, chunk=10,
                       progress=False, on_update=lambda image, st: updates.append(st.tours_completed))
    st = result.statistics
    assert isinstance(st, rr.RestoreStatistics) and result.steps == 40 and result.finishing_steps > 0
    assert st.tours_started == st.tours_completed == updates[-1] and len(updates) == 5
    # each call ran on the smallest batch holding its open tours (4096 lanes: 1024, then 256)
    rungs = driver.finishing_rungs(lanes, renderer.smallest_finishing_batch())
    assert rungs == {(512, True): (128,), (4096, True): (1024, 256), (512, False): (128, 32, 8)}[lanes, speculative]
    assert all(slots == min([r for r in rungs if r >= n] or [rungs[0]]) for n, slots in used)
    assert {slots for _, slots in used} == set(rungs)
    # finishing steps of the smaller batches cost less than a full step each
    assert budget < result.evaluations <= budget + result.finishing_steps * lanes // 4
    assert np.all(np.isfinite(result.image)) and result.image.sum() > 0


def test_finishing_batches_shrink_by_quarters():
    from restore.render._driver import finishing_rungs, finishing_slots

    assert finishing_rungs(16384) == (4096, 1024, 256) and finishing_slots(16384) == 4096
    assert finishing_rungs(2048) == (512,) and finishing_rungs(100) == (64,) and finishing_rungs(32) == (32,)
    assert finishing_rungs(2048, 8) == (512, 128, 32, 8) and finishing_rungs(100, 8) == (64, 16)


@pytest.mark.parametrize("renderer", [rr.MetropolisRestore(n_bootstrap=1000), rr.MALARestore(2e-4, n_bootstrap=1000)])
def test_a_finishing_step_moves_only_open_tours(renderer):
    """Finishing shares `slots` evaluations among the open lanes (speculative steps: trees for
    the Metropolis small step, the reject path for MALA); closed lanes keep their state and
    nothing of theirs is counted."""
    state = jax.jit(lambda k: renderer.init(TARGET, k, 16))(jax.random.key(0))
    open_lanes = np.zeros(16, bool)
    open_lanes[[1, 5, 6, 12]] = True
    state = renderer.stop_starting(state._replace(in_tour=jnp.asarray(open_lanes), tour_moves=jnp.arange(16, dtype=jnp.int32)))
    after, steps = jax.jit(lambda k, s: renderer.finish(TARGET, k, s, 1, 8))(jax.random.key(1), state)
    assert int(steps) == 1
    closed = ~open_lanes
    np.testing.assert_array_equal(np.asarray(after.lanes.position)[closed], np.asarray(state.lanes.position)[closed])
    np.testing.assert_array_equal(np.asarray(after.tour_moves)[closed], np.arange(16)[closed])
    assert not np.any(np.asarray(after.in_tour)[closed])
    moves = np.asarray(after.tour_moves)[open_lanes]
    events = int(after.tally.lane_steps)
    assert int(after.tally.local_moves) + int(after.tally.kills) == events and events >= 4
    # an open lane either ended its tour (moves reset) or made at least one more move
    assert np.all((moves == 0) | (moves > np.array([1, 5, 6, 12])))


@pytest.mark.filterwarnings("ignore::restore.UnreliableEstimateWarning")  # few tours in a short render
def test_a_repeated_render_reuses_its_compiled_programs():
    """A second render of the same set-up (the same target object, an equal renderer, the
    same lanes) compiles nothing and gives the image a first render gives; another target,
    other lanes or another renderer get programs of their own."""
    from restore._compile import _has_emitter_choice

    compiled = []

    def listen(event, duration, **kwargs):
        if event.endswith("backend_compile_duration"):
            compiled.append(kwargs.get("fun_name"))

    target = AnalyticImage.default(dim=3, resolution=(8, 8), num_bumps=2)  # a set-up of this test alone
    lanes = 128
    _has_emitter_choice()  # its one probe compilation per process, whichever test comes first

    def run(renderer, seed=0):
        compiled.clear()
        result = rr.render(
            target, renderer, key=jax.random.key(seed), evaluations=renderer.init_cost(lanes) + 30 * lanes,
            num_lanes=lanes, chunk=10, progress=False,
        )
        return result, sum("<lambda>" in str(f) for f in compiled)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        first, fresh = run(rr.MetropolisRestore(tour_length=8, n_bootstrap=1000))
        again, reused = run(rr.MetropolisRestore(tour_length=8, n_bootstrap=1000))  # an equal renderer
        other_key, _ = run(rr.MetropolisRestore(tour_length=8, n_bootstrap=1000), seed=1)
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert fresh == 3 and first.finishing_steps > 0  # the start, the chunk and the finisher
    assert reused == 0 and again.compile_seconds < first.compile_seconds / 5
    np.testing.assert_array_equal(again.image, first.image)
    assert again.statistics == first.statistics and again.finishing_steps == first.finishing_steps
    assert not np.array_equal(other_key.image, first.image)
    # what makes a set-up its own: the entry of the renders above, found again, and new ones
    renderer, key = rr.MetropolisRestore(tour_length=8, n_bootstrap=1000), jax.random.key(0)

    def entry(renderer=renderer, target=target, lanes=lanes):
        shape = jax.eval_shape(lambda k: renderer.init(target, k, lanes), key)
        return _programs(renderer, target, lanes, key, shape)

    assert entry().chunk is not None and entry() is entry()
    equal_target = AnalyticImage.default(dim=3, resolution=(8, 8), num_bumps=2)
    others = [entry(lanes=64), entry(renderer=rr.MetropolisRestore(tour_length=4, n_bootstrap=1000)), entry(target=equal_target)]
    assert all(other.chunk is None for other in others)


def test_driver_time_budget():
    result = rr.render(TARGET, rr.UniformSampler(), key=jax.random.key(2), seconds=0.3, num_lanes=256, progress=True)
    assert result.seconds >= 0.3 and result.seconds < 5 and result.steps > 0
    assert result.evaluations == 256 * result.steps
    # an ERPT step is a round: B seeds and M mutations of each of the `lanes` chains
    assert rr.ERPT(chain_length=4).step_cost(64) == 64 + 4 * 64
    assert rr.ERPT(chain_length=4, chains_per_seed=2).step_cost(64) == 32 + 4 * 64


def test_ctrl_c_keeps_the_finished_chunks():
    calls = []

    def interrupt_on_second_update(image, stats):
        calls.append(stats.tours_completed)
        if len(calls) == 2:
            raise KeyboardInterrupt

    renderer = rr.MetropolisRestore(tour_length=8, n_bootstrap=1000)
    result = rr.render(TARGET, renderer, key=jax.random.key(5), evaluations=10**9, num_lanes=256, chunk=10,
                       progress=False, on_update=interrupt_on_second_update)
    assert result.interrupted and result.steps == 20 and len(calls) == 2
    assert np.all(np.isfinite(result.image)) and result.image.sum() > 0
