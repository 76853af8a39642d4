"""Speculative jump-Restore steps finish tours with the law of plain steps.

Each tour started at a regeneration draw has expected Rao-Blackwellised integral
`E[sum hold h(x)] = (1 / c) int p h` (the regenerative identity behind every Restore
estimate). Tours run to their end by speculative steps must meet it for several `h`; a
negative control that replays the speculated events after a rejection (as if the rejected
candidate had been taken) must fail the same test.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore.local import MALA, RandomWalk
from restore.regeneration import Gaussian

# unnormalised mixture 0.3 N(-1.5, 0.4^2) + 0.7 N(1, 0.6^2), Z = sqrt(2 pi) (0.3 * 0.4 + 0.7 * 0.6)
WEIGHTS, MEANS, SDS = np.array([0.3, 0.7]), np.array([-1.5, 1.0]), np.array([0.4, 0.6])
Z = float(np.sqrt(2 * np.pi) * np.sum(WEIGHTS * SDS))
MOMENTS = np.array(
    [np.sum(WEIGHTS * SDS), np.sum(WEIGHTS * SDS * MEANS), np.sum(WEIGHTS * SDS * (MEANS**2 + SDS**2))]
) / np.sum(WEIGHTS * SDS)
LOG_RATE = float(np.log(Z / 6.0))  # tours of about 6 time units


def logp(x):
    z = (x[0] - MEANS) / SDS
    return jax.nn.logsumexp(jnp.log(WEIGHTS) - 0.5 * z**2)


SAMPLER = restore.JumpRestore(logp, RandomWalk(0.5), Gaussian(jnp.zeros(1), 4.0), log_rate=LOG_RATE)


def finish_tours(key, sampler=SAMPLER, lanes: int = 8192, slots: int = 32768, acceptance: float = 0.5):
    """`_finish_tours`, compiled once per sampler structure and shape."""
    return _compiled(sampler, key, jnp.float32(acceptance), lanes, slots)


def _finish_tours(sampler, key, acceptance, lanes, slots):
    """Start `lanes` tours and run them all to their end by speculative steps (trees shaped for
    `acceptance`); per tour the sums of `hold x (1, x, x^2)`, counted from the replayed events
    and, for the negative control, along the accepted branches alone (as if every candidate
    had been accepted)."""
    k_init, k_run = jax.random.split(key)
    states = jax.vmap(sampler.init)(jax.random.split(k_init, lanes))
    zero = jnp.zeros((lanes, 3))

    def body(carry):
        i, states, active, sums, wrong, calls_events = carry
        run = restore.speculative_steps(sampler, jax.random.fold_in(k_run, i), states, active, slots, acceptance)
        x = run.info.position[:, 0]
        h = run.info.expected_holding_time[:, None] * jnp.stack([jnp.ones_like(x), x, x**2], axis=1)
        sums = sums.at[run.lane].add(jnp.where(run.valid[:, None], h, 0.0))

        def accept_all(t, reached):  # broken replay: ignore the acceptance test
            follows = reached[run.parent] & ~run.info.regenerated[run.parent] & run.accepted_branch
            return jnp.where(run.level == t, follows, reached)

        roots = run.valid & (run.level == 0)
        broken = jax.lax.fori_loop(1, jnp.max(run.level) + 1, accept_all, roots)
        wrong = wrong.at[run.lane].add(jnp.where(broken[:, None], h, 0.0))
        return i + 1, run.states, run.active, sums, wrong, calls_events + jnp.array([1, jnp.sum(run.valid)], jnp.int32)

    init = (0, states, jnp.ones(lanes, bool), zero, zero, jnp.zeros(2, jnp.int32))
    _, _, active, sums, wrong, calls_events = jax.lax.while_loop(lambda c: jnp.any(c[2]), body, init)
    return sums, wrong, calls_events, active


_compiled = eqx.filter_jit(_finish_tours)


def z_scores(sums):
    """`c` times the mean tour sum against `int p h = Z E_p[h]`, in standard errors."""
    c = np.exp(LOG_RATE)
    per_tour = c * np.asarray(sums, np.float64)
    mean, se = per_tour.mean(0), per_tour.std(0, ddof=1) / np.sqrt(len(per_tour))
    return (mean - Z * MOMENTS) / se


MALA_SAMPLER = restore.JumpRestore(logp, MALA(0.8), Gaussian(jnp.zeros(1), 4.0), log_rate=LOG_RATE)


@pytest.fixture(scope="module")
def finished():
    return [finish_tours(jax.random.key(seed), acceptance=a) for seed, a in enumerate([0.5, 0.1, 0.9])]


@pytest.fixture(scope="module")
def finished_mala():
    """MALA's candidate needs the gradient: its lanes speculate along the reject path alone."""
    return finish_tours(jax.random.key(5), MALA_SAMPLER, lanes=8192, slots=16384)


