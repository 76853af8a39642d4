"""The compiled programs of a run: chunks of steps over every lane, and the finishing of open tours.

Everything a run keeps lives in a `RunCarry` of fixed shape on the device for the whole
run: the lanes' states, the current chunk's per-lane sums and tour histogram, the run's
totals, the tail buffers and the stored draws. A chunk (`advance`) steps every lane, adds
each step to the chunk's sums and histogram and offers the tours that end to the tail
buffers; at its end the chunk's sums join the totals and restart, and the host learns a
`ChunkReport` of a few scalars. Nothing per lane leaves the device until the run ends.

After the step budget, the tours still open are run to their end (`finish`): dropping
them would bias the estimates towards short tours (long tours are the ones likely to
straddle the end); finishing them makes the number of tours of each lane a stopping
time, so by Wald's identity the pooled sums `sum F` and `sum T` have the right ratio of
expectations. Nearly every lane has an open tour at the budget, but most end within a few
steps and a few last for hundreds, so stepping all lanes until the last tour ends would
mostly step lanes that are done. `finish` steps a narrower batch of `width` slots instead,
each holding one open lane: a lane whose tour ends is written back and its slot takes
the next open lane. Lane `i`'s `j`-th finishing step draws with the key of global step
`N + j` (`N` the budget), as a step of every lane would, so its path is the same whatever
the width. A lane may take up to ten times `N` finishing steps (`finishing_limit`); a tour
still open then is left out, and the run says so. Runs of fewer lanes (`finishing_width`)
first step every lane, for up to `N` steps (no second program to compile when, as usual,
every tour ends by then), and hand the lanes still open to the narrow batch. The narrow
batch runs in calls of `FINISHING_CALL` of its steps (a progress bar and Ctrl-C between them); the lanes still in a slot at the end of a call are written back
and taken again by the next, and the finishing's sums join the totals once, after the
last call (`fold_finishing`), so they do not depend on where the calls end.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._accumulators import (
    LaneSums,
    Totals,
    add_events,
    counted_ends,
    fold,
    halved,
    init_histogram,
    init_lane_sums,
    init_totals,
    open_tour_totals,
    restart_sums,
    update_histogram,
    update_step_sums,
)
from ._chunk import run_open_lanes, run_steps
from ._compile import jit, jit_chunk
from ._exceedances import append, make_room
from ._observables import Observables
from ._sharding import LaneSharding, map_devices, map_lanes
from ._sparse_draws import batch_lanes, draw_slots
from ._tails import SCORING, TourTailBuffers, init_tails, tail_rows_of, wanted_tours
from ._threefry import unrolled_keys


class RunCarry(NamedTuple):
    """Everything a run keeps, on the device, in arrays of fixed shape for the whole run.

    `sums` and `histogram` are the current chunk's (added to `totals` and restarted at the
    end of every chunk); `tails` the run's largest tours; `lane` each lane's index;
    `step` the steps every lane has taken (the budget's, then the finishing's).
    """

    states: Any
    sums: LaneSums
    histogram: tuple[Array, Array]
    totals: Totals
    tails: TourTailBuffers | None
    lane: Array
    draws: Array
    draw_weights: Array
    step: Array


class ChunkReport(NamedTuple):
    """What the host learns after a chunk: a few scalars, whatever the number of lanes.

    Attributes:
        steps: steps per lane the chunk ran (finishing: the most steps any lane took).
        time: simulated (continuous) time of all lanes in the chunk.
        accepted: accepted local moves (or MH large steps) in the chunk.
        regenerations: kills followed by a regeneration in the chunk.
        open_tours: lanes still in a counted tour at the end of the chunk.
    """

    steps: Array
    time: Array
    accepted: Array
    regenerations: Array
    open_tours: Array


class CarryShape(NamedTuple):
    """The sizes of a run's carry beyond its states (hashable: a static argument)."""

    num_lanes: int
    size: int
    tail_rows: int  # rows of the tail buffer (of each device's); 0 without tours
    capacity: int
    given_positions: bool
    num_devices: int  # 0: not sharded


