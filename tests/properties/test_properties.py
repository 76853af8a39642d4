"""Property-based tests of input handling: every call works or fails clearly (README, "Bad input").

For random settings, shapes, dtypes, log densities and regeneration distributions, a call
either works (and then its estimates are finite) or raises a `ValueError`/`TypeError`
whose message names the offending argument: never a hang, an error from deep inside XLA,
or a silent NaN. NaN or `+inf` log densities are zero density, counted and warned about;
a regeneration distribution that misses the target fails the pilot; outputs are written
atomically.

Run time: JAX compiles once per new structure, shape and dtype, so the properties that
run the sampler share a few compiled programs: dimension 2, fixed lane and step counts,
and log densities, rates and regeneration boxes held as array leaves of pytrees (new
examples are new values, not new programs). Most properties only construct objects or
trace with `jax.eval_shape`, which compiles nothing. Examples are derandomized (fixed).
"""

from __future__ import annotations

import errno
import math
import os
import re
import warnings
from pathlib import Path
from types import SimpleNamespace
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import restore
from restore._io import atomic_write
from restore.local import HMC, MALA, RandomWalk
from restore.regeneration import Gaussian, Mixture, StudentT, UniformBox

#: Constructing objects and tracing shapes: cheap, many examples.
CHEAP = settings(derandomize=True, database=None, deadline=None, max_examples=60,
                 suppress_health_check=[HealthCheck.too_slow])
#: Writing files with monkeypatched writers (a fresh `monkeypatch.context()` per example).
FILES = settings(CHEAP, max_examples=25, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
#: Running the sampler: each example is a short run of an already compiled program; the
#: first example of each structure pays the compilation, hence too_slow is suppressed.
RUNS = settings(derandomize=True, database=None, deadline=None, max_examples=12,
                suppress_health_check=[HealthCheck.too_slow])

LANES, STEPS = 8, 60  # every run below has these sizes, so runs share compiled programs
KEY = jax.random.key(0)


def std_normal(x):
    return -0.5 * jnp.sum(x**2)


def assert_names(error: BaseException, *names: str) -> None:
    """The error is a ValueError/TypeError and its message names one of `names`."""
    assert isinstance(error, (ValueError, TypeError)), repr(error)
    message = str(error)
    assert "unexpected keyword argument" not in message, message  # a misspelt argument is no check of its value
    assert any(name in message for name in names), f"{names} not in: {message}"


def outcome(fn):
    """`(value, None)` if `fn()` works, `(None, error)` if it raises ValueError/TypeError."""
    try:
        return fn(), None
    except (ValueError, TypeError) as error:
        return None, error


# --------------------------------------------------------------------------- strategies

#: Scalars good and bad: zero, negatives, NaN, infinities, huge and tiny values, bools,
#: strings, None, vectors, nested lists, NumPy scalars and arrays, complex numbers.
JUNK = [True, False, None, "a", "1.0", [0.5], [0.5, 1.0], [[1.0]], np.float32(0.5), np.float16(2.0),
        np.int64(3), np.array(0.5), np.array([0.5, np.nan]), 1 + 2j, np.complex64(1.0), object()]
numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, -1.0, math.nan, math.inf, -math.inf, 1e300, -1e300, 1e-300, 5e-324]),
    st.integers(-3, 5),
    st.sampled_from(JUNK),
)


def as_real_array(value):
    """The value as a NumPy array if it is a real number or array of them (not bool), else None."""
    if isinstance(value, (bool, np.bool_, str, bytes)) or value is None:
        return None
    try:
        arr = np.asarray(value)
    except Exception:
        return None
    return arr if arr.dtype.kind in "iuf" else None


def positive_scalar(value) -> bool:
    arr = as_real_array(value)
    return arr is not None and arr.ndim == 0 and bool(np.isfinite(arr)) and float(arr) > 0


def positive_integer(value, minimum: int) -> bool:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        return False
    return math.isfinite(value) and int(value) == value and value >= minimum


# --------------------------------------------------------------------------- kernel and rate settings


@CHEAP
@given(kind=st.sampled_from(["RandomWalk", "MALA", "HMC"]), value=numbers, dim=st.sampled_from([1, 2, 3]))
@example(kind="RandomWalk", value=[0.5, 1.0], dim=3)  # a vector of the wrong length
@example(kind="HMC", value=[0.5, 1.0], dim=2)  # HMC's step size is a scalar
@example(kind="RandomWalk", value=5e-324, dim=1)  # subnormal: zero to XLA, whatever the host made of it
def test_kernel_step_sizes_are_checked(kind, value, dim):
    name = {"RandomWalk": "scale", "MALA": "step_size", "HMC": "step_size"}[kind]
    arr = as_real_array(value)
    valid = arr is not None and arr.ndim <= (0 if kind == "HMC" else 1) and arr.size > 0
    # XLA flushes subnormal numbers to zero: such a step size is zero to JAX
    valid = valid and bool(np.all(np.isfinite(arr)) and np.all(arr >= np.finfo(np.float64).tiny)) and arr.shape in ((), (dim,))
    cls = {"RandomWalk": RandomWalk, "MALA": MALA, "HMC": HMC}[kind]
    sampler, error = outcome(lambda: restore.JumpRestore(std_normal, cls(value), Gaussian(jnp.zeros(dim)), log_rate=0.0))
    if valid:
        assert error is None, error
        state = jax.eval_shape(sampler.init, KEY)
        new_state, _ = jax.eval_shape(sampler.step, KEY, state)
        assert new_state == state
    else:
        assert_names(error, name)


