"""restore's programs compile at XLA backend optimisation level 1 on the CPU, unless the user sets a level."""

import os

import jax
import jax.numpy as jnp
import numpy as np

from restore import _compile
from restore._compile import compiler_options, jit


def options_seen(monkeypatch) -> list:
    """The compiler options of every `jax.jit` built from here on (a spy on `jax.jit`)."""
    seen: list = []
    original = jax.jit

    def spy(fun, **kwargs):
        seen.append(kwargs.get("compiler_options"))
        return original(fun, **kwargs)

    monkeypatch.setattr(jax, "jit", spy)
    return seen


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
    seen = options_seen(monkeypatch)

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


def test_programs_that_run_once_compile_with_the_older_emitters(monkeypatch):
    """`once` programs get `xla_cpu_use_fusion_emitters=False`; loops do not; `XLA_FLAGS` overrides both."""
    monkeypatch.setenv("XLA_FLAGS", "")
    assert _compile._has_emitter_choice()  # this XLA has the option (else it is left out)
    assert compiler_options(once=True) == {"xla_backend_optimization_level": 1, _compile.FUSION_EMITTERS: False}
    assert compiler_options() == {"xla_backend_optimization_level": 1}
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert compiler_options(once=True) == {"xla_backend_optimization_level": 1}


def test_an_option_this_xla_lacks_is_left_out(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.setattr(_compile, "_has_emitter_choice", lambda: False)
    assert compiler_options(once=True) == {"xla_backend_optimization_level": 1}


def test_a_program_compiled_for_once_computes_the_same_bits(monkeypatch):
    """The emitters change the machine code, not the numbers (against the newer emitters, forced
    here whatever `XLA_FLAGS` select; negative control: a changed program differs)."""

    def draws(key):
        x = jax.random.normal(key, (257, 3))
        return jnp.exp(jnp.sin(x) * 3.0).sum(axis=1) / jnp.log1p(x**2 + 1e-3).sum(axis=1)

    key = jax.random.key(3)
    newer = {"xla_backend_optimization_level": 1, _compile.FUSION_EMITTERS: True}
    reference = np.asarray(jax.jit(draws, compiler_options=newer)(key))
    monkeypatch.setenv("XLA_FLAGS", "")
    seen = options_seen(monkeypatch)
    once = np.asarray(jit(draws, once=True)(key))
    assert seen == [{"xla_backend_optimization_level": 1, _compile.FUSION_EMITTERS: False}]
    np.testing.assert_array_equal(once, reference)
    changed = np.asarray(jit(lambda k: draws(k) * (1.0 + 1e-15), once=True)(key))
    assert not np.array_equal(changed, reference)


def test_the_renderers_programs_keep_the_newer_emitters_whatever_xla_flags_select(monkeypatch):
    """The suite selects the older emitters in `XLA_FLAGS` (`tests/conftest.py`); the
    renderer's options override that (its loop compiles for minutes with the older ones),
    and the override reaches the compiled program. Negative control: default options."""

    def program(x):
        return jax.lax.fori_loop(0, 5, lambda i, c: jnp.sin(c) * 1.0001 + jnp.cos(c) ** 2 + c.sum(), x)

    x = jnp.ones((64, 16))
    assert "--xla_cpu_use_fusion_emitters=false" in os.environ["XLA_FLAGS"]  # set before JAX started
    older = jax.jit(program).lower(x).compile({}).as_text()
    assert jax.jit(program).lower(x).compile(compiler_options(once=True)).as_text() == older
    rendering = jax.jit(program).lower(x).compile(compiler_options(renderer=True)).as_text()
    assert rendering != older
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")
    assert compiler_options(renderer=True) == {"xla_backend_optimization_level": 1, _compile.FUSION_EMITTERS: True}
    assert compiler_options() == compiler_options(once=True) == {"xla_backend_optimization_level": 1}
