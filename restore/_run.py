"""One run of `restore.sample` (`Run`): set up, the step budget, the finishing of open tours, the result.

A run is a sequence of chunks, each one compiled loop (`_chunk.run_steps`) that steps every
lane (`_run_loop.advance`); the host drives the chunks (`_driver.drive`: their lengths,
checkpoints and progress). After the step budget, the tours still open are run to their
end (`_driver.drive_finishing`) by calls of another such loop: over a narrower batch of the
open lanes (`_run_loop.finish`), after a first pass over every lane where there are too few
lanes to start with the narrow batch.
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
from ._ahead import Ahead, compile_ahead, wait, wait_lowered
from ._calibration import calibrate, calibrated_like
from ._checkpoint import (
    CheckpointError,
    array_digest,
    key_fingerprint,
    load_checkpoint,
    read_header,
    save_checkpoint,
)
from ._compile import jit
from ._driver import Budget, Meter, drive, drive_finishing
from ._observables import Observables
from ._options import Checkpoint, SaveDraws, as_checkpoint
from ._result import SampleResult
from ._run_loop import (
    FINISHING_CALL,
    CarryShape,
    Chunk,
    RunCarry,
    active,
    advance,
    carry_shardings,
    finish,
    finishing_limit,
    finishing_width,
    fold_finishing,
    start_carry,
)
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
from ._validation import check_integer, check_key
from ._warnings import warn

Weights = Literal["rao_blackwell", "time"]

logger = logging.getLogger("restore")

#: Checkpoints of `restore.sample` hold the run's state in this layout (older ones are refused).
STATE_LAYOUT = "device-totals/3"


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
        scalars = (np.zeros((), np.int32), np.zeros((), bool), np.zeros((), np.int32), np.zeros((), np.int32))  # length, finishing, thin, half
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


class Run:
    """One run of `restore.sample`: set up on the device, then `advance` through the step
    budget, `finish` the open tours and read the `result`.

    Everything a run keeps is in one `RunCarry` on the device; the host holds the carry of
    the last chunk it waited for (`committed`) and of the last chunk dispatched (`head`).
    The arguments are `restore.sample`'s (see there), checked here. On one device, the
    first run of a process compiles the start states' and the loop's programs in
    background threads while the pilot runs (`RESTORE_COMPILE_AHEAD=0` in the environment
    compiles them in turn instead; the results are the same).
    """

    def __init__(
        self,
        sampler: AbstractSampler,
        key: PRNGKeyArray,
        *,
        num_lanes: int,
        num_steps: int,
        observables: Mapping[str, Callable[[Array], Array]] | None,
        weights: Weights,
        positions: Array | None,
        save: SaveDraws,
        progress: bool,
        num_chunks: int,
        finish_tours: bool | int,
        devices: Devices,
        checkpoint: Checkpoint | str | os.PathLike | None,
        first_lane: int,
    ):
        check_key(key)
        num_lanes, num_steps = check_integer(num_lanes, "num_lanes"), check_integer(num_steps, "num_steps")
        num_chunks, first_lane = check_integer(num_chunks, "num_chunks"), check_integer(first_lane, "first_lane", minimum=0)
        if weights not in ("rao_blackwell", "time"):
            raise ValueError(f"weights must be 'rao_blackwell' or 'time', got {weights!r}")
        if not isinstance(save, SaveDraws):
            raise TypeError(f"save must be a restore.SaveDraws, got {type(save).__name__}")
        checkpoint = as_checkpoint(checkpoint)
        finish_limit = _finish_limit(finish_tours, num_steps)
        sharding = lane_sharding(devices, num_lanes)
        sampler = check_sampler(sampler)
        if weights == "time" and sampler.is_diffusion:
            raise ValueError(
                "weights='time' is not available for diffusion dynamics: a thinning candidate stands for "
                "1/Gamma time units of the path (Campbell's formula), so use weights='rao_blackwell'"
            )
        positions = _checked_positions(positions, num_lanes, sampler.dim)
        key_pilot, key_init, key_run = _split_three(key)
        plan = save.plan(num_steps, num_lanes)
        init_keys = _lane_keys(key_init, num_lanes, first_lane)
        lane_keys = _lane_keys(key_run, num_lanes, first_lane)
        rao_blackwell = weights == "rao_blackwell"
        ahead = (None, None)
        if sharding is None and os.environ.get("RESTORE_COMPILE_AHEAD", "1") != "0":
            like = calibrated_like(sampler)
            ahead = _compile_run_ahead(like, init_keys, positions, lane_keys, observables, plan.rows, rao_blackwell)

        wait_lowered(ahead[1])  # the pilot's tracing would share Python's lock with the loop's (see `_ahead`)
        sampler, self.pilot = calibrate(sampler, key_pilot)
        if sharding is not None:
            sampler = _replicate(sampler, sharding)
            init_keys = put(init_keys, sharding.lanes)
            positions = None if positions is None else put(positions, sharding.lanes)
        wait(ahead[0])
        states = _init(sampler, init_keys, positions, sharding)
        dtype = states.logdensity.dtype
        observe = Observables(observables, sampler.dim, dtype)
        self.draws_note = save.plan(num_steps, num_lanes, sampler.dim, jnp.dtype(dtype).itemsize).note
        if self.draws_note is not None:
            logger.info(self.draws_note)  # said to the user when the draws are used (`SampleResult.note_thinning`)

        shape = _carry_shape(num_lanes, observe, sampler.has_tours, plan.rows, positions is not None, sharding)
        layout = None
        if sharding is None:
            carry = _start_carry_jit(states, shape)  # one compiled program rather than one per array, kept across calls
        else:  # created in place on the devices, each holding its own lanes
            start = functools.partial(start_carry, shape=shape)
            layout = carry_shardings(jax.eval_shape(start, states), sharding)
            carry = jit(start, in_shardings=(layout.states,), out_shardings=layout, once=True)(states)
            lane_keys = put(lane_keys, sharding.lanes)
        wait(ahead[1])

        self.sampler, self.observe, self.sharding, self.plan = sampler, observe, sharding, plan
        self.thin = jnp.asarray(plan.thin, jnp.int32)  # on the device once, not per chunk
        self.num_lanes, self.num_steps, self.num_chunks, self.weights = num_lanes, num_steps, num_chunks, weights
        self.lane_keys, self.rao_blackwell, self.progress = lane_keys, rao_blackwell, progress
        self.finish_limit = finish_limit  # the most finishing steps a lane may take; 0: the open tours are dropped
        self.checkpoint = checkpoint
        self.done, self.finishing_steps, self.unfinished, self.finished, self.spent = 0, 0, 0, False, 0.0
        self.interrupted = False
        self.finisher: Ahead | None = None  # the narrow finishing program, compiling in the background
        self.saver = None
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
                "dim": sampler.dim,
                "dtype": str(dtype),
                "observables": [[slot.name, list(slot.shape)] for slot in observe.slots],
                "weights": weights,
                "thin": plan.thin,
                "stored": plan.stored,
                **({} if save.rows is None else {"draw_rows": plan.rows}),
                "positions": None if positions is None else array_digest(positions),
                "finish_tours": finish_tours if isinstance(finish_tours, bool) else finish_limit,
                "num_devices": 1 if sharding is None else sharding.num_devices,
            }
            self.saver = _Saver(checkpoint.path, fingerprint, layout)
            if self.saver.should_resume(checkpoint.resume):
                carry, header = self.saver.load(carry)
                self.done, self.spent, self.finished = header["done"], header["wall_time"], header["finished"]
                self.finishing_steps, self.unfinished = header["finishing_steps"], header["unfinished"]
                if int(carry.step) != self.done + self.finishing_steps:
                    raise CheckpointError(f"checkpoint {checkpoint.path} is inconsistent: step {int(carry.step)}, header {self.done}")
        self.committed: RunCarry = carry  # the last chunk the host has waited for
        self.head: RunCarry = carry  # the last chunk dispatched (the next chunk starts from it)
        self.committed_steps = self.dispatched = self.done
        self.half = jnp.asarray(num_steps // 2, jnp.int32)  # on the device once, not per chunk
        self.trace_rows: list[tuple] = []  # per-chunk totals, from the chunks' reports
        self.width, self.wide_first = finishing_width(num_lanes // (1 if sharding is None else sharding.num_devices))
        self.session_start = time.perf_counter()

    def _chunk(self, length, finishing: bool, width: int = 0, taken: Array | None = None, limit: Array | None = None) -> Chunk:
        return Chunk(
            self.sampler, self.observe, self.lane_keys, jnp.asarray(length, jnp.int32), jnp.asarray(finishing), self.thin,
            self.half, self.rao_blackwell, self.sharding, width, taken, limit,
        )  # fmt: skip

    def _dispatch(self, length: int) -> Callable[[], int]:
        """Dispatch a chunk after the last one dispatched (cut in two at the middle of the budget,
        where the lanes' sums so far are kept as the run's first half); the function returned
        waits for it and commits it."""
        start, middle = self.dispatched, self.num_steps // 2
        self.dispatched += length
        parts = [middle - start, start + length - middle] if start < middle < start + length else [length]
        reports = []
        for part in parts:
            carry, report = advance(self._chunk(part, False), self.head)  # `head`'s buffers are donated to `carry`
            self.head = carry
            reports.append(report)

        def commit() -> int:
            rows, before = [], self.committed_steps
            done = before
            for report in reports:
                host = [np.asarray(x) for x in report]  # waits
                steps = int(host[0])
                time_, accepted, regenerations = (int(x) if x.dtype.kind == "i" else float(x) for x in host[1:4])
                done += steps
                rows.append((done, steps * self.num_lanes, time_, accepted, regenerations))
            self.committed, self.committed_steps = carry, done  # (`carry` may have given its buffers to the next chunk already)
            self.trace_rows += rows
            return done - before

        return commit

    def _save(self, _steps: int, wall_time: float) -> None:
        assert self.saver is not None
        self.saver.save(self.committed, done=self.committed_steps, wall_time=wall_time)  # only a committed run still holds its buffers

    def _elapsed(self) -> float:
        return self.spent + time.perf_counter() - self.session_start

    def advance(self) -> None:
        """Run the step budget in chunks (progress bar, checkpoints, Ctrl-C: `_driver.drive`)."""
        finisher = None
        if (
            not self.wide_first and self.sampler.has_tours and self.finish_limit and self.sharding is None
            and os.environ.get("RESTORE_COMPILE_AHEAD", "1") != "0"
        ):  # fmt: skip
            # the narrow finishing program compiles in the background while the budget runs
            zero, carry = np.zeros((), np.int32), self.committed
            taken = np.zeros((self.num_lanes,), np.int32)
            chunk = Chunk(self.sampler, self.observe, self.lane_keys, zero, np.zeros((), bool), zero, zero, self.rao_blackwell, None, self.width, taken, zero)
            inputs = (self.sampler, self.observe, carry, self.lane_keys, self.rao_blackwell, self.width)
            finisher = compile_ahead(finish, lambda: (chunk, _zeros_like(carry)), inputs)
        self.finisher = finisher
        label = f"{type(self.sampler).__name__}: {self.num_lanes} lanes"
        if self.sharding is not None:
            label += f" on {self.sharding.num_devices} devices"
        checkpoint = self.checkpoint
        outcome = drive(
            self._dispatch,
            budget=Budget(steps=self.num_steps),
            chunk=math.ceil(self.num_steps / min(self.num_chunks, self.num_steps)),
            done=self.done,
            spent=self.spent,
            meter=Meter(self.progress, label, self.num_steps, "steps", completed=self.done),
            save=self._save if self.saver is not None else None,
            save_every_steps=None if checkpoint is None else checkpoint.every_steps,
            save_every_seconds=None if checkpoint is None else checkpoint.every_seconds,
        )
        self.interrupted, self.done = outcome.interrupted, outcome.steps
        self.session_start, self.spent = time.perf_counter(), outcome.elapsed
        if self.interrupted:
            self.done = self.committed_steps  # the last chunk that finished
            warn(f"interrupted after {self.done} of {self.num_steps} steps; returning the partial result")

    def finish(self) -> None:
        """Run the open tours to their end (if `finish_tours`) and save the finished run to its checkpoint."""
        if self.sampler.has_tours and not self.interrupted and self.finish_limit and not self.finished:
            budget_run = _copied(self.committed)  # the finishing takes the run's buffers; Ctrl-C during it returns this
            try:
                self.committed, self.finishing_steps, self.unfinished = self._finish_tours()
            except KeyboardInterrupt:  # keep the budget's result; its open tours are dropped
                self.committed, self.interrupted = budget_run, True
                warn("interrupted while finishing the open tours; returning the result without them")
        if self.saver is not None and not self.interrupted and not self.finished:
            self.saver.save(
                self.committed, done=self.done, wall_time=self._elapsed(), finished=True,
                finishing_steps=self.finishing_steps, unfinished=self.unfinished,
            )  # fmt: skip
        if self.unfinished:
            warn(
                f"{self.unfinished} lanes still had an open tour after {self.finishing_steps} extra steps; those tours are "
                "left out of the tour-based estimates, which are therefore marked unreliable (tours can outlast the "
                "run: the regeneration barely covers a region where the target has mass, or the density's mass is infinite)",
                RuntimeWarning,
            )

    def _finish_tours(self) -> tuple[RunCarry, int, int]:
        """The carry with each open tour run to its end (or to the `finish_limit` of its lane's
        finishing steps), the steps that took and the tours still open.

        Runs of few lanes first step every lane, for up to the budget's steps, in one call of
        the chunk's program; the tours still open then (all of them, in runs of many lanes) go
        to the narrow batch, in calls of at most `FINISHING_CALL` steps of the batch with a
        progress bar between them and Ctrl-C taken within one call.
        """
        carry, steps = self.committed, 0
        if self.wide_first:  # every lane until the last open tour ends, or the budget's steps
            wide = min(self.finish_limit, self.num_steps)
            carry, report = advance(self._chunk(wide, True), carry)
            steps, still_open = int(report.steps), int(report.open_tours)
            if still_open == 0 or steps >= self.finish_limit:
                return carry, steps, still_open
        wait(self.finisher)
        taken = jnp.full((self.num_lanes,), steps, jnp.int32)  # every lane still open has taken them all
        if self.sharding is not None:
            taken = put(taken, self.sharding.lanes)
        limit = jnp.asarray(self.finish_limit, jnp.int32)
        opened = int(jnp.sum(active(carry.sums), dtype=jnp.int32))
        still_open = opened

        def call() -> tuple[int, int, bool]:  # one call of the narrow batch, committed
            nonlocal carry, taken, still_open
            carry, report, finished = finish(self._chunk(FINISHING_CALL, True, self.width, taken, limit), carry)
            taken, still_open = finished.taken, int(report.open_tours)
            return int(report.steps), still_open, int(finished.waiting) == 0

        steps += drive_finishing(call, opened, self.progress)
        return fold_finishing(carry, self.sharding), steps, still_open

    def result(self) -> SampleResult:
        """The run's result, read from the device once (gathered over devices and processes)."""
        wall_time = self._elapsed()
        host = to_host(self.committed)
        sums, histogram = host_totals(host.totals)
        # without the finishing, the tours open at the budget's end are left out (and counted as such)
        dropped = self.sampler.has_tours and (self.interrupted or not self.finish_limit)
        unfinished = int(np.sum(active(sums))) if dropped else self.unfinished
        stored_rows = min(self.plan.stored, math.ceil(self.done / self.plan.thin))
        return SampleResult.from_run(
            sampler=self.sampler,
            pilot=self.pilot,
            observables=self.observe,
            sums=sums,
            histogram=histogram,
            tails=tour_tails(host.tails) if self.sampler.has_tours else None,
            draws=np.asarray(host.draws)[:stored_rows],
            draw_weights=np.asarray(host.draw_weights)[:stored_rows],
            final_state=host.states,
            num_steps=self.done,
            finishing_steps=self.finishing_steps,
            thin=self.plan.thin,
            weights=self.weights,
            wall_time=wall_time,
            interrupted=self.interrupted,
            draws_note=self.draws_note,
            unfinished_tours=unfinished,
            trace=run_trace(self.trace_rows),
            tours_dropped=dropped,
        )


def _finish_limit(finish_tours: bool | int, num_steps: int) -> int:
    """The most finishing steps a lane may take (`finishing_limit`), 0 for none."""
    if isinstance(finish_tours, bool | np.bool_):
        return finishing_limit(num_steps) if finish_tours else 0
    return finishing_limit(num_steps, check_integer(finish_tours, "finish_tours (True, False or a number of steps)"))


def _checked_positions(positions, num_lanes: int, dim: int) -> Array | None:
    """`positions` as a finite `(num_lanes, d)` array, or `None`."""
    if positions is None:
        return None
    try:
        positions = jnp.asarray(positions)
    except (TypeError, ValueError) as error:
        raise TypeError(f"positions must be an array of numbers of shape (num_lanes, d), got {type(positions).__name__}") from error
    if positions.shape != (num_lanes, dim):
        raise ValueError(f"positions must have shape (num_lanes, d) = ({num_lanes}, {dim}), got {positions.shape}")
    if not bool(jnp.all(jnp.isfinite(positions))):
        raise ValueError("positions must be finite")
    return positions