@CHEAP
@given(name=st.sampled_from(["tour_length", "log_rate", "local_rate", "pilot_size"]), value=numbers)
def test_rate_settings_are_checked(name, value):
    kwargs = {"local_rate": {"log_rate": 0.0}, "pilot_size": {"tour_length": 1.0}}.get(name, {})
    kwargs[name] = value
    if name == "tour_length":
        inner = value[0] if isinstance(value, list) and len(value) == 1 else value  # one value per phase
        valid = positive_scalar(inner)
    elif name == "log_rate":
        arr = as_real_array(value)
        valid = arr is not None and arr.shape in ((), (1,)) and bool(np.all(np.isfinite(arr)))
    elif name == "local_rate":
        valid = positive_scalar(value)
    else:
        valid = positive_integer(value, 2) and value < 1e9
    sampler, error = outcome(lambda: restore.JumpRestore(std_normal, RandomWalk(0.5), Gaussian(jnp.zeros(2)), **kwargs))
    if name == "pilot_size" and isinstance(value, float) and 1e9 <= value < math.inf:
        return  # an integral but huge pilot size: accepted, though its pilot would not fit in memory
    if valid:
        assert error is None, error
    else:
        assert_names(error, name)


@CHEAP
@given(value=numbers)
def test_hmc_integration_steps_are_checked(value):
    kernel, error = outcome(lambda: HMC(0.1, value))
    if positive_integer(value, 1):
        assert error is None and kernel.num_integration_steps == int(value)
    else:
        assert_names(error, "num_integration_steps")


# --------------------------------------------------------------------------- restore.sample's arguments

count_junk = st.one_of(st.integers(-5, 0), st.floats(0.01, 50).filter(lambda x: x != int(x)),
                       st.sampled_from(["4", True, False, 2.5]))


@pytest.fixture(scope="module")
def small_sampler():
    return restore.JumpRestore(std_normal, RandomWalk(0.5), Gaussian(jnp.zeros(2), 1.5), log_rate=0.0)


class Accepted(Exception):
    """Raised by `Probe.step`: `restore.sample` accepted its arguments and started the run."""


class ProbeState(eqx.Module):
    position: jax.Array
    logdensity: jax.Array


class Probe(restore.AbstractSampler):
    """A stand-in sampler for checking `restore.sample`'s arguments: its first step raises
    `Accepted` while the run is traced, before anything is compiled."""

    has_tours: ClassVar[bool] = False

    @property
    def dim(self):
        return 2

    @property
    def dtype(self):
        return jnp.result_type(float)

    def init(self, key, position=None):
        return ProbeState(jnp.zeros(self.dim) if position is None else position, jnp.zeros(()))

    def step(self, key, state):
        raise Accepted


def sample_outcome(**kwargs):
    """What `restore.sample(Probe(), ...)` does with `kwargs`: `(None, error)` for a clear
    refusal, `("accepted", None)` if the run started."""
    draws = {name: kwargs.pop(name) for name in ("max_draws", "thin") if name in kwargs}  # options of SaveDraws
    arguments = {"num_lanes": LANES, "num_steps": STEPS, "progress": False, **kwargs}
    try:
        if draws:
            arguments["save"] = restore.SaveDraws(**draws)
        restore.sample(Probe(), KEY, **arguments)
    except Accepted:
        return "accepted", None
    except (ValueError, TypeError) as error:
        return None, error
    raise AssertionError("restore.sample returned without stepping")


@CHEAP
@given(name=st.sampled_from(["num_lanes", "num_steps", "num_chunks", "thin"]), value=count_junk)
def test_sample_refuses_bad_counts(name, value):
    if name == "thin" and value is True:
        return  # see test_sample_refuses_non_finite_counts_and_bad_budgets
    _, error = sample_outcome(**{name: value})
    assert_names(error, name)


@CHEAP
@given(weights=st.one_of(st.text(max_size=12), st.none(), st.integers()))
def test_sample_refuses_unknown_weights(weights):
    accepted, error = sample_outcome(weights=weights)
    if weights in ("rao_blackwell", "time"):
        assert accepted
    else:
        assert_names(error, "weights")


@settings(CHEAP)
@given(case=st.sampled_from([
    ("num_lanes", math.nan), ("num_lanes", None), ("num_steps", math.inf), ("num_chunks", -math.inf),
    ("thin", math.nan), ("thin", True), ("max_draws", -5), ("max_draws", 1.5), ("max_draws", math.nan),
    ("max_draws", math.inf), ("max_draws", True), ("num_lanes", [4]), ("thin", [4]), ("positions", "abc"),
    ("positions", [["a", "b"]]),
]))
def test_sample_refuses_non_finite_counts_and_bad_budgets(case):
    name, value = case
    _, error = sample_outcome(**{name: value})
    assert_names(error, name)