def active(sums: LaneSums) -> Array:
    """Lanes inside a tour that counts (an open tour after a regeneration)."""
    return (sums.open_steps > 0) & ~sums.skip_first


def start_carry(states, shape: CarryShape) -> RunCarry:
    """The carry at the start of a run: zero sums and totals, empty tail buffers and draws, step 0."""
    dtype, (num_lanes, size, tail_rows, capacity, given, devices) = states.logdensity.dtype, shape
    per_device = lambda tree: tree if not devices else jax.tree.map(lambda h: jnp.broadcast_to(h, (devices,) + h.shape), tree)
    histogram = per_device(init_histogram(dtype))
    sums = init_lane_sums(num_lanes, size, dtype, jnp.full((num_lanes,), given))
    return RunCarry(
        states=states,
        sums=sums,
        histogram=histogram,
        totals=init_totals(sums, histogram),
        tails=per_device(init_tails(tail_rows, size, dtype)) if tail_rows else None,
        lane=jnp.arange(num_lanes, dtype=jnp.int32),
        draws=jnp.zeros((capacity, num_lanes, states.position.shape[-1]), dtype),
        draw_weights=jnp.zeros((capacity, num_lanes), dtype),
        step=jnp.zeros((), jnp.int32),
    )


def carry_shardings(carry: RunCarry, sharding: LaneSharding) -> RunCarry:
    """Lane axes split over the mesh; the partial histograms and tail buffers one per device; the step counter replicated."""
    lanes = lambda tree: jax.tree.map(lambda _: sharding.lanes, tree)
    shardings = dict(
        states=lanes(carry.states),
        sums=lanes(carry.sums),
        histogram=lanes(carry.histogram),  # one row per device
        totals=lanes(carry.totals),
        tails=lanes(carry.tails),
        lane=sharding.lanes,
        draws=sharding.lanes_second,
        draw_weights=sharding.lanes_second,
        step=sharding.replicated,
    )
    return RunCarry._make(shardings[field] for field in RunCarry._fields)


class _Tallied(NamedTuple):
    """One step of some lanes, added to their sums, with what the histogram and tail buffers need."""

    states: Any
    sums: LaneSums
    observed: Array
    weight: Array
    histogram: Any
    tails: Any


def _tally(
    states, sums: LaneSums, histogram, tails, lane: Array, new_states, info, values: Array, rao_blackwell: bool, batch: int | None, on: Array | None = None
) -> _Tallied:
    """The lanes' states and sums after one step (`on`: the lanes that step; the others keep
    theirs), with the tours that ended and the starts drawn added to the sums, the histogram
    and the tail buffers (`lane`: the lanes' indices in the run).

    The lanes with such an event (a tenth or fewer in a typical step) are gathered `batch`
    at a time (`_sparse_draws.batch_lanes`, in lane order), so that only their rows of the
    tour sums are read and written; `batch=None` for samplers without tours.
    """
    weight = info.expected_holding_time if rao_blackwell else info.holding_time
    if on is not None:
        weight = jnp.where(on, weight, 0.0)
    integrals, durations = open_tour_totals(sums, values, weight)
    ended, drawn = counted_ends(sums, info), info.start_drawn
    if on is not None:
        ended, drawn = ended & on, drawn & on
    updated = update_step_sums(sums, values, weight, info, integrals, durations)
    if on is not None:
        keep = lambda new, old: jnp.where(on.reshape((-1,) + (1,) * (new.ndim - 1)), new, old)
        updated, new_states = jax.tree.map(keep, updated, sums), jax.tree.map(keep, new_states, states)
    if batch is not None:
        updated, histogram, tails = _events(updated, histogram, tails, lane, ended, drawn, integrals, durations, info.log_importance_weight, batch)
    return _Tallied(new_states, updated, info.position, weight, histogram, tails)


