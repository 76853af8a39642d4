"""The demo: jump Restore against the MH mixture baseline on a 10-d multimodal target."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._estimates import Estimate
from ._io import matplotlib_for, save_and_close
from ._jump_restore import JumpRestore
from ._mixture_mh import MixtureMH
from ._random import normal_draws
from ._result import SampleResult
from ._sample import sample
from .local import RandomWalk
from .regeneration import laplace_mixture


class DemoOutcome(NamedTuple):
    """Everything the demo measured."""

    truth: np.ndarray
    restore: Estimate
    mh: Estimate
    restore_seconds: float
    mh_seconds: float
    evaluations: int
    log_z: Estimate
    num_modes_found: int
    restore_result: SampleResult
    mh_result: SampleResult


def run_demo(
    dim: int = 10,
    num_lanes: int = 512,
    num_steps: int = 1500,
    tour_length: float = 10.0,
    seed: int = 0,
    progress: bool = True,
) -> DemoOutcome:
    """Sample a well-separated Gaussian mixture with unequal weights two ways, at equal evaluations.

    The regeneration (and MH large-step) distribution is a mixture of Student-t Laplace
    approximations with *equal* weights at the modes found from 64 random starts, so
    both samplers must discover the unequal mode weights themselves. Both use the same
    random-walk kernel; MH takes a large step with probability `1 / tour_length`.
    """
    from targets.analytic import well_separated_gaussian_mixture

    target = well_separated_gaussian_mixture(dim, 3, separation=8.0)
    key = jax.random.key(seed)
    k_starts, k_restore, k_mh = jax.random.split(key, 3)
    starts = 6.0 * normal_draws(k_starts, (64, dim), jnp.result_type(float))
    nu = laplace_mixture(target.logdensity, starts, tails="student_t", df=5.0, weights="equal")
    local = RandomWalk(2.38 / np.sqrt(dim))
    one_hot = lambda x: jax.nn.one_hot(target.assign_mode(x), target.num_modes, dtype=x.dtype)  # noqa: E731
    observables = {"mode weights": one_hot}

    restore_sampler = JumpRestore(target.logdensity, local, nu, tour_length=tour_length)
    mh_sampler = MixtureMH(target.logdensity, local, nu, large_step_probability=1.0 / tour_length)
    kwargs: dict[str, Any] = dict(num_lanes=num_lanes, num_steps=num_steps, observables=observables, progress=progress)

    t0 = time.perf_counter()
    restore_result = sample(restore_sampler, k_restore, **kwargs)
    restore_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    mh_result = sample(mh_sampler, k_mh, **kwargs)
    mh_seconds = time.perf_counter() - t0
    return DemoOutcome(
        truth=np.asarray(target.weights),
        restore=restore_result.estimate("mode weights"),
        mh=mh_result.estimate("mode weights"),
        restore_seconds=restore_seconds,
        mh_seconds=mh_seconds,
        evaluations=num_lanes * num_steps,
        log_z=restore_result.normalising_constant("tours"),
        num_modes_found=len(nu.components),
        restore_result=restore_result,
        mh_result=mh_result,
    )


def plot_demo(outcome: DemoOutcome, path: Path) -> Path:
    """Errors of the mode-weight estimates with 95% intervals, for both samplers."""
    matplotlib_for("the demo's plot")
    import matplotlib.pyplot as plt

    k = outcome.truth.size
    x = np.arange(k)
    fig, ax = plt.subplots(figsize=(6.4, 4.0), constrained_layout=True)
    ax.axhline(0.0, color="0.5", lw=1)
    for shift, est, name, colour in ((-0.1, outcome.restore, "jump Restore", "C0"), (0.1, outcome.mh, "MH mixture", "C3")):
        ax.errorbar(x + shift, est.value - outcome.truth, yerr=1.96 * est.standard_error, fmt="o", color=colour, capsize=4, label=name)
    ax.set_xticks(x, [f"mode {i}\n(weight {w:.3f})" for i, w in enumerate(outcome.truth)])
    ax.set_ylabel("estimate - truth (95% interval)")
    ax.set_title(f"Mode weights, {outcome.evaluations:,} density evaluations each")
    ax.legend()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_and_close(fig, path, dpi=120)
    return path