# --------------------------------------------------------------------------- positions and dtypes


@CHEAP
@given(
    shape=st.sampled_from([(), (1,), (2,), (3,), (2, 1), (1, 2), (0,)]),
    dtype=st.sampled_from(["float64", "float32", "float16", "int32", "bool", "complex64"]),
    poison=st.sampled_from([None, math.nan, math.inf, -math.inf]),
)
def test_starting_positions_are_checked(small_sampler, shape, dtype, poison):
    position = np.zeros(shape, dtype)
    if poison is not None and position.size and dtype.startswith("float"):
        position.flat[0] = poison
    state, error = outcome(lambda: small_sampler.init(KEY, position))
    valid = shape == (2,) and not dtype.startswith("complex") and (poison is None or not dtype.startswith("float"))
    if valid:
        assert error is None, error
        assert state.position.dtype == small_sampler.dtype == state.logdensity.dtype
        assert np.isfinite(float(state.logdensity)) and not np.isnan(float(state.log_kill_rate))
    else:
        assert_names(error, "position")


def regeneration(kind: str, dim: int, dtype, weight_dtype):
    zeros, one = jnp.zeros(dim, dtype), jnp.asarray(1.5, dtype)
    if kind == "Gaussian":
        return Gaussian(zeros, one)
    if kind == "StudentT":
        return StudentT(zeros, one, jnp.asarray(5.0, dtype))
    if kind == "UniformBox":
        return UniformBox(zeros - 4, zeros + 4)
    return Mixture([Gaussian(zeros, one), StudentT(zeros + 1, one, jnp.asarray(4.0, dtype))],
                   weights=jnp.asarray([1.0, 2.0], weight_dtype))


@settings(CHEAP, max_examples=30)
@given(
    kind=st.sampled_from(["Gaussian", "StudentT", "UniformBox", "Mixture"]),
    dtype=st.sampled_from([jnp.float32, jnp.float64]),
    weight_dtype=st.sampled_from([jnp.float32, jnp.float64]),
    out_dtype=st.sampled_from([jnp.float16, jnp.float32, jnp.float64]),
    local=st.sampled_from(["RandomWalk", "MALA", "HMC"]),
    param_dtype=st.sampled_from([jnp.float32, jnp.float64]),
    rate=st.sampled_from(["weak", "float64", "float32"]),
    position_dtype=st.sampled_from([None, np.int32, np.float32, np.float64]),
    dim=st.sampled_from([1, 3]),
    mh=st.booleans(),
)
def test_a_run_keeps_one_dtype(kind, dtype, weight_dtype, out_dtype, local, param_dtype, rate, position_dtype, dim, mh):
    """A sampler (jump Restore, or the MH baseline) runs in its regeneration's dtype
    whatever the other parts compute in.

    `lax.while_loop` (in `restore.sample`) needs `step` to return a state of exactly the
    dtypes it was given; a float32 regeneration with x64 on, a float64 step size, a
    calibrated (float64) rate or a log density in another precision used to break that.
    """
    nu = regeneration(kind, dim, dtype, weight_dtype)
    kernel = {
        "RandomWalk": lambda: RandomWalk(jnp.asarray(0.5, param_dtype)),
        "MALA": lambda: MALA(jnp.full(dim, 0.1, param_dtype)),
        "HMC": lambda: HMC(jnp.asarray(0.1, param_dtype), 3, jnp.ones(dim, param_dtype)),
    }[local]()
    log_rate = {"weak": 0.0, "float64": jnp.asarray(0.0, jnp.float64), "float32": jnp.asarray(0.0, jnp.float32)}[rate]
    logdensity = lambda x: std_normal(x).astype(out_dtype)  # noqa: E731
    if mh:
        sampler = restore.MixtureMH(logdensity, kernel, nu, 0.2)
    else:
        sampler = restore.JumpRestore(logdensity, kernel, nu, log_rate=log_rate)
    assert sampler.dtype == jax.eval_shape(nu.sample, KEY).dtype == jnp.dtype(dtype)
    position = None if position_dtype is None else np.zeros(dim, position_dtype)
    state = jax.eval_shape(sampler.init, KEY, position)
    new_state, info = jax.eval_shape(sampler.step, KEY, state)
    assert new_state == state
    for leaf in jax.tree.leaves((state, info)):
        assert not jnp.issubdtype(leaf.dtype, jnp.floating) or leaf.dtype == sampler.dtype, (state, info)


