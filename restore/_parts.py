"""The check of a sampler's parts: a local kernel, a regeneration distribution and a log density that fit."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from jaxtyping import Array

from ._validation import check_logdensity
from .local import AbstractLocalKernel
from .regeneration import AbstractRegeneration


def check_parts(logdensity: Callable[[Array], Any], local: Any, regeneration: Any, has_aux: bool = False) -> None:
    """A sampler's parts: a restore.local kernel, a regeneration distribution, and a
    log density and kernel that fit its dimension."""
    if not isinstance(local, AbstractLocalKernel):
        raise TypeError(f"local must be a restore.local kernel, got {type(local).__name__}")
    if not isinstance(regeneration, AbstractRegeneration):
        raise TypeError(f"regeneration must be a restore.regeneration distribution, got {type(regeneration).__name__}")
    check_logdensity(logdensity, regeneration.dim, with_grad=local.uses_gradient, has_aux=has_aux)
    local.check_dim(regeneration.dim)
