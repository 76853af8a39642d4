"""How restore compiles its own programs: XLA's backend optimisation level 1 on the CPU.

On the CPU, XLA's compile time is mostly LLVM's, and it grows with the number of kernels
of a program: the sampler's loop has about 160 and took 2.1-2.6 s to compile at the
default level 3. At level 1 it compiles in about half the time and ran as fast (512 lanes
x 1500 steps, medians of 5 runs in alternating processes: a first call of `restore.sample`
4.6-5.0 s -> 3.5 s with a Gaussian regeneration and 7.7-7.9 s -> 4.9-5.1 s with a
Student-t mixture; run times equal within the machine's noise). Draws and tours are
bit-identical; float64 sums can differ in the last bits (relative 1e-13), since LLVM may
contract other multiply-adds. Level 0 is worse on both counts: the first call took
5.4-5.7 s and the run 2.5-2.7 s instead of 0.76-0.94 s.

The level applies to the CPU backend only, and not at all when `XLA_FLAGS` sets
`--xla_backend_optimization_level` (then the user's choice stands).
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax

#: XLA's backend optimisation level for restore's programs on the CPU.
CPU_OPTIMIZATION_LEVEL = 1


def compiler_options() -> dict[str, Any]:
    """The options of restore's programs: the CPU level, unless the backend is not the CPU
    or `XLA_FLAGS` sets a level."""
    if "xla_backend_optimization_level" in os.environ.get("XLA_FLAGS", "") or jax.default_backend() != "cpu":
        return {}
    return {"xla_backend_optimization_level": CPU_OPTIMIZATION_LEVEL}


def jit(fun: Callable | None = None, *, filtered: bool = False, **kwargs) -> Callable:
    """`jax.jit(fun, **kwargs)` (or `eqx.filter_jit` when `filtered`) with `compiler_options()`.

    The jitted function is built at the first call, when the backend is known (importing
    restore does not start JAX's backends). Use as `@jit`, `@jit(filtered=True)` or
    `@jit(static_argnums=1)`. `.lower(*args)` lowers it for `args` (to compile it ahead).
    """
    if fun is None:
        return functools.partial(jit, filtered=filtered, **kwargs)
    built: list[Callable] = []

    def build():
        with _BUILD_LOCK:  # a program may be compiled ahead from another thread (`_ahead`)
            if not built:
                wrap = eqx.filter_jit if filtered else jax.jit
                built.append(wrap(fun, **kwargs, compiler_options=compiler_options()))
        return built[0]

    @functools.wraps(fun)
    def call(*args, **kw):
        return (built[0] if built else build())(*args, **kw)

    call.lower = lambda *args, **kw: build().lower(*args, **kw)  # type: ignore[attr-defined]
    return call


_BUILD_LOCK = threading.Lock()