def test_a_float32_run_with_x64_on_stays_float32_and_finite():
    """End to end: a float32 regeneration, a float64 log density and a tour length (a float64 pilot)."""
    nu = Gaussian(jnp.zeros(2, jnp.float32), jnp.float32(1.5))
    sampler = restore.JumpRestore(lambda x: std_normal(x) + np.float64(0.0), RandomWalk(0.7), nu, tour_length=2.0)
    positions = np.ones((LANES, 2))  # float64 starts are cast too
    result = restore.sample(sampler, KEY, num_lanes=LANES, num_steps=STEPS, positions=positions, progress=False)
    assert result.draws.dtype == np.float32 and result.final_state.position.dtype == np.float32
    est = result.estimate("x", method="lanes")
    assert np.all(np.isfinite(est.value)) and np.all(np.isfinite(est.standard_error))


# --------------------------------------------------------------------------- log densities


def _raises(error):
    def logdensity(x):
        raise error

    return logdensity


LOG_DENSITIES = {
    "float": (lambda x: std_normal(x), True),
    "python float": (lambda x: 0.0, True),
    "numpy float": (lambda x: np.float64(-1.0), True),
    "float32": (lambda x: std_normal(x).astype(jnp.float32), True),
    "float16": (lambda x: std_normal(x).astype(jnp.float16), True),
    "nan": (lambda x: jnp.nan * jnp.sum(x), True),  # valid: zero density everywhere (the pilot then fails)
    "vector": (lambda x: -0.5 * x**2, False),
    "shape (1,)": (lambda x: jnp.sum(x, keepdims=True), False),
    "shape (1, 1)": (lambda x: jnp.sum(x).reshape(1, 1), False),
    "int": (lambda x: jnp.sum(x).astype(jnp.int32), False),
    "python int": (lambda x: 1, False),
    "bool": (lambda x: x[0] > 0, False),
    "complex": (lambda x: jnp.sum(x) + 0j, False),
    "None": (lambda x: None, False),
    "tuple": (lambda x: (jnp.sum(x), jnp.sum(x)), False),
    "string": (lambda x: "p", False),
    "needs two arguments": (lambda x, y: jnp.sum(x), False),
    "raises RuntimeError": (_raises(RuntimeError("boom from the user's model")), False),
    "raises KeyError": (_raises(KeyError("theta")), False),
    "raises ZeroDivisionError": (_raises(ZeroDivisionError("division by zero")), False),
    "concrete value needed": (lambda x: float(x[0]), False),
    "not callable": ("p(x)", False),
    # an external model without a derivative rule: fine for a random walk, not for MALA
    "no derivative rule": (lambda x: jax.pure_callback(lambda y: np.float64(-0.5 * np.sum(y**2)),
                                                       jax.ShapeDtypeStruct((), jnp.float64), x,
                                                       vmap_method="sequential"), "gradient-free kernels"),
}


@CHEAP
@given(which=st.sampled_from(sorted(LOG_DENSITIES)), dim=st.sampled_from([1, 2, 3]),
       local=st.sampled_from([RandomWalk(0.5), MALA(0.2)]), rate=st.sampled_from([{"log_rate": 0.0}, {"tour_length": 2.0}]))
def test_log_densities_that_do_not_return_a_real_scalar_are_refused(which, dim, local, rate):
    logdensity, valid = LOG_DENSITIES[which]
    if valid == "gradient-free kernels":
        valid = not local.uses_gradient
    sampler, error = outcome(lambda: restore.JumpRestore(logdensity, local, Gaussian(jnp.zeros(dim)), **rate))
    if valid:
        assert error is None, error
        if sampler.log_rate is not None:  # and the run traces, with the sampler's dtypes
            state = jax.eval_shape(sampler.init, KEY)
            assert jax.eval_shape(sampler.step, KEY, state)[0] == state
        return
    assert_names(error, "logdensity")
    if which == "no derivative rule":
        assert "jax.grad failed" in str(error) and "RandomWalk" in str(error)
    if which.startswith("raises"):  # the user's own exception is named and chained
        assert type(error.__cause__).__name__ == which.split()[-1]
        assert str(error.__cause__.args[0]) in str(error)


def test_a_log_density_that_is_nan_everywhere_fails_the_pilot_clearly():
    sampler = restore.JumpRestore(lambda x: jnp.nan * jnp.sum(x), RandomWalk(0.5), Gaussian(jnp.zeros(2)), tour_length=1.0,
                                  pilot_size=16)
    with pytest.raises(ValueError, match=r"NaN or \+inf at 16 of them.*misses the target's support"):
        sampler.calibrate(KEY)


class Target(eqx.Module):
    """`N(0, I)` restricted to the box `|x_i| <= half_width`, with a region where the log
    density is `bad_value` (NaN or `+inf`). Every parameter is an array leaf, so new values
    reuse the compiled run."""

    half_width: jax.Array
    bad_low: jax.Array
    bad_high: jax.Array
    bad_value: jax.Array

    def __call__(self, x):
        value = jnp.where(jnp.all(jnp.abs(x) <= self.half_width), std_normal(x), -jnp.inf)
        bad = jnp.all((x >= self.bad_low) & (x <= self.bad_high))
        return jnp.where(bad, self.bad_value, value)


