"""`render`: run a renderer in jitted chunks to a time or evaluation budget, with progress."""

from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._checkpoint import key_fingerprint, load_checkpoint, save_checkpoint
from .._compile import compiler_options
from .._driver import Budget, Meter, drive
from .._options import Checkpoint, as_checkpoint
from .._threefry import unrolled_keys
from .._validation import check_key
from ._pss import check_target
from ._renderer import (
    AbstractRenderer,
    RenderStatistics,
    check_count,
    check_lanes,
    host_params,
    host_tally,
    host_tally_dtype,
    zero_tally,
)

#: Default work per jitted chunk when `chunk` is not given (target evaluations).
_CHUNK_EVALUATIONS = 2**20
#: int32 event counts in a device tally must not overflow within one chunk.
_MAX_CHUNK_EVALUATIONS = 2**30


@dataclasses.dataclass(frozen=True)
class RenderResult:
    """What `render` returns.

    Attributes:
        image: the estimate, `(H, W, 3)` float32.
        evaluations: target evaluations spent (initialisation included).
        seconds: wall time of the run (initialisation, steps and `on_update` calls),
            compilation excluded.
        compile_seconds: time spent compiling the jitted initialisation and chunk (near
            zero when an earlier render of the same set-up compiled them).
        steps: renderer steps taken per lane within the budget.
        num_lanes: number of lanes.
        statistics: the renderer's diagnostics, a typed record (`RestoreStatistics`,
            `PSSMLTStatistics`, `ERPTStatistics`, `UniformStatistics`): acceptance rate, tours,
            `c`, `Z_hat`, ..., with the renderer's tail shape (Restore: `tour_k_hat` of its tour
            durations; PSSMLT: `z_k_hat` of the luminance behind `Z_hat`) and a warning above
            `TAIL_WARNING`. Read its fields as attributes; `as_dict()` gives them by name.
        interrupted: the run was stopped by Ctrl-C (KeyboardInterrupt); the image holds
            every chunk finished before it.
        finishing_steps: steps taken after the budget to complete open work (Restore's
            open tours with `finish_tours`), on all lanes at first and then on the few
            lanes still open; their evaluations and time are included in `evaluations`
            and `seconds`.
        finishing_seconds: the part of `seconds` spent finishing.
    """

    image: np.ndarray
    evaluations: int
    seconds: float
    compile_seconds: float
    steps: int
    num_lanes: int
    statistics: RenderStatistics
    interrupted: bool = False
    finishing_steps: int = 0
    finishing_seconds: float = 0.0

    @property
    def evaluations_per_second(self) -> float:
        return self.evaluations / self.seconds if self.seconds > 0 else math.nan


def _check_budget(seconds, evaluations):
    if seconds is None and evaluations is None:
        raise ValueError("give a budget: seconds=..., evaluations=..., or both (the run stops at the first spent)")
    if seconds is not None:
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float, np.integer, np.floating)):
            raise ValueError(f"seconds must be a number, got {seconds!r}")
        seconds = float(seconds)
        if not (math.isfinite(seconds) and seconds > 0):
            raise ValueError(f"seconds must be positive and finite, got {seconds!r}")
    if evaluations is not None:
        evaluations = check_count(evaluations, "evaluations")
    return seconds, evaluations


