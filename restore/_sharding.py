"""Sharding the lane axis of a run over several devices (and hosts) with `jax.sharding`.

Lanes are independent, so the lane axis of everything lane-shaped (states, per-lane sums,
lane keys, stored draws) is split over a 1-d mesh, the tour histogram is kept as one
partial histogram per device, and the sampler's parameters and the step counter are
replicated. The jitted loop is partitioned by XLA; the per-lane work runs under
`shard_map`, so each device advances exactly its own lanes. See `docs/scaling.md`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import equinox as eqx
import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

#: What `restore.sample(devices=...)` accepts.
Devices = int | Literal["all"] | Sequence[jax.Device] | Mesh | None

AXIS = "lanes"
_EXPECTED = "devices must be None, 'all', an int, a sequence of devices or a Mesh"


class LaneSharding(NamedTuple):
    """A mesh and the shardings of lane-leading, lane-second and replicated arrays."""

    mesh: Mesh
    lanes: NamedSharding  # lane axis first: states, sums, lane keys
    lanes_second: NamedSharding  # lane axis second: stored draws (slot, lane, ...)
    replicated: NamedSharding  # shared over lanes: histogram, step counter

    @property
    def num_devices(self) -> int:
        return int(self.mesh.devices.size)


def lane_sharding(devices: Devices, num_lanes: int) -> LaneSharding | None:
    """The sharding for `devices` (`None`: no sharding, the single-device path)."""
    if devices is None:
        return None
    if isinstance(devices, Mesh):
        mesh = devices
        axes: Any = mesh.axis_names if len(mesh.axis_names) > 1 else mesh.axis_names[0]
    else:
        if isinstance(devices, str):
            if devices != "all":
                raise ValueError(f"{_EXPECTED}, got {devices!r}")
            chosen = jax.devices()
        elif isinstance(devices, bool):
            raise TypeError(f"{_EXPECTED}, got {devices!r}")
        elif isinstance(devices, (int, np.integer)):
            available = jax.devices()
            if not 1 <= int(devices) <= len(available):
                platform = available[0].platform
                raise ValueError(f"devices={int(devices)} but {len(available)} devices are available ({platform})")
            chosen = available[: int(devices)]
        else:
            try:
                chosen = list(devices)
            except TypeError:
                raise TypeError(f"{_EXPECTED}, got {devices!r}") from None
            if not chosen or not all(isinstance(d, jax.Device) for d in chosen):
                raise TypeError(f"{_EXPECTED}, got {devices!r}")
            if len({d.id for d in chosen}) != len(chosen):
                raise ValueError("devices must not repeat a device")
        mesh, axes = Mesh(np.array(chosen), (AXIS,)), AXIS
    size = int(mesh.devices.size)
    if num_lanes % size:
        raise ValueError(
            f"num_lanes ({num_lanes}) must be divisible by the number of devices ({size}) to shard the lanes evenly"
        )
    return LaneSharding(
        mesh,
        NamedSharding(mesh, PartitionSpec(axes)),
        NamedSharding(mesh, PartitionSpec(None, axes)),
        NamedSharding(mesh, PartitionSpec()),
    )


def map_lanes(fn, sharding: LaneSharding, module, *lane_args):
    """`vmap(lambda *a: fn(module, *a))(*lane_args)`, each device mapping only its own lanes.

    Runs under `shard_map`, so the per-lane work is never left to the partitioner's
    choices (which could, e.g., gather all lanes for a linear solve shared over lanes).
    `module` (a sampler: a pytree with static parts) is replicated; `lane_args` and the
    outputs are split along their leading lane axis.
    """
    arrays, static = eqx.partition(module, eqx.is_array)

    def local(arrays, *lane_args):
        return jax.vmap(lambda *a: fn(eqx.combine(arrays, static), *a))(*lane_args)

    lanes = sharding.lanes.spec
    return jax.shard_map(
        local, mesh=sharding.mesh, in_specs=(PartitionSpec(),) + (lanes,) * len(lane_args), out_specs=lanes
    )(arrays, *lane_args)


def map_devices(fn, sharding: LaneSharding, *args):
    """`fn` on each device's block of `args` (all split along their leading axis)."""
    lanes = sharding.lanes.spec
    return jax.shard_map(fn, mesh=sharding.mesh, in_specs=(lanes,) * len(args), out_specs=lanes)(*args)


def put(x, sharding: NamedSharding):
    """A global array with `sharding` from `x`, which every process holds in full.

    In one process this is `jax.device_put`. With several processes, arrays that are
    not global yet go through the host with `make_array_from_callback` (each process
    fills its own devices' shards); PRNG key arrays travel as their key data.
    """
    if jax.process_count() == 1:
        return jax.device_put(x, sharding)
    if isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
        impl = jax.random.key_impl(x)
        return jax.random.wrap_key_data(put(jax.random.key_data(x), sharding), impl=impl)
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
        return x if x.sharding == sharding else jax.device_put(x, sharding)
    host = np.asarray(x)
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])


def to_host(tree):
    """Numpy copies of every array of `tree`, gathered from all processes where needed."""

    def gather(x):
        if isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            return jax.random.wrap_key_data(gather(jax.random.key_data(x)), impl=jax.random.key_impl(x))
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            from jax.experimental import multihost_utils

            # A global array that spans several processes is gathered whole: `tiled=True`
            # keeps its global shape (`tiled=False` would stack per-process copies, and is
            # refused for arrays that no single process holds in full).
            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return np.asarray(x) if isinstance(x, jax.Array) else x

    return jax.tree.map(gather, tree)


def from_every_process(values: Sequence[int]) -> np.ndarray:
    """`values` (a few integers) of every process, one row per process (one row with one process)."""
    row = np.asarray(values, np.int64)[None]
    if jax.process_count() == 1:
        return row
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(row[0])).reshape(jax.process_count(), -1)


def wait_for_every_process(name: str) -> None:
    """A barrier over all processes (nothing with one process)."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)
