"""How restore compiles its own programs: XLA's backend optimisation level 1 on the CPU.

On the CPU, XLA's compile time is mostly LLVM's, and it grows with the number of kernels
of a program: the sampler's loop has about 160. At level 1 it compiles much faster than at
the default level 3 and runs as fast. Draws and tours are bit-identical; float64 sums can
differ in the last bits (relative 1e-13), since LLVM may contract other multiply-adds.
Level 0 is worse on both counts: slower to compile and slower to run.

Programs that run once per call (the start states, the pilot, key and carry set-up:
`jit(once=True)`) also compile with XLA's older CPU kernel emitters
(`xla_cpu_use_fusion_emitters=False`): they compile faster, and their code runs for
milliseconds. The loops keep the newer emitters, whose code runs the jump-Restore loop
faster by more than the compile time it saves, with bit-identical results either way.
The renderer's programs ask for the newer emitters even where `XLA_FLAGS` selects the
older ones: with those, the render loop of a Mitsuba scene did not finish compiling in
any reasonable time.

Each setting applies to the CPU backend only, and the emitter choice only where this XLA
has it. `XLA_FLAGS` overrides the level of every program and the emitters of every
program but the renderer's (then the user's choice stands). The test suite selects the
older emitters in its `XLA_FLAGS` to compile less (`tests/conftest.py`).

The measurements behind these choices are in `docs/benchmarks.md` ("Measurements behind
design choices in the code").
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable
from typing import Any, Protocol, cast

import equinox as eqx
import jax
import numpy as np

#: XLA's backend optimisation level for restore's programs on the CPU.
CPU_OPTIMIZATION_LEVEL = 1


class Lowerable(Protocol):
    """A program built by `jit` or `jit_chunk`: callable, with `.lower(*args)`, which lowers
    it for `args` (to compile it ahead)."""

    lower: Callable[..., Any]

    def __call__(self, *args: Any, **kwargs: Any) -> Any: ...


#: The XLA option that selects the CPU kernel emitters (see the module's docstring).
FUSION_EMITTERS = "xla_cpu_use_fusion_emitters"


def compiler_options(once: bool = False, renderer: bool = False) -> dict[str, Any]:
    """The options of restore's programs on the CPU (none on other backends): level 1,
    and for a program that runs `once` per call the older kernel emitters, except what
    `XLA_FLAGS` sets. The `renderer`'s programs always get the newer emitters (the older
    ones compile its loop for minutes)."""
    if jax.default_backend() != "cpu":
        return {}
    flags = os.environ.get("XLA_FLAGS", "")
    options: dict[str, Any] = {}
    if "xla_backend_optimization_level" not in flags:
        options["xla_backend_optimization_level"] = CPU_OPTIMIZATION_LEVEL
    if renderer and _has_emitter_choice():
        options[FUSION_EMITTERS] = True
    elif once and FUSION_EMITTERS not in flags and _has_emitter_choice():
        options[FUSION_EMITTERS] = False
    return options


@functools.cache
def _has_emitter_choice() -> bool:
    """Whether this XLA takes the emitter option (a newer one may drop it): one tiny compilation, once."""
    try:
        jax.jit(lambda x: x + 1).lower(np.zeros((), np.float32)).compile({FUSION_EMITTERS: False})
    except Exception:  # noqa: BLE001 - any refusal means: leave the option out
        return False
    return True


def jit(fun: Callable | None = None, *, filtered: bool = False, once: bool = False, **kwargs) -> Callable:
    """`jax.jit(fun, **kwargs)` (or `eqx.filter_jit` when `filtered`) with `compiler_options(once)`.

    `once`: the program runs once per call (set-up, not a loop), so it is compiled for a
    short compile time. The jitted function is built at the first call, when the backend
    is known (importing restore does not start JAX's backends). Use as `@jit`,
    `@jit(filtered=True, once=True)` or `@jit(static_argnums=1)`. `.lower(*args)` lowers
    it for `args` (to compile it ahead).
    """
    if fun is None:
        return functools.partial(jit, filtered=filtered, once=once, **kwargs)
    built: list[Callable] = []

    def build():
        with _BUILD_LOCK:  # a program may be compiled ahead from another thread (`_ahead`)
            if not built:
                wrap = eqx.filter_jit if filtered else jax.jit
                built.append(wrap(fun, **kwargs, compiler_options=compiler_options(once)))
        return built[0]

    @functools.wraps(fun)
    def call(*args, **kw):
        return (built[0] if built else build())(*args, **kw)

    # a function object takes any attribute; the cast names the one it is given here
    cast(Lowerable, call).lower = lambda *args, **kw: build().lower(*args, **kw)
    return call


_BUILD_LOCK = threading.Lock()


def jit_chunk(fun: Callable) -> Callable:
    """`fun(chunk, carry)` compiled as a loop (`compiler_options()`), returning at once (asynchronous
    dispatch), with the carry donated: its buffers become the result's.

    `chunk` may hold anything (a sampler, static settings): its arrays are traced and
    everything else is static, as with `eqx.filter_jit`, and none of it is donated. `carry`
    is a pytree of arrays. (`eqx.filter_jit` waits for every call to end, to report
    runtime errors, so the host could not dispatch a chunk before the last one ended.)
    `.lower(chunk, carry)` lowers it (to compile it ahead).
    """
    built: list[Callable] = []

    def inner(dynamic, static, carry):
        return fun(_join(dynamic, static), carry)

    inner.__name__ = inner.__qualname__ = fun.__name__  # the program's name in JAX's logs and caches

    def build():
        with _BUILD_LOCK:
            if not built:
                built.append(jax.jit(inner, static_argnums=1, donate_argnums=2, compiler_options=compiler_options()))
        return built[0]

    @functools.wraps(fun)
    def call(chunk, carry):
        return (built[0] if built else build())(*_split(chunk), carry)

    cast(Lowerable, call).lower = lambda chunk, carry: build().lower(*_split(chunk), carry)  # as in `jit`
    return call


def _split(tree) -> tuple[list, tuple]:
    """`tree`'s arrays (in leaf order, `None` elsewhere) and its hashable rest (structure and other leaves)."""
    leaves, structure = jax.tree.flatten(tree)
    arrays = [leaf if eqx.is_array(leaf) else None for leaf in leaves]
    rest = tuple(_DYNAMIC if eqx.is_array(leaf) else leaf for leaf in leaves)
    return arrays, (structure, rest)


def _join(arrays: list, static: tuple):
    structure, rest = static
    return jax.tree.unflatten(structure, [a if r is _DYNAMIC else r for a, r in zip(arrays, rest, strict=True)])


class _Dynamic:
    """Marks where an array goes back in `_join` (hashable, and equal only to itself)."""

    def __repr__(self) -> str:
        return "<array>"


_DYNAMIC = _Dynamic()
