"""Compile a run's programs in the background while its pilot runs.

The first `restore.sample` call of a process compiles three programs whose compilation
does not depend on each other's results: the pilot that calibrates the kill rate, the
start states, and the run loop (the largest: 2-4 s on a 2-core CPU). Their inputs'
shapes are known before the pilot has run, so the start states and the run loop are
compiled in two background threads (XLA compiles without holding Python's lock) while the
pilot compiles and runs. A program compiled this way lands in JAX's cache, so the call
that runs it compiles nothing. Each signature is compiled ahead once per process; a
compilation that fails here is dropped silently (the call itself then compiles the
program, and reports the error if there is one).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import jax
import numpy as np

logger = logging.getLogger("restore")

_EXECUTOR = ThreadPoolExecutor(max_workers=2, thread_name_prefix="restore-compile")
_STARTED: set = set()
_LOCK = threading.Lock()


def compile_ahead(program: Callable, arguments: Callable[[], tuple], inputs: tuple) -> Future | None:
    """Compile `program` for `arguments()` (built in a background thread) unless this process
    has done so for the same `inputs` before (what `arguments` builds them from; checked
    here, so a repeated call starts no thread). The future's result is `True` when it compiled."""
    try:
        seen = (program, _signature(inputs))
    except TypeError:  # an unhashable input: no way to tell a repeated call
        return None
    with _LOCK:
        if seen in _STARTED:
            return None
        _STARTED.add(seen)
    return _EXECUTOR.submit(_compile, program, arguments)


def wait(future: Future | None) -> None:
    """Wait until a compilation started by `compile_ahead` has ended (whatever its outcome)."""
    if future is not None:
        future.exception()


def _compile(program: Callable, arguments: Callable[[], tuple]) -> bool:
    try:
        program.lower(*arguments()).compile()  # type: ignore[attr-defined]
        return True
    except Exception as error:  # noqa: BLE001 - the call compiles it again and reports any error
        logger.debug("compiling %s ahead failed: %r", getattr(program, "__name__", program), error)
        return False


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
