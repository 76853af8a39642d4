"""Wall-clock timing with compilation measured apart, and the raw throughput of the target."""

from __future__ import annotations

import time
from collections.abc import Callable

import jax
import jax.monitoring as monitoring
import jax.numpy as jnp
import numpy as np

# JAX reports tracing, lowering and XLA compilation as time spans under these events.
_COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
)


class Stopwatch:
    """Time a block, and the part of it JAX spent tracing and compiling.

    Compile time is the length of the union of JAX's compile-event spans inside the
    block (nested spans count once), so `wall - compile` is the run time a warm
    (already compiled) call would take, without running anything twice.
    """

    def __init__(self) -> None:
        self._spans: list[tuple[float, float]] = []
        self.wall = 0.0
        self.compile = 0.0

    def _listen(self, event: str, start_time: float, end_time: float, **kwargs: str | int) -> None:
        if event in _COMPILE_EVENTS:
            self._spans.append((start_time, end_time))

    def __enter__(self) -> Stopwatch:
        monitoring.register_event_time_span_listener(self._listen)
        self._start = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.wall = time.perf_counter() - self._start
        monitoring.unregister_event_time_span_listener(self._listen)
        self.compile = min(_union_length(self._spans), self.wall)

    @property
    def run(self) -> float:
        """Wall time minus compilation."""
        return max(self.wall - self.compile, 0.0)

    def compile_so_far(self) -> float:
        """Compile time inside the block up to now (for time-budget loops)."""
        return _union_length(self._spans)

    def elapsed_run(self) -> float:
        """Run time (compilation excluded) inside the block up to now."""
        return time.perf_counter() - self._start - self.compile_so_far()


def _union_length(spans: list[tuple[float, float]]) -> float:
    total, end = 0.0, -np.inf
    for s, e in sorted(spans):
        if e <= end:
            continue
        total += e - max(s, end)
        end = e
    return total


def raw_rate(logdensity: Callable, x0: jnp.ndarray, steps: int = 200, repeats: int = 3) -> float:
    """Evaluations per second of `jit(vmap(logdensity))` over a scan of `steps` perturbed batches `x0`.

    The physical limit for a sampler that needs one new evaluation per lane and step
    (the approach of `examples/benchmark_core.py`); compilation excluded, median of repeats.
    """

    @jax.jit
    def run(x):
        def body(carry, _):
            x, acc = carry
            x = x + 1e-9
            return (x, acc + jnp.sum(jax.vmap(logdensity)(x))), None

        return jax.lax.scan(body, (x, jnp.zeros((), x.dtype)), None, length=steps)[0][1]

    jax.block_until_ready(run(x0))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(run(x0))
        times.append(time.perf_counter() - t)
    return x0.shape[0] * steps / float(np.median(times))
