"""Compile a run's programs in the background while its pilot runs.

The first `restore.sample` call of a process compiles three programs whose compilation
does not depend on each other's results: the pilot that calibrates the kill rate, the
start states, and the run loop (the largest). Their inputs'
shapes are known before the pilot has run, so the start states and the run loop are
compiled in two background threads (XLA compiles without holding Python's lock) while the
pilot compiles and runs. A program compiled this way lands in JAX's cache, so the call
that runs it compiles nothing.

Tracing and lowering hold Python's lock, so they run in order of need: the run loop's
first, alone (its XLA compilation is the longest step of a first call), then the start
states' and the pilot's, while XLA compiles the loop. Started all at once they shared
the lock and delayed the loop's compilation, and the demo's first call took longer
(`docs/benchmarks.md`).

Each signature is compiled ahead once per process; a compilation that fails here is
dropped silently (the call itself then compiles the program, and reports the error if
there is one).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, NamedTuple, cast

import jax
import numpy as np

from ._compile import Lowerable

logger = logging.getLogger("restore")

_EXECUTOR = ThreadPoolExecutor(max_workers=2, thread_name_prefix="restore-compile")
_STARTED: set = set()
_LOCK = threading.Lock()


class Ahead(NamedTuple):
    """A compilation started by `compile_ahead`: `done` ends with it (its result is `True`
    when it compiled), `lowered` is set once its tracing and lowering have ended."""

    done: Future
    lowered: threading.Event


def compile_ahead(
    program: Callable, arguments: Callable[[], tuple], inputs: tuple, after: Ahead | None = None
) -> Ahead | None:
    """Compile `program` for `arguments()` (built in a background thread) unless this process
    has done so for the same `inputs` before (what `arguments` builds them from; checked
    here, so a repeated call starts no thread). With `after` (started earlier), the tracing
    waits until `after` is lowered."""
    try:
        seen = (program, _signature(inputs))
    except TypeError:  # an unhashable input: no way to tell a repeated call
        return None
    with _LOCK:
        if seen in _STARTED:
            return None
        _STARTED.add(seen)
    lowered = threading.Event()
    # `after` was submitted first, so it has left the queue (first in, first out) before
    # this job waits for it: a waiting job never holds up the job it waits for.
    return Ahead(_EXECUTOR.submit(_compile, program, arguments, lowered, after), lowered)


def wait(ahead: Ahead | None) -> None:
    """Wait until a compilation started by `compile_ahead` has ended (whatever its outcome)."""
    if ahead is not None:
        ahead.done.exception()


def wait_lowered(ahead: Ahead | None) -> None:
    """Wait until a compilation started by `compile_ahead` has been traced and lowered (or has failed)."""
    if ahead is not None:
        ahead.lowered.wait()


def _compile(program: Callable, arguments: Callable[[], tuple], lowered: threading.Event, after: Ahead | None) -> bool:
    try:
        wait_lowered(after)
        # the programs compiled ahead are built by `restore._compile.jit` or `jit_chunk`, which give them `.lower`
        compiling = cast(Lowerable, program).lower(*arguments())
        lowered.set()
        compiling.compile()
        return True
    except Exception as error:  # noqa: BLE001 - the call compiles it again and reports any error
        logger.debug("compiling %s ahead failed: %r", getattr(program, "__name__", program), error)
        return False
    finally:
        lowered.set()


def _signature(args: tuple) -> tuple:
    """What selects a compiled program: the pytree structure, the static leaves, and each
    array's shape and dtype (raises `TypeError` for an unhashable leaf)."""
    leaves, structure = jax.tree.flatten(args)

    def leaf(x: Any) -> Any:
        if isinstance(x, (jax.Array, np.ndarray)):
            return (x.shape, x.dtype, getattr(x, "weak_type", False))
        hash(x)
        return x

    return structure, tuple(leaf(x) for x in leaves)