def target(half_width, bad_low, bad_high, bad_value) -> Target:
    """A `Target` with float64 (not weakly typed) leaves, so that every run shares one program."""
    leaf = lambda v: jnp.asarray(np.broadcast_to(np.asarray(v, np.float64), np.shape(v)))  # noqa: E731
    corner = lambda v: leaf(np.broadcast_to(v, (2,)))  # noqa: E731
    return Target(leaf(half_width), corner(bad_low), corner(bad_high), leaf(bad_value))


def box(low, high) -> UniformBox:
    return UniformBox(jnp.asarray(np.broadcast_to(np.asarray(low, np.float64), (2,))),
                      jnp.asarray(np.broadcast_to(np.asarray(high, np.float64), (2,))))


KERNELS = {"RandomWalk": RandomWalk(0.7), "MALA": MALA(0.3), "HMC": HMC(0.3, 3)}
WARNING_INVALID = r"NaN or \+inf"
WARNING_UNCOVERED = "regeneration density is zero"
EXPECTED_ESTIMATE_ERRORS = "complete tour|hold no time|squares underflow"


def run(sampler, key=KEY, **kwargs):
    """`restore.sample` with the shared sizes; returns the result and the warning messages."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = restore.sample(sampler, key, num_lanes=LANES, num_steps=STEPS, progress=False, **kwargs)
    return result, [str(w.message) for w in caught]


def assert_estimates_finite_or_refused(result):
    for method in ("tours", "lanes"):
        est, error = outcome(lambda: result.estimate("x", method=method))  # noqa: B023
        if error is not None:
            assert isinstance(error, ValueError) and re.search(EXPECTED_ESTIMATE_ERRORS, str(error)), error
        else:
            assert np.all(np.isfinite(est.value)) and np.all(np.isfinite(est.standard_error)), (method, est)
            assert np.all(est.standard_error > 0), (method, est)


@RUNS
@given(
    local=st.sampled_from(sorted(KERNELS)),
    half_width=st.sampled_from([math.inf, 1.5, 3.0]),
    width=st.floats(0.5, 5.0),
    centre=st.tuples(st.floats(-3, 3), st.floats(-3, 3)),
    size=st.floats(0.0, 3.0),
    bad_value=st.sampled_from([math.nan, math.inf]),
    log_rate=st.one_of(st.floats(-3, 3), st.sampled_from([800.0, 1e300])),
)
@example(local="RandomWalk", half_width=math.inf, width=3.0, centre=(0.0, 0.0), size=10.0, bad_value=math.nan, log_rate=0.0)
def test_nan_and_inf_regions_are_zero_density_counted_and_warned(local, half_width, width, centre, size, bad_value, log_rate):
    """A random region where the log density is NaN or `+inf`, a target with bounded or
    unbounded support, a regeneration box that may or may not cover it, and rates from
    ordinary to absurd: the run completes, every NaN/`+inf` evaluation and every uncovered
    state is counted and warned about, no NaN reaches the state, draws or estimates, and
    an estimate that cannot be formed says why."""
    centre = np.asarray(centre)
    density = target(half_width, centre - size, centre + size, bad_value)
    sampler = restore.JumpRestore(density, KERNELS[local], box(-width, width), log_rate=log_rate)
    result, messages = run(sampler)
    assert not any(re.search("invalid value encountered|divide by zero|overflow encountered", m) for m in messages), messages
    assert (result.num_invalid > 0) == any(re.search(WARNING_INVALID, m) for m in messages), messages
    assert (result.num_uncovered > 0) == any(WARNING_UNCOVERED in m for m in messages), messages
    if width >= half_width:
        assert result.num_uncovered == 0
    if size >= 9.0:  # the whole box is invalid: every tour start is killed at once with weight zero
        assert result.num_invalid > 0
        with pytest.raises(ValueError, match="hold no time"):
            result.estimate("x", method="lanes")
    assert np.all(np.isfinite(result.draws)) and np.all(np.isfinite(result.draw_weights))
    assert np.all(result.draw_weights >= 0)
    final = result.final_state
    assert np.all(np.isfinite(final.position)) and not np.any(np.isnan(final.logdensity))
    assert not np.any(final.logdensity == np.inf)
    assert_estimates_finite_or_refused(result)
    log_z, error = outcome(lambda: result.normalising_constant("importance"))
    if error is None:
        assert np.isfinite(log_z.value) and np.isfinite(log_z.standard_error), log_z
    else:
        assert re.search("importance (weights|draws)", str(error)), error


@settings(RUNS, max_examples=2)
@given(log_rate=st.sampled_from([1e300, 800.0]))
def test_normalising_constant_refuses_underflowed_tours(log_rate):
    density = target(math.inf, 9.0, 9.5, math.nan)
    sampler = restore.JumpRestore(density, KERNELS["RandomWalk"], box(-3.0, 3.0), log_rate=log_rate)
    result, _ = run(sampler)
    with pytest.raises(ValueError, match="hold no time|squares underflow"):
        result.normalising_constant()


# --------------------------------------------------------------------------- regeneration against the target's support


@RUNS
@given(
    half_width=st.floats(1.0, 3.0),
    width=st.floats(0.5, 1.0),
    where=st.sampled_from(["inside", "outside"]),
    offset=st.floats(0.0, 1.0),
    poisoned=st.booleans(),
    bad_value=st.sampled_from([math.nan, math.inf]),
)
def test_a_regeneration_that_misses_the_support_fails_the_pilot(half_width, width, where, offset, poisoned, bad_value):
    """Boxes inside the support calibrate; boxes beside it (or where the log density is
    NaN/`+inf` throughout) fail the pilot with a clear error; with a raw `log_rate` (no
    pilot) the run then refuses to estimate, saying why."""
    if where == "inside":
        low = -half_width + offset * (2 * half_width - width)
    else:
        low = half_width + 0.1 + 2.0 * offset
    nu = box(low, low + width)
    bad_low, bad_high = (low - 0.1, low + width + 0.1) if poisoned else (9.0, 9.5)
    density = target(half_width, bad_low, bad_high, bad_value)
    sampler = restore.JumpRestore(density, KERNELS["RandomWalk"], nu, tour_length=2.0, pilot_size=64)
    calibration, error = outcome(lambda: sampler.calibrate(KEY))
    if where == "inside" and not poisoned:
        assert error is None, error
        calibrated, pilot = calibration
        assert math.isfinite(pilot.log_z) and math.isfinite(float(calibrated.log_rate))
        return
    assert isinstance(error, ValueError) and "misses the target's support" in str(error), error
    assert (r"NaN or +inf" in str(error)) == poisoned
    raw = restore.JumpRestore(density, KERNELS["RandomWalk"], nu, log_rate=0.0)
    result, _ = run(raw)
    with pytest.raises(ValueError, match="hold no time"):
        result.estimate("x", method="lanes")


# --------------------------------------------------------------------------- regeneration distributions

matrix_entries = st.floats(-3, 3)


@st.composite
def covariances(draw, dim):
    form = draw(st.sampled_from(["scalar", "diagonal", "matrix", "wrong shape", "junk"]))
    if form == "scalar":
        return draw(numbers)
    if form == "diagonal":
        entries = st.sampled_from([1.0, 0.5, 0.0, -1.0, math.nan, math.inf])
        return np.asarray(draw(st.lists(entries, min_size=dim, max_size=dim)))
    if form == "matrix":
        a = np.asarray(draw(st.lists(matrix_entries, min_size=dim * dim, max_size=dim * dim))).reshape(dim, dim)
        return draw(st.sampled_from([a @ a.T + 0.1 * np.eye(dim), a, a + a.T, a @ a.T]))
    if form == "wrong shape":
        return np.ones(draw(st.sampled_from([(dim + 1,), (dim, dim + 1), (1, 1, 1)])))
    return draw(st.sampled_from(JUNK))


def real_parameter(value):
    """Regeneration parameters: real numbers or arrays of them; bools count as 0/1 (documented)."""
    if isinstance(value, (bool, np.bool_)):
        return np.asarray(float(value))
    return as_real_array(value)


def covariance_status(cov, dim) -> str:
    """"valid", "invalid", or "borderline" (singular or barely asymmetric: the library's
    tolerances decide, and either outcome is fine as long as it is clear)."""
    arr = real_parameter(cov)
    if arr is None or not np.all(np.isfinite(arr)):
        return "invalid"
    if arr.shape in ((), (dim,)):
        return "valid" if np.all(arr > 0) else "invalid"
    if arr.shape != (dim, dim):
        return "invalid"
    asymmetry, size = np.abs(arr - arr.T).max(), max(np.abs(arr).max(), 1e-300)
    if asymmetry > 1e-6 * size:
        return "invalid"
    eig = np.linalg.eigvalsh(0.5 * (arr + arr.T))
    scale = np.abs(eig).max()
    if asymmetry > 1e-12 * size:
        return "borderline"
    return "valid" if eig.min() > 1e-8 * scale else "invalid" if eig.min() < -1e-8 * scale else "borderline"


BAD_VECTORS = [np.zeros((3, 1)), np.zeros(0), "x", None, [1 + 1j, 1j, 1j]]


def finite_positive(arr, shape) -> bool:
    return arr is not None and arr.shape == shape and bool(np.all(np.isfinite(arr) & (arr > 0)))


def mixture_components(which: str, dim: int):
    return {
        "list": [Gaussian(np.zeros(dim)), StudentT(np.ones(dim), 2.0, 3.0)],
        "single": Gaussian(np.zeros(dim)),
        "empty": [],
        "mixed dims": [Gaussian(np.zeros(dim)), Gaussian(np.zeros(dim + 1))],
        "junk": [Gaussian(np.zeros(dim)), "nu"],
    }[which]


@CHEAP
@given(data=st.data(), kind=st.sampled_from(["Gaussian", "StudentT", "UniformBox", "Mixture"]),
       dim=st.sampled_from([1, 2, 3]))
def test_regeneration_distributions_check_their_parameters(data, kind, dim):
    """Valid parameters give a distribution whose draws and log densities are finite;
    invalid ones raise an error naming the parameter. Singular-but-PD borderline matrices
    may go either way (tolerances), but never produce NaN."""
    mean = data.draw(st.one_of(st.just(np.zeros(dim)), st.sampled_from(BAD_VECTORS)))
    mean_valid = isinstance(mean, np.ndarray) and mean.shape == (dim,)
    if kind == "Gaussian":
        cov = data.draw(covariances(dim))
        status = covariance_status(cov, dim) if mean_valid else "invalid"
        names, build = ("mean", "cov"), lambda: Gaussian(mean, cov)
    elif kind == "StudentT":
        cov, df = data.draw(covariances(dim)), data.draw(numbers)
        df_arr = real_parameter(df)
        # at least 0.1 degrees of freedom in float64: with fewer, draws overflow to infinity
        df_valid = df_arr is not None and df_arr.ndim == 0 and bool(np.isfinite(df_arr)) and float(df_arr) >= 0.1
        status = covariance_status(cov, dim) if mean_valid and df_valid else "invalid"
        names, build = ("loc", "scale", "df"), lambda: StudentT(mean, cov, df)
    elif kind == "UniformBox":
        bad_highs = [np.zeros(dim), -np.ones(dim), np.full(dim, math.inf), np.full(dim, math.nan), np.ones(dim + 1), "x"]
        high = data.draw(st.one_of(st.just(np.ones(dim)), st.sampled_from(bad_highs)))
        status = "valid" if mean_valid and finite_positive(real_parameter(high), (dim,)) else "invalid"
        names, build = ("low", "high"), lambda: UniformBox(mean, high)
    else:
        which = data.draw(st.sampled_from(["list", "single", "empty", "mixed dims", "junk"]))
        weights = data.draw(st.one_of(st.none(), st.sampled_from(JUNK),
                                      st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=3)))
        weights_valid = weights is None or finite_positive(real_parameter(weights), (2,))
        status = "valid" if which == "list" and weights_valid else "invalid"
        components = mixture_components(which, dim)
        names, build = ("components", "weights", "Component", "dim"), lambda: Mixture(components, weights)
    dist, error = outcome(build)
    if error is not None:
        assert status != "valid", error
        assert_names(error, *names)
        return
    assert status != "invalid", f"accepted invalid parameters for {kind}"
    draws, log_probs = draws_and_log_probs(dist, KEY)
    assert draws.shape == (4, dim) and np.all(np.isfinite(draws))
    assert np.all(np.isfinite(log_probs))


@eqx.filter_jit
def draws_and_log_probs(dist, key):
    """Compiled once per distribution structure (parameters are traced)."""
    draws = dist.sample(key, (4,))
    return draws, jax.vmap(dist.log_prob)(draws)


@pytest.mark.parametrize("df", [2e4, 1e8, 1e20, 1e300, 1.7e308])
def test_student_t_with_huge_df_is_the_gaussian_limit_not_nan(df):
    """`log Gamma((df + d) / 2) - log Gamma(df / 2)` used to cancel to 0 (and `maha / df` to
    underflow): a wrong density from df ~ 1e12, NaN from df ~ 5e305."""
    x = jnp.array([0.3, -1.2, 2.0])
    gaussian = float(Gaussian(jnp.zeros(3), 1.0).log_prob(x))
    np.testing.assert_allclose(float(StudentT(jnp.zeros(3), 1.0, df).log_prob(x)), gaussian, atol=1e-3 if df < 1e5 else 1e-9)


# --------------------------------------------------------------------------- interrupted writes

FAILURES = {
    "disk full": lambda: OSError(errno.ENOSPC, "No space left on device"),
    "Ctrl-C": KeyboardInterrupt,
    "bug": lambda: RuntimeError("writer crashed"),
}


def partial_then_raise(failure: str, fraction: float):
    """A writer that writes part of some data to the path it is given, then raises."""

    def writer(tmp: Path, data: bytes = b"x" * 1000) -> None:
        with open(tmp, "wb") as handle:
            handle.write(data[: int(fraction * len(data))])
        raise FAILURES[failure]()

    return writer


def listing(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@st.composite
def old_files(draw):
    """None (no file yet) or the bytes of an existing file."""
    return draw(st.one_of(st.none(), st.binary(min_size=0, max_size=64)))


@FILES
@given(old=old_files(), failure=st.sampled_from(sorted(FAILURES)), fraction=st.floats(0.0, 1.0),
       name=st.sampled_from(["out.npy", "out.NPY", "results.csv", "no-suffix", ".hidden", "a b.png"]))
def test_atomic_write_leaves_the_old_file_or_none(tmp_path_factory, old, failure, fraction, name):
    folder = tmp_path_factory.mktemp("atomic")
    path = folder / name
    if old is not None:
        path.write_bytes(old)
    before = listing(folder)
    with pytest.raises(BaseException) as info:
        atomic_write(path, partial_then_raise(failure, fraction))
    assert not isinstance(info.value, AssertionError)
    assert listing(folder) == before  # old content intact (or still no file), no stray temporary file


@FILES
@given(old=old_files(), mode=st.sampled_from([None, 0o644, 0o600, 0o664]), umask=st.sampled_from([0o022, 0o077, 0o002]))
def test_atomic_write_keeps_the_usual_permissions(tmp_path_factory, old, mode, umask):
    """A new file gets `0o666 & ~umask` (not a temporary file's private 0o600); a replaced
    file keeps its mode."""
    folder = tmp_path_factory.mktemp("modes")
    path = folder / "out.txt"
    if old is not None:
        path.write_bytes(old)
        if mode is not None:
            os.chmod(path, mode)
    expected = (path.stat().st_mode & 0o777) if old is not None else 0o666 & ~umask
    previous = os.umask(umask)
    try:
        atomic_write(path, lambda tmp: tmp.write_bytes(b"new"))
    finally:
        os.umask(previous)
    assert path.read_bytes() == b"new" and path.stat().st_mode & 0o777 == expected
    assert sorted(p.name for p in folder.iterdir()) == ["out.txt"]


@FILES
@given(old=old_files(), suffix=st.sampled_from([".npy", ".NPY", ".Npy", ".png", ".PNG"]),
       failure=st.sampled_from(sorted(FAILURES)), fraction=st.floats(0.0, 1.0), fail=st.booleans())
def test_save_image_is_atomic(tmp_path_factory, monkeypatch, old, suffix, failure, fraction, fail):
    """`save_image` either writes the whole image or leaves the old file (or none); with
    any suffix case, never a stray `.npy` beside an empty file."""
    import matplotlib.image

    from restore.render._images import load_image, save_image

    folder = tmp_path_factory.mktemp("images")
    path = folder / f"render{suffix}"
    if old is not None:
        path.write_bytes(old)
    before = listing(folder)
    image = np.linspace(0.0, 2.0, 4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    if fail:
        def broken_save(target, *args, **kwargs):
            data = b"\x93NUMPY" + b"\0" * 200
            if hasattr(target, "write"):
                target.write(data[: int(fraction * len(data))])
            else:
                Path(target).write_bytes(data[: int(fraction * len(data))])
            raise FAILURES[failure]()

        with monkeypatch.context() as patch:
            patch.setattr(np, "save", broken_save)
            patch.setattr(matplotlib.image, "imsave", broken_save)
            with pytest.raises(BaseException) as info:
                save_image(path, image)
        assert not isinstance(info.value, AssertionError)
        assert listing(folder) == before
        return
    save_image(path, image)
    assert sorted(p.name for p in folder.iterdir()) == [path.name]
    if suffix.lower() == ".npy":
        np.testing.assert_array_equal(load_image(path), image)
    else:
        assert path.read_bytes().startswith(b"\x89PNG")


def fake_suite_result():
    config = SimpleNamespace(name="fake", seeds=1, full_evaluations=10, lanes=1, steps=10, fractions=(1.0,), max_points=10,
                             problems=())
    return SimpleNamespace(config=config, rows=[], ratios=[], machine={"cpu": "test"}, seconds=1.0, files={},
                           interrupted=False, raw_rates={})


@FILES
@given(old=st.one_of(st.none(), st.text(max_size=40)), failure=st.sampled_from(sorted(FAILURES)),
       fraction=st.floats(0.0, 1.0), which=st.sampled_from(["results.csv", "results.md"]))
def test_bench_report_files_are_written_atomically(tmp_path_factory, monkeypatch, old, failure, fraction, which):
    """An interrupted `write_results` leaves each report file whole: old or new, never cut."""
    import restore._io
    from restore.bench import write_results

    out = tmp_path_factory.mktemp("bench")
    for name in ("results.csv", "results.md"):
        if old is not None:
            (out / name).write_text(old)
    before = listing(out)
    real_open = open

    def failing_open(file, mode="r", *args, **kwargs):
        handle = real_open(file, mode, *args, **kwargs)
        if "w" not in mode or not Path(file).name.startswith(f".{which}."):
            return handle

        class Cut:
            def __enter__(self):
                return self

            def __exit__(self, *exc):
                handle.close()

            def write(self, text):
                handle.write(text[: int(fraction * len(text))])
                raise FAILURES[failure]()

        return Cut()

    with monkeypatch.context() as patch:
        patch.setattr(restore._io, "open", failing_open, raising=False)
        with pytest.raises(BaseException) as info:
            write_results(fake_suite_result(), out)
    assert not isinstance(info.value, AssertionError)
    after = listing(out)
    assert set(after) == set(before) | ({"results.csv"} if which == "results.md" else set())  # no stray files
    assert after.get(which) == before.get(which)  # the interrupted file: old content, or still absent
    files = write_results(fake_suite_result(), out)  # and a clean write replaces both
    assert files["csv"].read_text().startswith("problem,") and "# Restore comparison suite" in files["markdown"].read_text()
