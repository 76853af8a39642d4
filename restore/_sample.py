"""Run many independent lanes of a sampler, with every sum and tail kept on the device.

A run is a sequence of chunks, each one compiled `jax.lax.while_loop` that steps every
lane (`_run_loop.advance`); the host drives the chunks (`_driver.drive`: their lengths,
checkpoints and progress). After the step budget, the tours still open are run to their
end by another `while_loop`: over a narrower batch of the open lanes
(`_run_loop.finish`), or over every lane where there are too few lanes for that.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import time
from collections.abc import Callable, Mapping
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray

from ._accumulators import (
    host_totals,
)
from ._ahead import compile_ahead, wait, wait_lowered
from ._checkpoint import (
    CheckpointError,
    array_digest,
    key_fingerprint,
    load_checkpoint,
    read_header,
    save_checkpoint,
)
from ._compile import jit
from ._driver import Budget, Meter, drive
from ._observables import Observables
from ._result import SampleResult
from ._run_loop import CarryShape, Chunk, RunCarry, advance, carry_shardings, finish, finishing_width, start_carry
from ._sampler import AbstractSampler, check_sampler
from ._sharding import (
    Devices,
    LaneSharding,
    from_every_process,
    lane_sharding,
    map_lanes,
    put,
    to_host,
    wait_for_every_process,
)
from ._tails import tail_rows, tour_tails
from ._threefry import unrolled_keys
from ._trace import run_trace
from ._validation import check_integer, check_interval, check_key
from ._warnings import warn

Weights = Literal["rao_blackwell", "time"]

logger = logging.getLogger("restore")

#: Checkpoints of `restore.sample` hold the run's state in this layout (older ones are refused).
STATE_LAYOUT = "device-totals/2"


@jit(static_argnums=1, once=True)
def _lane_keys(key: PRNGKeyArray, num_lanes: int, first_lane: int | Array = 0) -> Array:
    """One key per lane, independent of how many lanes there are (lane `i` is reproducible)."""
    return jax.vmap(lambda i: jax.random.fold_in(key, i))(first_lane + jnp.arange(num_lanes))


@jit(filtered=True, once=True)
def _init(sampler, keys: Array, positions: Array | None, sharding: LaneSharding | None = None):
    keys = unrolled_keys(keys)
    if sharding is not None:
        if positions is None:
            return map_lanes(lambda s, k: s.init(k), sharding, sampler, keys)
        return map_lanes(lambda s, k, x: s.init(k, x), sharding, sampler, keys, positions)
    if positions is None:
        return jax.vmap(sampler.init)(keys)
    return jax.vmap(sampler.init)(keys, positions)


def _replicate(tree, sharding: LaneSharding):
    """Every array leaf of `tree` (e.g. a sampler's parameters) replicated over the mesh."""
    arrays, rest = eqx.partition(tree, eqx.is_array)
    return eqx.combine(jax.tree.map(lambda x: put(x, sharding.replicated), arrays), rest)


_start_carry_jit = jit(start_carry, static_argnums=1, once=True)


def _carry_shape(num_lanes: int, observe: Observables, has_tours: bool, capacity: int, given: bool, sharding) -> CarryShape:
    devices = 0 if sharding is None else sharding.num_devices
    rows = tail_rows(num_lanes // max(devices, 1), observe.size) if has_tours else 0
    return CarryShape(num_lanes, observe.size, rows, capacity, given, devices)


def _compile_run_ahead(like, init_keys, positions, lane_keys, observables, capacity: int, rao_blackwell: bool):
    """Compile the run loop's and the start states' programs in the background while the
    pilot runs (`_ahead`), for a sampler built like the calibrated one (`like`). The loop
    is traced first and the start states after it (see `_ahead`)."""

    def loop_arguments() -> tuple:
        # The start states' layout from one lane: tracing `vmap` over every lane is slower.
        one = [init_keys] if positions is None else [init_keys, positions]
        lane = jax.eval_shape(like.init, *[jax.ShapeDtypeStruct(a.shape[1:], a.dtype) for a in one])
        states = jax.tree.map(lambda a: jax.ShapeDtypeStruct((init_keys.shape[0], *a.shape), a.dtype), lane)
        observe = Observables(observables, like.dim, states.logdensity.dtype)
        shape = _carry_shape(init_keys.shape[0], observe, like.has_tours, capacity, positions is not None, None)
        layout = jax.eval_shape(functools.partial(start_carry, shape=shape), states)
        carry = jax.tree.map(lambda a: np.zeros(a.shape, a.dtype), layout)  # NumPy: no program to compile
        scalars = (np.zeros((), np.int32), np.zeros((), bool), np.zeros((), np.int32))  # length, finishing, thin
        return Chunk(like, observe, lane_keys, *scalars, rao_blackwell, None), carry

    inputs = (like, init_keys, positions, lane_keys, observables, capacity, rao_blackwell)
    loop = compile_ahead(advance, loop_arguments, inputs)
    return compile_ahead(_init, lambda: (like, init_keys, positions, None), inputs, after=loop), loop


@jit(once=True)
def _copied(tree):
    """A copy of `tree`'s arrays on the device."""
    return jax.tree.map(jnp.copy, tree)


def _zeros_like(tree):
    """NumPy zeros shaped like `tree`'s arrays (arguments to compile a program for, with no program to make them)."""
    return jax.tree.map(lambda a: np.zeros(a.shape, a.dtype), tree)


@jit(once=True)
def _split_three(key: PRNGKeyArray) -> tuple[PRNGKeyArray, PRNGKeyArray, PRNGKeyArray]:
    """`jax.random.split(key, 3)`, unpacked in one compiled program (not one to split and one to unpack)."""
    return tuple(jax.random.split(key, 3))


class _Saver:
    """Saves a run's carry to its checkpoint file and loads it back (onto the devices of a sharded run)."""

    def __init__(self, path, fingerprint: dict, layout: RunCarry | None):
        self.path, self.fingerprint, self.layout = path, fingerprint, layout

    def save(self, carry: RunCarry, *, done: int, wall_time: float, finished=False, finishing_steps=0, unfinished=0):
        """Write the run to the file. With several processes every process gathers the run (a
        collective), process 0 writes it, and all wait until it is written."""
        header = dict(self.fingerprint, done=int(done), wall_time=float(wall_time), finished=bool(finished))
        header.update(finishing_steps=int(finishing_steps), unfinished=int(unfinished))
        host = to_host(carry)
        if jax.process_index() == 0:
            save_checkpoint(self.path, host, header)
        wait_for_every_process(f"restore checkpoint {done} {finished}")

    def should_resume(self, resume: bool) -> bool:
        """Whether to continue from the file. With several processes all must find the same
        checkpoint (the file must be on a file system that every process sees)."""
        found = bool(resume) and os.path.exists(self.path)
        progress = [-1, -1]
        if found and jax.process_count() > 1:
            header = read_header(self.path)
            progress = [int(header.get("done", -1)), int(header.get("finished", False))]
        seen = from_every_process([int(found), *progress])
        if np.any(seen != seen[0]):
            found_by = {i: ("no checkpoint" if not row[0] else f"step {row[1]}") for i, row in enumerate(seen.tolist())}
            raise CheckpointError(
                f"the processes disagree about checkpoint {self.path} (by process: {found_by}); with several "
                "processes the checkpoint must be on a file system that every process sees"
            )
        return found

    def load(self, carry: RunCarry) -> tuple[RunCarry, dict]:
        restored, header = load_checkpoint(self.path, carry, self.fingerprint)
        if self.layout is not None:
            return jax.tree.map(put, restored, self.layout), header
        return jax.tree.map(jnp.asarray, restored), header


def _thinning(num_steps: int, num_lanes: int, max_draws: int, thin: int | None) -> tuple[int, int]:
    if thin is None:
        thin = max(1, math.ceil(num_steps * num_lanes / max_draws)) if max_draws > 0 else num_steps + 1
    thin = check_integer(thin, "thin")
    stored = 0 if max_draws <= 0 else min(math.ceil(num_steps / thin), max(max_draws // num_lanes, 0))
    return int(thin), int(stored)


def _draw_capacity(stored: int, num_lanes: int, max_draws: int) -> int:
    """Rows of the draws buffer: `stored` rounded up to a power of two, within the budget.

    The buffer's shape is part of the compiled program; rounding it up lets runs of
    other lengths (most of all, several short runs) share one program. The extra rows are
    never written and are cut off the result.
    """
    if stored == 0:
        return 0
    return min(1 << (stored - 1).bit_length(), max(max_draws // num_lanes, stored))


def sample(
    sampler: AbstractSampler,
    key: PRNGKeyArray,
    *,
    num_lanes: int,
    num_steps: int,
    observables: Mapping[str, Callable[[Array], Array]] | None = None,
    weights: Weights = "rao_blackwell",
    positions: Array | None = None,
    max_draws: int = 100_000,
    thin: int | None = None,
    draw_rows: int | None = None,
    progress: bool = True,
    num_chunks: int = 50,
    finish_tours: bool = True,
    devices: Devices = None,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_steps: int | None = None,
    checkpoint_seconds: float | None = 60.0,
    resume: bool = True,
    first_lane: int = 0,
) -> SampleResult:
    """Run `num_lanes` independent lanes for `num_steps` steps each and stream estimates.

    Lanes start at draws of the regeneration distribution (each lane is then a
    regenerative process from its first step: no burn-in), or at `positions`, in which
    case each lane's first, partial tour is left out of the tour-based estimates.
    Observables are integrated against the holding times as the run goes (constant
    memory); thinned draws with their weights are kept for post-hoc work. On one
    device, the first call of a process compiles the start states' and the run loop's
    programs in background threads while the pilot runs (`RESTORE_COMPILE_AHEAD=0` in
    the environment compiles them in turn instead; the results are the same).

    Arguments:
        sampler: a sampler (`restore.AbstractSampler`): `JumpRestore`, `Restore` or
            `MixtureMH`. One given a `tour_length` is calibrated first with a pilot
            estimate of `Z` (`SampleResult.pilot`).
        key: a JAX PRNG key. Lane `i` uses `fold_in(key, i)`-derived keys, so it gives
            the same path whatever `num_lanes` is. The loop draws with them as
            `unrolled_keys` (the same bits as JAX's keys, a faster program on the CPU).
        num_lanes: number of independent lanes, run in parallel with `vmap`.
        num_steps: steps per lane (each step is one density evaluation for RandomWalk
            and MALA local dynamics).
        observables: mapping from names to functions of one state; default
            `{"x": x, "x**2": x**2}`. The position `"x"` is streamed too when the
            mapping does not define it, so `result.estimate("x")` is always there.
        weights: `"rao_blackwell"` (holding times replaced by their means
            `1/(r + gamma)`, lower variance) or `"time"` (the sampled holding times).
        positions: optional `(num_lanes, d)` starting points.
        max_draws: budget of stored draws over all lanes: memory for draws is fixed by
            it, whatever the number of steps. When the run makes more states, every
            `thin`-th step is stored, with a message (logged, shown with the progress
            bar, and in `result.summary()`); `0` stores none.
        thin: store every `thin`-th state (overrides the budget's choice).
        draw_rows: rows per lane of the buffer of stored draws (default: the draws stored
            per lane rounded up to a power of two, within `max_draws`). The buffer is part
            of the compiled program, so runs of other lengths given the same `draw_rows`
            share one program (`restore.autosample` gives its stages the final run's).
            At least the number of draws stored per lane.
        progress: show a progress bar (updated between jitted chunks, so it costs nothing
            inside the loop).
        num_chunks: how many jitted chunks the run is cut into for the progress bar.
        finish_tours: after the budget, run each lane on (at most `num_steps` more
            steps, usually a handful) until its open tour ends, so that tour-based
            estimates are not biased towards short tours. With `False` the open tours
            are dropped.
        devices: shard the lanes over several devices. `None` (default): one device,
            the default one. An int `n`: the first `n` of `jax.devices()`; `"all"`: all
            of them; or a sequence of devices, or a `jax.sharding.Mesh` (the lane axis
            is split over all of its axes). `num_lanes` must be divisible by the number
            of devices. Everything lane-shaped (states, per-lane sums, lane keys, stored
            draws) is split over a 1-d mesh with `NamedSharding`, and the jitted loop is
            partitioned so that each device advances its own lanes (the per-lane step
            under `shard_map`), with no communication between devices while the budget
            runs; the tour histogram is kept as one partial histogram per device. Lane
            keys do not depend on the layout, so a sharded run gives the same per-lane
            paths as a run on one device. Results are gathered to the host as numpy
            (partial histograms summed) and every estimate merges the per-lane sums by
            summation, as on one device.
            Several hosts: call `jax.distributed.initialize()` first in every process,
            run the same program (same key, arguments and sampler) in each, and pass
            `devices="all"` (the mesh spans `jax.devices()`, all global devices, so the
            lanes are split across hosts); every process gets the full result, the
            same bits as one process running the same lanes (tested with two
            processes on one machine); see `docs/scaling.md`.
        checkpoint: a file to save the run's full state to (lane states, per-lane sums,
            tour histogram, stored draws, step count; keys are derived from `key` and the
            step count, so they need no saving), atomically, every `checkpoint_steps`
            steps and/or `checkpoint_seconds` seconds, when the step budget is spent, on
            Ctrl-C, and when the run is finished. If the file exists (and `resume`), the
            run continues from it: an interrupted and resumed run gives results
            bit-identical to an uninterrupted one with the same key and arguments, and a
            finished checkpoint returns its result at once. A checkpoint of another run
            (other key, sizes, sampler parameters, observables or devices) is refused with
            a `CheckpointError` that says what differs. With several processes, process 0
            writes the file, which must be on a file system that every process sees.
        checkpoint_steps: save at the end of the first chunk at or after every
            `checkpoint_steps` steps (chunk boundaries do not move, so a run computes
            the same numbers with or without checkpoints; raise `num_chunks` for finer
            saves).
        checkpoint_seconds: save when this many seconds have passed since the last save
            (checked between chunks); `None` for step-based saves only.
        resume: continue from an existing `checkpoint` file (default); `False` starts
            afresh and overwrites it.
        first_lane: index of this run's first lane. Lane `first_lane + i` gets the same
            keys in every run, so one large run can be split into parts (e.g. over
            machines) with `first_lane=0, n, 2n, ...` and the parts joined with
            `restore.merge_results`: the merged per-lane sums are bit-identical to those
            of one run with all the lanes.

    Returns:
        A `SampleResult` with estimates, standard errors and diagnostics. Interrupting
        with Ctrl-C returns the result of the chunks completed so far (marked
        `interrupted`), after saving it to `checkpoint` if one is given.
    """
    check_key(key)
    num_lanes, num_steps = check_integer(num_lanes, "num_lanes"), check_integer(num_steps, "num_steps")
    num_chunks, first_lane = check_integer(num_chunks, "num_chunks"), check_integer(first_lane, "first_lane", minimum=0)
    max_draws = check_integer(max_draws, "max_draws", minimum=0)
    if weights not in ("rao_blackwell", "time"):
        raise ValueError(f"weights must be 'rao_blackwell' or 'time', got {weights!r}")
    if checkpoint_steps is not None:
        checkpoint_steps = check_integer(checkpoint_steps, "checkpoint_steps")
    checkpoint_seconds = check_interval(checkpoint_seconds)
    sharding = lane_sharding(devices, num_lanes)
    sampler = check_sampler(sampler)
    if weights == "time" and sampler.is_diffusion:
        raise ValueError(
            "weights='time' is not available for diffusion dynamics: a thinning candidate stands for "
            "1/Gamma time units of the path (Campbell's formula), so use weights='rao_blackwell'"
        )

    key_pilot, key_init, key_run = _split_three(key)
    dim = sampler.dim
    if positions is not None:
        try:
            positions = jnp.asarray(positions)
        except (TypeError, ValueError) as error:
            raise TypeError(f"positions must be an array of numbers of shape (num_lanes, d), got {type(positions).__name__}") from error
        if positions.shape != (num_lanes, dim):
            raise ValueError(f"positions must have shape (num_lanes, d) = ({num_lanes}, {dim}), got {positions.shape}")
        if not bool(jnp.all(jnp.isfinite(positions))):
            raise ValueError("positions must be finite")
    thin_given = thin
    thin, stored = _thinning(num_steps, num_lanes, max_draws, thin)
    capacity = _draw_capacity(stored, num_lanes, max_draws)
    if draw_rows is not None:
        capacity = check_integer(draw_rows, "draw_rows", minimum=0)
        if capacity < stored:
            raise ValueError(f"draw_rows={capacity} is fewer than the {stored} draws this run stores per lane")
    init_keys = _lane_keys(key_init, num_lanes, first_lane)
    lane_keys = _lane_keys(key_run, num_lanes, first_lane)
    rao_blackwell = weights == "rao_blackwell"
    ahead = (None, None)
    if sharding is None and os.environ.get("RESTORE_COMPILE_AHEAD", "1") != "0":
        like = sampler.calibration_stand_in()
        ahead = _compile_run_ahead(like, init_keys, positions, lane_keys, observables, capacity, rao_blackwell)

    wait_lowered(ahead[1])  # the pilot's tracing would share Python's lock with the loop's (see `_ahead`)
    sampler, pilot = sampler.calibrate(key_pilot)
    if sharding is not None:
        sampler = _replicate(sampler, sharding)
        init_keys = put(init_keys, sharding.lanes)
        positions = None if positions is None else put(positions, sharding.lanes)
    wait(ahead[0])
    states = _init(sampler, init_keys, positions, sharding)
    dtype = states.logdensity.dtype
    observe = Observables(observables, dim, dtype)

    draws_note = None
    if thin_given is None and thin > 1 and stored > 0:
        draws_note = (
            f"thinned to the draws budget max_draws={max_draws:,}: {num_lanes:,} lanes x {num_steps:,} steps "
            f"make {num_lanes * num_steps:,} states, so one state in every {thin} steps of each lane is stored "
            f"({stored * num_lanes:,} draws, {stored * num_lanes * dim * jnp.dtype(dtype).itemsize / 2**20:.3g} MiB); "
            "raise max_draws or set thin to keep more"
        )
        logger.info(draws_note)  # said to the user when the draws are used (`SampleResult.note_thinning`)

    chunk = math.ceil(num_steps / min(num_chunks, num_steps))
    has_tours = sampler.has_tours
    shape = _carry_shape(num_lanes, observe, has_tours, capacity, positions is not None, sharding)
    layout = None
    if sharding is None:
        carry = _start_carry_jit(states, shape)  # one compiled program rather than one per array, kept across calls
    else:  # created in place on the devices, each holding its own lanes
        start = functools.partial(start_carry, shape=shape)
        layout = carry_shardings(jax.eval_shape(start, states), sharding)
        carry = jit(start, in_shardings=(layout.states,), out_shardings=layout, once=True)(states)
        lane_keys = put(lane_keys, sharding.lanes)
    wait(ahead[1])

    saver = None
    done, finishing_steps, unfinished, finished, spent = 0, 0, 0, False, 0.0
    if checkpoint is not None:
        fingerprint = {
            "state_layout": STATE_LAYOUT,
            "key": key_fingerprint(key),
            "sampler": type(sampler).__name__,
            "sampler_arrays": array_digest(sampler),
            "num_lanes": num_lanes,
            "first_lane": first_lane,
            "num_steps": num_steps,
            "num_chunks": num_chunks,
            "dim": dim,
            "dtype": str(dtype),
            "observables": [[slot.name, list(slot.shape)] for slot in observe.slots],
            "weights": weights,
            "thin": thin,
            "stored": stored,
            **({} if draw_rows is None else {"draw_rows": capacity}),
            "positions": None if positions is None else array_digest(positions),
            "finish_tours": bool(finish_tours),
            "num_devices": 1 if sharding is None else sharding.num_devices,
        }
        saver = _Saver(checkpoint, fingerprint, layout)
        if saver.should_resume(resume):
            carry, header = saver.load(carry)
            done, spent, finished = header["done"], header["wall_time"], header["finished"]
            finishing_steps, unfinished = header["finishing_steps"], header["unfinished"]
            if int(carry.step) != done + finishing_steps:
                raise CheckpointError(f"checkpoint {checkpoint} is inconsistent: step {int(carry.step)}, header {done}")

    thin_array = jnp.asarray(thin, jnp.int32)
    chunk_of = lambda length, finishing, width=0: Chunk(  # noqa: E731
        sampler, observe, lane_keys, jnp.asarray(length, jnp.int32), jnp.asarray(finishing), thin_array, rao_blackwell, sharding, width
    )
    width = finishing_width(num_lanes // (1 if sharding is None else sharding.num_devices))
    run: RunCarry = carry  # the committed carry: the last chunk the host has waited for
    head = carry  # the carry of the last chunk dispatched (the next chunk starts from it)
    trace_rows: list[tuple] = []  # per-chunk totals, from the chunks' reports
    committed_steps = done

    def dispatch(length: int) -> Callable[[], int]:
        """Dispatch a chunk after the last one dispatched; the function returned waits for it and commits it."""
        nonlocal head
        carry, report = advance(chunk_of(length, False), head)  # `head`'s buffers are donated to `carry`
        head = carry

        def commit() -> int:
            nonlocal run, committed_steps
            host = [np.asarray(x) for x in report]  # waits
            steps = int(host[0])
            time_, accepted, regenerations = (int(x) if x.dtype.kind == "i" else float(x) for x in host[1:4])
            run, committed_steps = carry, committed_steps + steps  # (`carry` may have given its buffers to the next chunk already)
            trace_rows.append((committed_steps, steps * num_lanes, time_, accepted, regenerations))
            return steps

        return commit

    def save(_steps: int, wall_time: float) -> None:
        assert saver is not None
        saver.save(run, done=committed_steps, wall_time=wall_time)  # the driver saves only a committed run that still holds its buffers

    finisher = None
    if width is not None and has_tours and finish_tours and sharding is None and os.environ.get("RESTORE_COMPILE_AHEAD", "1") != "0":
        # the narrow finishing program compiles in the background while the budget runs
        zero = np.zeros((), np.int32)
        arguments = lambda: (Chunk(sampler, observe, lane_keys, zero, np.zeros((), bool), zero, rao_blackwell, None, width), _zeros_like(carry))
        finisher = compile_ahead(finish, arguments, (sampler, observe, carry, lane_keys, rao_blackwell, width))
    label = f"{type(sampler).__name__}: {num_lanes} lanes"
    if sharding is not None:
        label += f" on {sharding.num_devices} devices"
    outcome = drive(
        dispatch,
        budget=Budget(steps=num_steps),
        chunk=chunk,
        done=done,
        spent=spent,
        meter=Meter(progress, label, num_steps, "steps", completed=done),
        save=save if saver is not None else None,
        save_every_steps=checkpoint_steps,
        save_every_seconds=checkpoint_seconds,
    )
    interrupted, done = outcome.interrupted, outcome.steps
    session_start, spent = time.perf_counter(), outcome.elapsed
    elapsed = lambda: spent + time.perf_counter() - session_start  # noqa: E731
    if interrupted:
        done = committed_steps  # the last chunk that finished
        warn(f"interrupted after {done} of {num_steps} steps; returning the partial result")
    if has_tours and not interrupted and finish_tours and not finished:
        budget_run = _copied(run)  # the finishing takes `run`'s buffers; Ctrl-C during it returns this
        try:
            limit = jnp.asarray(num_steps, jnp.int32)
            if width is None:  # every lane until the last open tour ends
                ended, report = advance(chunk_of(limit, True), run)
            else:  # a narrower batch of the open lanes
                wait(finisher)
                ended, report = finish(chunk_of(limit, True, width), run)
            extra, still_open = int(report.steps), int(report.open_tours)  # waits for the finishing
            run, finishing_steps, unfinished = ended, extra, still_open
        except KeyboardInterrupt:  # keep the budget's result; its open tours are dropped
            run, interrupted = budget_run, True
            warn("interrupted while finishing the open tours; returning the result without them")
    if saver is not None and not interrupted and not finished:
        saver.save(run, done=done, wall_time=elapsed(), finished=True, finishing_steps=finishing_steps, unfinished=unfinished)
    if unfinished:
        warn(
            f"{unfinished} lanes still had an open tour after {finishing_steps} extra steps; those tours are "
            "left out of the tour-based estimates, which are therefore marked unreliable (tours can outlast the "
            "run: the regeneration barely covers a region where the target has mass, or the density's mass is infinite)",
            RuntimeWarning,
        )
    wall_time = elapsed()
    host = to_host(run)  # numpy, gathered over devices (and processes)
    sums, histogram = host_totals(host.totals)
    stored_rows = min(stored, math.ceil(done / thin))
    return SampleResult.from_run(
        sampler=sampler,
        pilot=pilot,
        observables=observe,
        sums=sums,
        histogram=histogram,
        tails=tour_tails(host.tails) if has_tours else None,
        draws=np.asarray(host.draws)[:stored_rows],
        draw_weights=np.asarray(host.draw_weights)[:stored_rows],
        final_state=host.states,
        num_steps=done,
        finishing_steps=finishing_steps,
        thin=thin,
        weights=weights,
        wall_time=wall_time,
        interrupted=interrupted,
        draws_note=draws_note,
        unfinished_tours=unfinished,
        trace=run_trace(trace_rows),
    )