def render(
    target,
    renderer: AbstractRenderer,
    *,
    key,
    seconds: float | None = None,
    evaluations: int | None = None,
    num_lanes: int = 4096,
    chunk: int | None = None,
    progress: bool = True,
    on_update: Callable[[np.ndarray, RenderStatistics], None] | None = None,
    checkpoint: Checkpoint | str | os.PathLike | None = None,
) -> RenderResult:
    """Render `target` with `renderer` until the time or evaluation budget is spent.

    The renderer's `init` and a chunk of `chunk` steps (a `fori_loop`) are compiled once,
    ahead of the run (reported as `compile_seconds`, not counted in `seconds`), and kept
    for the next renders of the same set-up in this process (the same target object,
    an equal renderer, the same lanes: see `_programs`), which then start at once. Between
    chunks the device tally is added to float64 host totals and zeroed, the progress bar
    advances, and `on_update(image_so_far, statistics)` is called (progressive output).
    Ctrl-C (KeyboardInterrupt) stops the run and returns the image of the finished chunks,
    with `interrupted=True`.

    Budgets: `evaluations` counts every target evaluation, initialisation (bootstrap)
    included; the run takes the largest whole number of steps that fits, so it stops on
    the budget exactly when `evaluations - init_cost` is a multiple of the step cost
    (`num_lanes` for all but `ERPT`, whose step is a round). `seconds` is checked between
    chunks; near the end the chunk is shortened from the measured time per step, so the
    run overshoots by at most about one step. With both, the first spent stops the run.

    Finishing: a renderer with open work at the end of the budget (`renderer.finishes`:
    Restore with complete tours) then starts nothing new and steps until that work is
    done. A finishing step evaluates a batch of points shared among the open lanes, so a
    few long tours do not cost a full batch per step: the smallest of `finishing_rungs(lanes)`
    (a quarter of the lanes, at least 64, then quarters of that down to 256) that holds one
    point per open tour. Restore with a Metropolis small step runs its open tours by
    speculative steps there (`restore.speculative_steps`: several events of a tour per
    evaluation batch). The finishing programs are compiled ahead too. Finishing comes
    on top of the budget: its steps and time are in `finishing_steps`, `finishing_seconds`,
    `evaluations` and `seconds`.

    Arguments:
        target: a PSS target (`restore.render.PSSTarget`).
        renderer: e.g. `MetropolisRestore()`, `PSSMLT()`, `ERPT()`, `UniformSampler()`.
        key: a JAX PRNG key.
        seconds: wall-time budget (positive).
        evaluations: evaluation budget (positive integer).
        num_lanes: parallel lanes (chains, tours or samples per step).
        chunk: steps per jitted call; default about 2^20 evaluations' worth.
        progress: show a rich progress bar.
        on_update: called as `on_update(image, statistics)` after every chunk, with the image
            so far (`(H, W, 3)` float32) and the renderer's statistics record so far (its
            tail diagnostics, computed once at the end, are NaN).
        checkpoint: a `restore.Checkpoint` or a file name (saved every 60 s): where to save
            the run (renderer state, float64 host tallies, step and chunk counts, time
            spent), atomically, every `every_seconds` and/or at the first chunk end after
            every `every_steps` steps, at the end and on Ctrl-C. If it exists (and
            `resume`), the render continues
            from it. Chunk keys follow the chunk count, so with an `evaluations` budget
            and a fixed `chunk` an interrupted and resumed render is bit-identical to an
            uninterrupted one; under a time budget the chunk lengths follow the clock, so
            a resumed render is a valid continuation but not a bit-identical one. A
            checkpoint of another render (key, renderer, target, lanes, chunk, budget)
            is refused with a `CheckpointError`.

    Returns:
        A `RenderResult`.

    Raises:
        ValueError: on bad budgets, lanes or chunk, a budget smaller than the
            initialisation plus one step, or a target the renderer cannot start on.
    """
    if not isinstance(renderer, AbstractRenderer):
        raise TypeError(f"renderer must be a restore.render renderer, got {type(renderer).__name__}")
    check_target(target, needs_gradient=renderer.uses_gradient)
    seconds, evaluations = _check_budget(seconds, evaluations)
    lanes = check_lanes(num_lanes)
    checkpoint = as_checkpoint(checkpoint)
    if on_update is not None and not callable(on_update):
        raise TypeError("on_update must be callable as on_update(image, statistics)")
    init_cost, step_cost = renderer.init_cost(lanes), renderer.step_cost(lanes)
    if chunk is None:
        chunk = max(1, _CHUNK_EVALUATIONS // step_cost)
    chunk = check_count(chunk, "chunk")
    if chunk * step_cost > _MAX_CHUNK_EVALUATIONS:
        raise ValueError(
            f"chunk x step cost = {chunk * step_cost} evaluations would overflow the int32 tallies; use a smaller chunk"
        )
    max_steps = None
    if evaluations is not None:
        max_steps = (evaluations - init_cost) // step_cost
        if max_steps < 1:
            raise ValueError(
                f"an evaluation budget of {evaluations} does not cover initialisation ({init_cost}) plus one step "
                f"({step_cost} evaluations with {lanes} lanes)"
            )

    check_key(key)
    key_init, key_run = jax.random.split(key)
    state_shape = jax.eval_shape(lambda k: renderer.init(target, k, lanes), key_init)
    name = type(renderer).__name__
    total, unit = (float(evaluations), "evals") if evaluations is not None else (seconds, "s")
    fingerprint = {
        "key": key_fingerprint(key),
        "renderer": repr(renderer),
        "target": [type(target).__name__, target.dim, list(target.resolution)],
        "lanes": lanes,
        "chunk": chunk,
        "evaluations": evaluations,
        "seconds": seconds,
    }
    state, totals, steps, chunks, spent = None, None, 0, 0, 0.0
    finishing, finishing_evaluations, finished, finishing_seconds = 0, 0, False, 0.0
    if checkpoint is not None and checkpoint.resume and os.path.exists(checkpoint.path):  # checked before any compilation
        tally_like = jax.tree.map(lambda x: np.zeros(x.shape, host_tally_dtype(x)), state_shape.tally)
        (state, totals), header = load_checkpoint(checkpoint.path, (state_shape, tally_like), fingerprint)
        state = jax.tree.map(jnp.asarray, state)
        steps, chunks, spent = header["steps"], header["chunks"], header["seconds_spent"]
        finishing, finished = header.get("finishing_steps", 0), header.get("finished", False)
        finishing_evaluations = header.get("finishing_evaluations", 0)
        finishing_seconds = header.get("finishing_seconds", 0.0)
    done = (max_steps is not None and steps >= max_steps) or (seconds is not None and spent >= seconds)

    t0 = time.perf_counter()
    programs = _programs(renderer, target, lanes, key_init, state_shape)
    finishes = renderer.finishes and not finished
    new_init = state is None and programs.init is None
    new_chunk = not done and programs.chunk is None
    new_finisher = finishes and programs.finisher is None
    if new_init:
        programs.init = jax.jit(lambda k: renderer.init(target, k, lanes)).lower(key_init).compile(compiler_options(renderer=True))
    init_fn = programs.init
    # One throwaway call of each newly compiled function, so that a target's own first-call work
    # (e.g. Dr.Jit recording its kernels for these batch sizes) is paid here, outside the budget.
    warm_key = jax.random.fold_in(key_init, 1)
    if new_init or new_chunk or new_finisher:
        warm_state = init_fn(warm_key) if state is None else state
    if new_chunk:
        programs.chunk = _compile_chunk(renderer, target, key_run, state_shape, warm_key, warm_state)
    if new_finisher:
        programs.finisher = _finisher(renderer, target, lanes, state_shape, warm_key, warm_state)
    chunk_fn, finisher = programs.chunk, programs.finisher
    compile_seconds = time.perf_counter() - t0

    start = time.perf_counter()
    if state is None:
        state = jax.block_until_ready(init_fn(key_init))
    params = host_params(state.params)
    renderer.check(params)
    spent += time.perf_counter() - start  # the initialisation counts against a time budget

    def advance(n: int) -> int:
        nonlocal state, totals, chunks
        advanced = chunk_fn(jax.random.fold_in(key_run, chunks), state, jnp.asarray(n, jnp.int32))
        drained = host_tally(advanced.tally, totals)  # blocks until the chunk is done
        state, totals, chunks = zero_tally(advanced), drained, chunks + 1  # committed together
        return n

    def report(steps: int, elapsed: float) -> tuple[float, str]:
        spent_evaluations = init_cost + steps * step_cost
        position = spent_evaluations if evaluations is not None else min(elapsed, seconds)
        return position, f"{spent_evaluations / max(elapsed, 1e-9):.3g} evals/s"

    def update() -> None:
        if on_update is not None:
            image = np.asarray(renderer.image(target, state, totals), np.float32)
            on_update(image, renderer.statistics(params, totals))

    def save(steps_done: int, elapsed: float) -> None:
        header = dict(
            fingerprint, steps=steps_done, chunks=chunks, seconds_spent=elapsed, finishing_steps=finishing,
            finishing_evaluations=finishing_evaluations, finished=finished, finishing_seconds=finishing_seconds,
        )
        assert checkpoint is not None  # the driver saves only with a checkpoint
        save_checkpoint(checkpoint.path, (state, totals), header)

    outcome = drive(
        advance,
        budget=Budget(max_steps, seconds),
        chunk=chunk,
        done=steps,
        spent=spent,
        meter=Meter(progress, f"render {name}", total, unit, completed=report(steps, spent)[0] if steps else 0),
        report=report,
        on_chunk=update,
        save=save if checkpoint is not None else None,
        save_every_steps=None if checkpoint is None else checkpoint.every_steps,
        save_every_seconds=None if checkpoint is None else checkpoint.every_seconds,
    )
    if outcome.interrupted and totals is None:
        raise KeyboardInterrupt  # nothing finished to keep
    steps, interrupted, wall = outcome.steps, outcome.interrupted, outcome.elapsed
    if renderer.finishes and not interrupted and not finished:
        # `state` stays the one at the end of the budget: the checkpoint keeps it, with the
        # totals, as the start of finishing (or, once done, with `finished` set)
        (totals, chunks, taken, taken_evaluations, seconds_taken), interrupted = _finish(
            renderer, finisher, state, totals, key_run, chunks, chunk, progress, lanes, step_cost
        )
        finishing, finishing_evaluations = finishing + taken, finishing_evaluations + taken_evaluations
        wall += seconds_taken
        finishing_seconds += seconds_taken
        if not interrupted:
            finished = True
            update()
            if checkpoint is not None:
                save(steps, wall)
    image = np.asarray(renderer.image(target, state, totals), np.float32)
    statistics = renderer.statistics(params, totals, state)
    if not interrupted:
        renderer.warn_tail(statistics)
    return RenderResult(
        image=image,
        evaluations=init_cost + steps * step_cost + finishing_evaluations,
        seconds=wall,
        compile_seconds=compile_seconds,
        steps=steps,
        num_lanes=lanes,
        statistics=statistics,
        interrupted=interrupted,
        finishing_steps=finishing,
        finishing_seconds=finishing_seconds,
    )


@dataclasses.dataclass
class _Programs:
    """The compiled programs of one render set-up (renderer, target, lanes, key and state
    shapes), each compiled when first needed. `target` is held so that its `id` stays its own."""

    target: Any
    init: Any = None
    chunk: Any = None
    finisher: Any = None


#: Set-ups whose programs are kept, most recently used last. Each keeps its target alive
#: (the programs call back into it), so only a few are kept.
_PROGRAMS: OrderedDict[tuple, _Programs] = OrderedDict()
_PROGRAMS_KEPT = 4
_PROGRAMS_LOCK = threading.Lock()


def _programs(renderer, target, lanes, key, state_shape) -> _Programs:
    """The programs compiled for this set-up by an earlier `render` in this process, or an
    empty entry to compile them into.

    Renders of one scene are often repeated (realisations of `render-compare`, a resumed
    checkpoint, renders of growing budgets), and each compilation takes seconds. The
    set-up is matched by the target's identity (a target is taken not to change between
    renders), the renderer's value, the lanes, the key's type and the state's shapes; a
    renderer that cannot be hashed gets fresh programs every time.
    """
    leaves, treedef = jax.tree.flatten(state_shape)
    try:
        setup = (
            id(target), renderer, lanes, key.shape, str(key.dtype), treedef, tuple((x.shape, str(x.dtype)) for x in leaves),
            jax.default_backend(), tuple(sorted(compiler_options(renderer=True).items())),
        )
        hash(setup)
    except TypeError:  # e.g. a renderer with an array field
        return _Programs(target)
    with _PROGRAMS_LOCK:
        found = _PROGRAMS.get(setup)
        if found is None:  # an entry holds its target, so an id in the table is that target's
            found = _PROGRAMS[setup] = _Programs(target)
        _PROGRAMS.move_to_end(setup)
        while len(_PROGRAMS) > _PROGRAMS_KEPT:
            _PROGRAMS.popitem(last=False)
    return found


def _compile_chunk(renderer, target, key_run, state_shape, warm_key, warm_state):
    """The chunk program (`renderer.run` for a traced number of steps), called once here."""
    # the chunk's draws on unrolled Threefry keys: the same bits, a faster loop on the CPU
    # (the init keeps JAX's keys, where unrolling costs more compile time than it saves)
    run = lambda k, s, n: renderer.run(target, unrolled_keys(k), s, n)  # noqa: E731
    n_spec = jax.ShapeDtypeStruct((), jnp.int32)
    chunk_fn = jax.jit(run).lower(key_run, state_shape, n_spec).compile(compiler_options(renderer=True))
    jax.block_until_ready(chunk_fn(warm_key, warm_state, jnp.asarray(1, jnp.int32)))
    return chunk_fn


#: Finishing evaluates at most `max(_FINISHING_SLOTS, lanes // _FINISHING_SHARE)` points per
#: step (at most `lanes`), and fewer, down to `_FINISHING_SMALLEST`, as tours close.
_FINISHING_SLOTS = 64
_FINISHING_SHARE = 4
_FINISHING_SMALLEST = 256


def finishing_slots(lanes: int) -> int:
    """The most points evaluated per finishing step for a render of `lanes` lanes."""
    return min(lanes, max(_FINISHING_SLOTS, lanes // _FINISHING_SHARE))


def finishing_rungs(lanes: int) -> tuple[int, ...]:
    """The batch sizes of the finishing steps, largest first: `finishing_slots(lanes)`, then
    quarters of it while they hold `_FINISHING_SMALLEST` points.

    Why several: a step costs a fixed overhead plus a share per point, and most of the
    finishing time goes to the last few long tours. With thousands of tours open, the large
    batch gives each one a step; with a few hundred, a smaller batch still gives each one a
    step (or a tree of speculative steps) at a fraction of the cost. The ladder finished the
    pool scene's tours sooner than the largest batch alone (`docs/rendering.md`,
    `docs/benchmarks.md`).
    """
    rungs = [finishing_slots(lanes)]
    while rungs[-1] // _FINISHING_SHARE >= _FINISHING_SMALLEST:
        rungs.append(rungs[-1] // _FINISHING_SHARE)
    return tuple(rungs)


def _finisher(renderer, target, lanes, state_shape, warm_key, warm_state):
    """`((slots, finish), ...)`: the renderer's `finish` compiled for the run's state with
    each of `finishing_rungs(lanes)` evaluations per step, and called once here, outside
    the budget (Dr.Jit records its kernels for each batch size). Its draws run on unrolled
    Threefry keys, as the chunk's do: the same bits, in less finishing time."""
    key_spec = jax.eval_shape(lambda: warm_key)
    n_spec = jax.ShapeDtypeStruct((), jnp.int32)
    programs = []
    for slots in finishing_rungs(lanes):
        run = lambda k, s, n, slots=slots: renderer.finish(target, unrolled_keys(k), s, n, slots)  # noqa: E731
        finish = jax.jit(run).lower(key_spec, state_shape, n_spec).compile(compiler_options(renderer=True))
        jax.block_until_ready(finish(warm_key, warm_state, jnp.asarray(1, jnp.int32)))
        programs.append((slots, finish))
    return tuple(programs)


def _rung(finishers, still_open: int):
    """The finisher with the smallest batch that holds a point for each of `still_open` tours
    (the largest when none does)."""
    fitting = [f for f in finishers if f[0] >= still_open]
    return fitting[-1] if fitting else finishers[0]


def _finish(renderer, finisher, state, totals, key_run, chunks, chunk, progress, lanes, step_cost):
    """Complete the open work: no new work starts; each step evaluates the points of one
    finisher's batch (`_rung`: the smallest that holds the open tours), shared among the
    open lanes (Restore: speculative steps along each open tour), `chunk` steps a call,
    until nothing is open. The tallies are drained after every call.
    Returns `((totals, chunks, steps, evaluations, seconds), interrupted)`; Ctrl-C keeps every
    call that finished."""
    start, taken, evaluations = time.perf_counter(), 0, 0
    state = renderer.stop_starting(state)
    open_work = renderer.open_tours(state)
    meter = Meter(progress and open_work > 0, "finishing open tours (none start)", open_work, "tours")
    try:
        with meter.shown():
            while (still_open := renderer.open_tours(state)) > 0:
                meter.update(open_work - still_open, f"{still_open:,} open, {taken:,} steps")
                slots, finish = _rung(finisher, still_open)
                advanced, n = finish(jax.random.fold_in(key_run, chunks), state, jnp.asarray(chunk, jnp.int32))
                drained = host_tally(advanced.tally, totals)
                state, totals, chunks = zero_tally(advanced), drained, chunks + 1
                taken, evaluations = taken + int(n), evaluations + int(n) * slots * step_cost // lanes
            meter.update(open_work, f"{taken:,} steps")
    except KeyboardInterrupt:
        return (totals, chunks, taken, evaluations, time.perf_counter() - start), True
    return (totals, chunks, taken, evaluations, time.perf_counter() - start), False