def test_speculative_tours_have_the_regenerative_integral(finished):
    for sums, _, _, active in finished:
        assert not bool(jnp.any(active))
        assert np.all(np.abs(z_scores(sums)) < 4), z_scores(sums)
    pooled = np.concatenate([np.asarray(s) for s, *_ in finished])
    assert np.all(np.abs(z_scores(pooled)) < 4)


def test_speculative_mala_tours_have_the_regenerative_integral(finished_mala):
    sums, _, (calls, events), active = finished_mala
    assert not bool(jnp.any(active))
    assert np.all(np.abs(z_scores(sums)) < 4), z_scores(sums)


def test_replaying_events_after_a_rejection_fails(finished):
    """Negative control: the same trees, replayed as if every candidate had been accepted."""
    pooled = np.concatenate([np.asarray(w) for _, w, _, _ in finished])
    assert np.max(np.abs(z_scores(pooled))) > 8  # measured 11.8


@pytest.mark.parametrize(
    ("scale", "guess", "at_least"), [(0.1, 0.9, 10), (0.1, 0.5, 4), (0.1, 0.1, 1.5), (5.0, 0.1, 5), (5.0, 0.9, 1.5)]
)
def test_a_call_advances_a_lane_by_many_events(scale, guess, at_least):
    """One long open tour with 64 slots: several events per batched evaluation, most when the
    tree fits the acceptance (about 0.9 with small steps, low with large ones); measured
    15 / 6.7 / 2.2 events per call for small steps and guesses 0.9 / 0.5 / 0.1."""
    long_tours = restore.JumpRestore(logp, RandomWalk(scale), Gaussian(jnp.zeros(1), 4.0), log_rate=float(np.log(Z / 3000)))
    _, _, (calls, events), _ = finish_tours(jax.random.key(7), long_tours, lanes=1, slots=64, acceptance=guess)
    assert int(events) > at_least * int(calls)


@pytest.mark.parametrize(("step", "at_least", "at_most"), [(5.0, 3, 64), (0.05, 1, 1.2)])
def test_a_gradient_kernel_speculates_along_the_reject_path(step, at_least, at_most):
    """MALA's candidates after an acceptance would need the accepted point's gradient, so a
    lane's tree is the reject path alone: many events per call where most moves are rejected
    (large steps), about one where most are accepted (small steps); no event follows an
    accepted candidate within a call."""
    long_tours = restore.JumpRestore(logp, MALA(step), Gaussian(jnp.zeros(1), 4.0), log_rate=float(np.log(Z / 3000)))
    states = jax.vmap(long_tours.init)(jax.random.split(jax.random.key(0), 1))
    run = restore.speculative_steps(long_tours, jax.random.key(1), states, jnp.ones(1, bool), 64)
    assert not bool(jnp.any(run.accepted_branch)) and bool(jnp.all(run.parent[1:] == jnp.arange(63)))
    _, _, (calls, events), _ = finish_tours(jax.random.key(7), long_tours, lanes=1, slots=64)
    assert at_least * int(calls) < int(events) <= at_most * int(calls)
