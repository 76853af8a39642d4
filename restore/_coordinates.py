"""Does the log density read exactly the coordinates it is given?

A wrong `dim` fails silently in JAX: indexing past the end of an array clamps the index
(`x[1]` of a 1-d point reads `x[0]`), so a 2-d density given `dim=1` is a different, proper
density with a wrong `Z`; and a 2-d density given `dim=3` is flat along the third
coordinate, so its mass is infinite and no sampler can normalise it. Both are found by
one compiled program on a few points where the user expects mass: JAX's `checkify`
catches out-of-range indices, and moving each coordinate by about the spread of the
points shows which coordinates the density never reacts to.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import checkify
from jaxtyping import Array

from ._compile import jit
from ._warnings import warn


def check_coordinates(logdensity: Callable[[Array], Array], points: Array) -> None:
    """Refuse a `logdensity` that indexes past its `d` coordinates; warn when it ignores some.

    Arguments:
        logdensity: the log density of one point `(d,)`.
        points: a few points `(n, d)` where the user expects mass (e.g. seeding starts).
    """
    try:
        error, (base, moved) = _probe(logdensity, points)
        message = error.get()
    except Exception:  # noqa: BLE001 - code checkify cannot run (callbacks, custom calls): nothing to check
        return
    d = points.shape[-1]
    if message:
        raise ValueError(
            f"logdensity reads past the {d} coordinates of its point ({message.strip()}); JAX would "
            f"silently read another coordinate instead: give the dimension the density reads (dim={d} is too small)"
        )
    base, moved = np.asarray(base), np.asarray(moved)
    finite = np.isfinite(base)
    if not finite.any():
        return
    # "did not change": within rounding (the moved points are evaluated in another order)
    tolerance = 16 * np.finfo(base.dtype).eps * (1.0 + np.abs(base[:, None]))
    with np.errstate(invalid="ignore"):  # -inf - -inf at points outside the support
        reacts = np.any(~(np.abs(moved - base[:, None]) <= tolerance) & finite[:, None], axis=0)
    if reacts.any() and not reacts.all():
        flat = np.flatnonzero(~reacts)
        shown = ", ".join(map(str, flat[:10])) + (", ..." if flat.size > 10 else "")
        warn(
            f"logdensity did not change when coordinate{'s' if flat.size > 1 else ''} {shown} moved (at "
            f"{int(finite.sum())} points, by about their spread): a density that does not depend on a "
            "coordinate has infinite mass along it, so Z and every estimate are meaningless. Is dim "
            f"({d}) larger than the number of coordinates the density reads ({int(reacts.sum())})?",
            RuntimeWarning,
        )


@jit(filtered=True, once=True)
def _probe(logdensity, points):
    """Out-of-range indices (a `checkify` error) at the first point, and the density at each
    point and at each point moved along each coordinate in turn: `(n,)` and `(n, d)`."""
    error, _ = checkify.checkify(logdensity, errors=checkify.index_checks)(points[0])
    step = jnp.std(points, axis=0) + 1.0
    moved_points = points[:, None, :] + jnp.diag(step)[None]  # (n, d, d)
    value = lambda x: jnp.asarray(logdensity(x), points.dtype)
    base = jax.vmap(value)(points)
    moved = jax.vmap(jax.vmap(value))(moved_points)
    return error, (base, moved)
