"""Jump Restore: a pi-invariant Markov kernel embedded in continuous time, killed and regenerated."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import numpy as np
from jaxtyping import Array

from ._parts import check_parts
from ._restore import AbstractRestore, RestoreState
from ._validation import check_positive
from .dynamics import Jump
from .local import AbstractLocalKernel
from .regeneration import AbstractRegeneration
from .transfer import Independent

JumpRestoreState = RestoreState
"""The state of a jump-Restore lane (the general `RestoreState`)."""


class JumpRestore(AbstractRestore):
    """Jump Restore sampler (Algorithm 7.1 of the jump Restore paper), one lane at a time.

    The general `Restore` process with one phase: local dynamics `Jump(local, local_rate)`
    (the Markov kernel `local` embedded in continuous time with exponential holding
    times) and an independent transfer `Independent(regeneration)`. The kill rate is
    `gamma(x) = c_tilde * u(x) / p(x)`, with `u` the density of `regeneration`. The state
    at any fixed time is distributed as the target once it was. Each step costs one new
    density evaluation (plus the kernel's internal ones, e.g. HMC's trajectory), shared
    between the local candidate and the regeneration draw.

    Give exactly one of `log_rate` (`log c_tilde`, the raw constant) or `tour_length`
    (the mean tour duration `T = 1/c`, in units of local-move time). A tour length is
    turned into `log c_tilde = log Z_hat - log T` by `calibrate(key)` with an importance
    sampling pilot estimate of the normalising constant `Z`; `calibrate` returns the
    calibrated sampler and the pilot. `restore.sample` does it for you and keeps the pilot
    in its result.

    The run's floating dtype is that of the regeneration distribution's draws
    (`sampler.dtype`): starting positions, proposals and the log density's values are cast
    to it, so a float32 regeneration gives a float32 run even with `jax_enable_x64` on.

    Arguments:
        logdensity: unnormalised log density of one point `(d,)`, returning a real
            scalar (checked once at construction; an exception it raises is re-raised as a
            `ValueError` naming it). NaN or `+inf` values are treated as zero density and
            counted. Gradient-based kernels (MALA, HMC) also need `jax.grad` of it.
        local: the local kernel, e.g. `restore.local.RandomWalk(0.5)`.
        regeneration: the regeneration distribution `nu`, e.g.
            `restore.regeneration.laplace_mixture(logdensity, starts)`.
        log_rate: `log c_tilde`.
        tour_length: mean tour duration `T > 0`.
        local_rate: rate `r > 0` of local moves (default 1).
        pilot_size: number of regeneration draws of the pilot estimate of `Z`.
        has_aux: `logdensity` returns a pair `(log density, aux)`, as with
            `jax.value_and_grad(..., has_aux=True)`; `aux` (any pytree of arrays) is kept in
            the state and reported in `StepInfo.aux` for the state each step weighs (a
            renderer splats the colour of a light path this way, at no second evaluation).
    """

    def __init__(
        self,
        logdensity: Callable[[Array], Any],
        local: AbstractLocalKernel,
        regeneration: AbstractRegeneration,
        *,
        log_rate: float | Array | None = None,
        tour_length: float | None = None,
        local_rate: float = 1.0,
        pilot_size: int = 4096,
        has_aux: bool = False,
    ):
        check_parts(logdensity, local, regeneration, has_aux=has_aux)
        if log_rate is not None and getattr(log_rate, "ndim", 0) != 0:
            raise ValueError(f"log_rate must be a scalar, got shape {np.shape(log_rate)}")
        if local_rate is None:
            raise TypeError("local_rate must be a positive number (the rate r of local moves), got None")
        dynamics = Jump(local, check_positive(local_rate, "local_rate"))
        self._setup(logdensity, dynamics, Independent(regeneration), log_rate, tour_length, None, None, pilot_size, has_aux)

    @property
    def local(self) -> AbstractLocalKernel:
        return cast(Jump, self.dynamics[0]).kernel

    @property
    def regeneration(self) -> AbstractRegeneration:
        return self.transfers[0].reference

    @property
    def local_rate(self) -> float:
        return cast(Jump, self.dynamics[0]).rate