def _events(sums: LaneSums, histogram, tails, lane, ended, drawn, integrals, durations, log_importance_weight, batch: int):
    """The sums, histogram and tail buffer after the tours that `ended` and the starts `drawn`,
    `batch` lanes at a time (the buffer, compacted first if this step's rows above its
    thresholds might not fit, takes those of each batch)."""
    event = ended | drawn
    num_lanes = event.shape[0]
    rank = jnp.cumsum(event, dtype=jnp.int32) - 1
    total = rank[-1] + 1
    wanted = wanted_tours(tails, durations, integrals, ended, log_importance_weight, drawn)
    tails = make_room(tails, jnp.sum(wanted, dtype=jnp.int32) + batch, SCORING)

    def body(loop):
        sums, histogram, tails, start = loop
        index = batch_lanes(event, rank, start, batch)
        safe = jnp.minimum(index, num_lanes - 1)
        valid = index < num_lanes
        e, d = ended[safe] & valid, drawn[safe] & valid
        f, t, w = integrals[safe], durations[safe], log_importance_weight[safe]
        sums = add_events(sums, index, e, d, f, t, w)
        histogram = update_histogram(histogram, t, e)
        tails = append(tails, tail_rows_of(t, f, e, w, d), lane[safe], wanted[safe] & valid)
        return sums, histogram, tails, start + batch

    zero = jnp.zeros((), jnp.int32)
    return jax.lax.while_loop(lambda loop: loop[3] < total, body, (sums, histogram, tails, zero))[:3]


def event_batch(sampler, num_lanes: int) -> int | None:
    """Lanes gathered per batch of tour ends and starts (`_tally`), or `None` for a sampler without tours."""
    if not sampler.has_tours:
        return None
    return draw_slots(num_lanes, sampler.tour_end_fraction()) or num_lanes


def _one_device(tree):
    return jax.tree.map(lambda a: a[0], tree)


def _per_device(tree):
    return jax.tree.map(lambda a: a[None], tree)


def _end_chunk(carry: RunCarry, steps: Array, half: Array | np.ndarray) -> tuple[RunCarry, ChunkReport]:
    """The chunk's report, and the carry with the chunk's sums and histogram added to the totals
    and restarted (and, if the chunk ended at step `half`, the lanes' sums so far kept as the
    first half of the run: `_accumulators.halved`)."""
    folded = _folded(carry)
    totals, sums = halved(folded.totals, folded.sums, carry.step == half)
    return folded._replace(totals=totals, sums=sums), _report(carry, steps)


def _report(carry: RunCarry, steps: Array) -> ChunkReport:
    s = carry.sums
    return ChunkReport(
        steps, jnp.sum(s.all_t), jnp.sum(s.num_accepted), jnp.sum(s.num_regenerations), jnp.sum(active(s), dtype=jnp.int32)
    )


def _folded(carry: RunCarry) -> RunCarry:
    """The carry with the chunk's sums and histogram added to the totals and restarted."""
    s = carry.sums
    totals = fold(carry.totals, s, carry.histogram)
    return carry._replace(sums=restart_sums(s), histogram=jax.tree.map(jnp.zeros_like, carry.histogram), totals=totals)


def _observed_step(sampler_and_observe, key, state):
    """One lane's step, with the observables at the state its weight refers to."""
    sampler, observe = sampler_and_observe
    new_state, info = sampler.step(key, state)
    return new_state, info, observe(info.position)


