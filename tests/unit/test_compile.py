"""restore's programs compile at XLA backend optimisation level 1 on the CPU, unless the user sets a level."""

import jax
import jax.numpy as jnp
import numpy as np

from restore import _compile
from restore._compile import compiler_options, jit


def test_level_one_on_the_cpu_unless_xla_flags_sets_a_level(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_enable_fast_math=false")
    assert compiler_options() == {"xla_backend_optimization_level": _compile.CPU_OPTIMIZATION_LEVEL}
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=3")
    assert compiler_options() == {}
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setenv("XLA_FLAGS", "")
    assert compiler_options() == {}


def test_jitted_functions_take_the_options_and_keep_their_results(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "")
    seen = []
    original = jax.jit

    def spy(fun, **kwargs):
        seen.append(kwargs.get("compiler_options"))
        return original(fun, **kwargs)

    monkeypatch.setattr(jax, "jit", spy)

    @jit(static_argnums=1)
    def power(x, n):
        return jnp.sum(jnp.sin(x) ** n)

    x = jnp.linspace(0.0, 3.0, 101)
    assert seen == []  # nothing is built before the first call
    value = power(x, 3)
    assert seen == [{"xla_backend_optimization_level": 1}]
    np.testing.assert_allclose(float(value), float(jnp.sum(jnp.sin(x) ** 3)), rtol=1e-12)
    power(x, 2)  # built once
    assert len(seen) == 1

    @jit(filtered=True)
    def scaled(f, x):
        return f(x) * 2.0

    np.testing.assert_allclose(np.asarray(scaled(jnp.cos, x)), 2.0 * np.cos(np.asarray(x)), rtol=1e-12)
