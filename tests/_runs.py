"""Helpers for the subprocess scripts of the tests that run one sampler in several layouts."""

import contextlib
import os

import numpy as np


def forced_devices_flags(devices: int) -> str:
    """`XLA_FLAGS` for a subprocess on `devices` forced CPU devices, with the suite's compiler flags (`tests/conftest.py`)."""
    return f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()


def record(arrays: dict, name: str, result) -> None:
    """Add `result`'s per-lane sums, draws, histogram and estimates to `arrays`, under `name/`."""
    for field in result.sums._fields:
        arrays[f"{name}/sums/{field}"] = getattr(result.sums, field)
    arrays[f"{name}/draws"] = result.draws
    arrays[f"{name}/draw_weights"] = result.draw_weights
    arrays[f"{name}/histogram_counts"], arrays[f"{name}/histogram_times"] = result.histogram
    for obs in ("x", "x**2"):
        est = result.estimate(obs)
        arrays[f"{name}/estimate/{obs}"] = np.stack([est.value, est.standard_error])
    arrays[f"{name}/log_z"] = np.asarray(result.normalising_constant().value)


@contextlib.contextmanager
def ctrl_c_after(chunks: int):
    """Inside, `restore.sample` is interrupted (`KeyboardInterrupt`) when it dispatches chunk
    `chunks + 1` (the chunk in flight, the last, is waited for and committed)."""
    import restore._run as run_module

    advance, calls = run_module.advance, []

    def interrupting(*args, **kwargs):
        calls.append(1)
        if len(calls) == chunks + 1:
            raise KeyboardInterrupt
        return advance(*args, **kwargs)

    run_module.advance = interrupting
    try:
        yield
    finally:
        run_module.advance = advance