class Chunk(NamedTuple):
    """What a chunk's program takes besides the carry (none of it is donated).

    Attributes:
        sampler: the sampler.
        observe: the observables.
        lane_keys: each lane's key.
        length: steps of the chunk (finishing at full width: at most this many per lane;
            `finish`: iterations of the narrow batch); NumPy arrays (here and in `finishing`,
            `thin`, `taken` and `limit`) only where a chunk is built to compile ahead.
        finishing: finish the open tours (start none), else run the step budget.
        thin: store the state every `thin` steps.
        half: the middle of the step budget: a chunk that ends at this step keeps the
            lanes' sums so far as the first half of the run (`_accumulators.halved`).
        rao_blackwell: weigh by the expected holding times (static).
        sharding: how the lanes are split over devices (static; `None` on one device).
        width: slots of the narrow finishing batch (`finish` only; static).
        taken: the finishing steps each lane took in earlier calls (`finish` only).
        limit: the most finishing steps a lane may take (`finish` only).
    """

    sampler: Any
    observe: Observables
    lane_keys: Array
    length: Array | np.ndarray
    finishing: Array | np.ndarray
    thin: Array | np.ndarray
    half: Array | np.ndarray
    rao_blackwell: bool
    sharding: LaneSharding | None = None
    width: int = 0
    taken: Array | np.ndarray | None = None
    limit: Array | np.ndarray | None = None


