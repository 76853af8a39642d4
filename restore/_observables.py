"""Observables: named functions of a state, flattened into one vector per state."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array


def position(x: Array) -> Array:
    """The state itself (the default observable `"x"`)."""
    return x


def square(x: Array) -> Array:
    """Elementwise square of the state (the default observable `"x**2"`)."""
    return x**2


DEFAULT_OBSERVABLES: dict[str, Callable[[Array], Array]] = {"x": position, "x**2": square}


class Slot(NamedTuple):
    """Where one observable lives in the flat vector."""

    name: str
    shape: tuple[int, ...]
    start: int
    size: int


class Observables(eqx.Module):
    """A fixed set of named observables evaluated together as one flat vector.

    The position `"x"` is always among them: a mapping that does not define `"x"` gets it
    added after its own observables (so `result.estimate("x")` works with any
    observables, and the user's observables keep their places in the vector).
    """

    functions: tuple[Callable[[Array], Array], ...] = eqx.field(static=True)
    slots: tuple[Slot, ...] = eqx.field(static=True)

    def __init__(self, observables: Mapping[str, Callable[[Array], Array]] | None, dim: int, dtype):
        observables = DEFAULT_OBSERVABLES if observables is None else observables
        if not isinstance(observables, Mapping) or not observables:
            raise ValueError("observables must be a non-empty mapping from names to functions of one state")
        if "x" not in {str(name) for name in observables}:
            observables = {**observables, "x": position}
        slots, start = [], 0
        probe = jax.ShapeDtypeStruct((dim,), dtype)
        for name, fn in observables.items():
            if not callable(fn):
                raise TypeError(f"observable {name!r} is not callable")
            try:
                out = jax.eval_shape(fn, probe)
            except Exception as err:
                raise ValueError(f"observable {name!r} failed on a state of shape ({dim},): {err}") from err
            if not hasattr(out, "shape"):
                raise ValueError(f"observable {name!r} must return an array, got {type(out).__name__}")
            size = math.prod(out.shape)
            slots.append(Slot(str(name), tuple(out.shape), start, size))
            start += size
        self.functions = tuple(observables.values())
        self.slots = tuple(slots)

    @property
    def size(self) -> int:
        return sum(slot.size for slot in self.slots)

    def __call__(self, x: Array) -> Array:
        return jnp.concatenate([jnp.ravel(fn(x)).astype(x.dtype) for fn in self.functions])

    @property
    def requested(self) -> tuple[Slot, ...]:
        """The observables as they were given: without the position `"x"` where it was only added."""
        added = len(self.slots) > 1 and self.slots[-1].name == "x" and self.functions[-1] is position
        return self.slots[:-1] if added else self.slots

    def slot(self, name: str) -> Slot:
        for slot in self.slots:
            if slot.name == name:
                return slot
        raise KeyError(f"no observable named {name!r}; streamed observables are {[s.name for s in self.slots]}")
