"""Calls into the Mitsuba tracer are serialised, whichever threads XLA runs its callbacks on."""

import threading
import time
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np

from targets.mitsuba._jax_bridge import values_callback


def test_concurrent_callbacks_never_enter_the_tracer_together():
    inside, most = [0], [0]
    guard = threading.Lock()

    def tracer(u):  # stands in for the Dr.Jit call: records how many threads are inside at once
        with guard:
            inside[0] += 1
            most[0] = max(most[0], inside[0])
        time.sleep(0.05)
        with guard:
            inside[0] -= 1
        n = u.shape[0]
        return SimpleNamespace(luminance=np.ones(n, np.float32), rgb=np.ones((n, 3), np.float32))

    call = jax.jit(values_callback(tracer, 2))
    u = jnp.zeros((4, 2), jnp.float32)
    jax.block_until_ready(call(u))  # compiled before the threads start
    threads = [threading.Thread(target=lambda: jax.block_until_ready(call(u))) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert most[0] == 1