@jit_chunk
def advance(chunk: Chunk, carry: RunCarry) -> tuple[RunCarry, ChunkReport]:
    """Run every lane for `length` steps (a chunk of the step budget), or (`finishing`) until
    each lane's open tour ends, at most `length` steps. The carry is donated: its buffers
    become the new carry's (a run keeps no second copy of its sums, tails and draws).

    Every step updates the chunk's per-lane sums and histogram, offers the tours that
    ended to the tail buffers and stores the state every `thin` steps; at the end the
    chunk's sums join the run's totals (`_end_chunk`). One compiled program serves every
    chunk length, thinning and both modes (all are traced), so runs of other lengths reuse
    it. When finishing, no tour starts: a lane whose tour has ended stops (its state and
    sums are frozen), and every lane is stepped until the last open tour ends (`finish`
    steps a narrower batch instead, in a program of its own).

    With a `sharding` (static; `None` on one device) the lanes are split over a mesh:
    the per-lane work (the sampler's step and the observables), the histogram and the
    tail buffers run under `shard_map`, each device on its own lanes with its own partial
    histogram and buffers, and the carry's layout is pinned inside the loop. The devices
    do not talk to each other within a chunk (when finishing, they agree at every step
    whether any lane is still in a tour); the chunk's report is a sum over them.
    """
    sampler, observe, lane_keys, length, finishing, thin, half, rao_blackwell, sharding = chunk[:9]

    def going(carry):
        if sharding is not None:  # no cross-device reduction per step unless finishing
            return jax.lax.cond(finishing, lambda: jnp.any(active(carry.sums)), lambda: jnp.asarray(True))
        return ~finishing | jnp.any(active(carry.sums))

    def body(_, carry):
        keys = jax.vmap(lambda k: jax.random.fold_in(k, carry.step))(lane_keys)
        if sharding is None:
            new_states, info = sampler.step_lanes(keys, carry.states)
            values = jax.vmap(observe)(info.position)
        else:
            new_states, info, values = map_lanes(_observed_step, sharding, (sampler, observe), keys, carry.states)
        on = ~finishing | active(carry.sums)
        if sharding is None:
            t = _tally(carry.states, carry.sums, carry.histogram, carry.tails, carry.lane, new_states, info, values, rao_blackwell, batch, on)
        else:  # each device its own lanes, with one partial histogram and one set of buffers per device

            def local(states, sums, histogram, tails, lane, new_states, info, values, on):
                t = _tally(states, sums, _one_device(histogram), _one_device(tails), lane, new_states, info, values, rao_blackwell, batch, on)
                return t._replace(histogram=_per_device(t.histogram), tails=_per_device(t.tails))

            t = map_devices(local, sharding, carry.states, carry.sums, carry.histogram, carry.tails, carry.lane, new_states, info, values, on)
        histogram, tails = t.histogram, t.tails
        draws, draw_weights = carry.draws, carry.draw_weights
        if draws.shape[0] > 0:
            slot = carry.step // thin
            draws, draw_weights = jax.lax.cond(
                ~finishing & (carry.step % thin == 0) & (slot < draws.shape[0]),
                lambda d, w: (d.at[slot].set(t.observed), w.at[slot].set(t.weight)),
                lambda d, w: (d, w),
                draws,
                draw_weights,
            )
        new = carry._replace(
            states=t.states, sums=t.sums, histogram=histogram, tails=tails, draws=draws, draw_weights=draw_weights, step=carry.step + 1
        )
        if sharding is not None:
            new = jax.lax.with_sharding_constraint(new, carry_shardings(new, sharding))
        return new

    lane_keys = unrolled_keys(lane_keys)  # the same bits, a faster program on the CPU
    batch = event_batch(sampler, carry.lane.shape[0] // (1 if sharding is None else sharding.num_devices))
    if sharding is not None:
        carry = jax.lax.with_sharding_constraint(carry, carry_shardings(carry, sharding))
    carry, done = run_steps(body, carry, length, going)
    carry, report = _end_chunk(carry, done, half)
    if sharding is not None:
        carry = jax.lax.with_sharding_constraint(carry, carry_shardings(carry, sharding))
    return carry, report


#: Runs of at least this many lanes (per device) finish their open tours `NARROW_FACTOR` times
#: narrower (`finish`); smaller runs first step all their lanes (`advance`), which needs no
#: second compiled program, and hand the narrow batch only the tours still open after the
#: budget's steps. Narrower batches finish sooner down to about 1/32 of the lanes
#: (`docs/benchmarks.md`).
NARROW_FINISH_LANES = 4096
NARROW_FACTOR = 32


#: A lane may take up to this many times the budget's steps to end its open tour. A long tour
#: holds one slot of the narrow batch, where at full width it costs a step of every lane, so
#: the narrow batch can afford to finish the rare long tours that a cap of the budget's steps
#: would leave open (and the run's estimates unreliable): `docs/benchmarks.md`.
NARROW_FINISHING_STEPS = 10

#: The narrow batch's steps per call of `finish`: between calls the host shows the progress
#: of the finishing and takes Ctrl-C.
FINISHING_CALL = 128


def finishing_width(num_lanes: int) -> tuple[int, bool]:
    """Slots of the narrow finishing batch for `num_lanes` lanes (a device's), and whether the
    open tours are first run at full width (fewer than `NARROW_FINISH_LANES` lanes)."""
    return max(1, num_lanes // NARROW_FACTOR), num_lanes < NARROW_FINISH_LANES


def finishing_limit(num_steps: int, limit: int | None = None) -> int:
    """The most finishing steps a lane may take after a budget of `num_steps`: `limit`, or
    `NARROW_FINISHING_STEPS` times the budget's, within the run's int32 step counter."""
    wanted = num_steps * NARROW_FINISHING_STEPS if limit is None else limit
    return max(1, min(wanted, np.iinfo(np.int32).max - num_steps))


def _finish_lanes(
    sampler, observe, states, sums, histogram, tails, lane, taken, lane_keys, base, limit, iterations, rao_blackwell: bool, width: int
):
    """Run each lane's open tour towards its end, `width` lanes at a time (`_chunk.run_open_lanes`,
    see the module docstring), for at most `iterations` steps of the batch; a lane stops when
    its tour ends or it has taken `limit` finishing steps.

    `taken`: the finishing steps each lane has taken; its `j`-th draws with the key of step
    `base + j`. Returns the lanes' states and sums (those still in a slot written back, to
    go on in the next call), the histogram, the tails and `taken`.
    """
    batch = event_batch(sampler, width)

    def step(slot, shared, slot_lane, slot_steps, live, _):
        slot_states, slot_sums = slot
        keys = jax.vmap(lambda k, j: jax.random.fold_in(k, base + j))(lane_keys[slot_lane], slot_steps)
        new_states, info = sampler.step_lanes(keys, slot_states)
        values = jax.vmap(observe)(info.position)
        t = _tally(slot_states, slot_sums, *shared, slot_lane, new_states, info, values, rao_blackwell, batch, live)
        return (t.states, t.sums), (t.histogram, t.tails), counted_ends(slot_sums, info) & live

    (states, sums), (histogram, tails), taken, _ = run_open_lanes(
        step, (states, sums), (histogram, tails), active(sums), taken, limit, iterations, width
    )
    return states, sums, histogram, tails, taken


class Finished(NamedTuple):
    """What a call of `finish` gives back besides the carry and its report.

    Attributes:
        taken: the finishing steps each lane has taken (`Chunk.taken` of the next call).
        waiting: lanes whose tour is still open and that may still step (none: finishing is over).
    """

    taken: Array
    waiting: Array


@jit_chunk
def finish(chunk: Chunk, carry: RunCarry) -> tuple[RunCarry, ChunkReport, Finished]:
    """Run the open tours towards their end, `width` lanes at a time, for at most `length`
    iterations of the batch (see the module docstring); called until no lane is `waiting`.

    No tour starts: a lane whose tour ends stops there, as does one that has taken `limit`
    finishing steps. `carry.step` is the budget's steps plus the most finishing steps any
    lane has taken (`chunk.taken`), so the report's `steps` are those the call added to
    that most; its other sums cover the calls since the budget. After the last call (none
    `waiting`), `fold_finishing` adds the sums and histogram to the totals: once, so that a
    lane's sums are the same, bit for bit, however its finishing steps fell into calls.
    With a `sharding`, each device finishes its own lanes (`width` slots each), without
    talking to the others. The carry is donated.
    """
    sampler, observe, lane_keys, iterations, _, _, _, rao_blackwell, sharding, width, taken, limit = chunk
    if taken is None or limit is None:
        raise ValueError("finish needs the finishing steps each lane took so far (`taken`) and their `limit`")
    lane_keys = unrolled_keys(lane_keys)
    most = jnp.max(taken)
    base = carry.step - most  # the budget's steps
    args = (carry.states, carry.sums, carry.histogram, carry.tails, carry.lane, taken, lane_keys)
    if sharding is None:
        states, sums, histogram, tails, taken = _finish_lanes(sampler, observe, *args, base, limit, iterations, rao_blackwell, width)
    else:

        def local(sampler_and_observe, states, sums, histogram, tails, lane, taken, lane_keys, base, limit, iterations):
            sampler, observe = sampler_and_observe
            h, b = _one_device(histogram), _one_device(tails)
            out = _finish_lanes(sampler, observe, states, sums, h, b, lane, taken, lane_keys, base, limit, iterations, rao_blackwell, width)
            states, sums, h, b, taken = out
            return states, sums, _per_device(h), _per_device(b), taken

        arrays, static = eqx.partition((sampler, observe), eqx.is_array)
        lanes, replicated = sharding.lanes.spec, jax.sharding.PartitionSpec()
        mapped = jax.shard_map(
            lambda arrays, *rest: local(eqx.combine(arrays, static), *rest),
            mesh=sharding.mesh,
            in_specs=(replicated,) + (lanes,) * 7 + (replicated,) * 3,
            out_specs=(lanes,) * 5,
        )
        states, sums, histogram, tails, taken = mapped(arrays, *args, base, limit, iterations)
    added = jnp.max(taken) - most
    carry = carry._replace(states=states, sums=sums, histogram=histogram, tails=tails, step=carry.step + added)
    report = _report(carry, added)
    waiting = jnp.sum(active(carry.sums) & (taken < limit), dtype=jnp.int32)
    if sharding is not None:
        carry = jax.lax.with_sharding_constraint(carry, carry_shardings(carry, sharding))
    return carry, report, Finished(taken, waiting)


@jit(once=True, static_argnums=1, donate_argnums=0)
def fold_finishing(carry: RunCarry, sharding: LaneSharding | None) -> RunCarry:
    """The carry after the last call of `finish`, with the finishing's sums and histogram added
    to the totals (laid out over `sharding`'s devices as the run's carry is)."""
    carry = _folded(carry)
    return carry if sharding is None else jax.lax.with_sharding_constraint(carry, carry_shardings(carry, sharding))
