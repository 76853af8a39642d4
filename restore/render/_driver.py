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
from .._driver import Budget, Meter, drive, drive_finishing
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

    The renderer's programs are compiled ahead of the run (`compile_seconds`, not counted
    in `seconds`) and kept for the next renders of the same set-up in this process. An
    `evaluations` budget counts every target evaluation, initialisation included; `seconds`
    is checked between chunks (the run overshoots by about one step). Open work at the end
    of the budget (Restore's open tours) is then finished, on top of the budget, in batches
    shared among the open lanes. Ctrl-C returns the image of the finished chunks
    (`interrupted=True`).

    Arguments:
        target: a PSS target (`restore.render.PSSTarget`).
        renderer: e.g. `MetropolisRestore()`, `PSSMLT()`, `ERPT()`, `UniformSampler()`.
        key: a JAX PRNG key.
        seconds: wall-time budget (positive); with `evaluations` too, the first spent stops the run.
        evaluations: evaluation budget (positive integer).
        num_lanes: parallel lanes (chains, tours or samples per step).
        chunk: steps per jitted call; default about 2^20 evaluations' worth.
        progress: show a rich progress bar.
        on_update: called as `on_update(image, statistics)` after every chunk, with the image
            so far (`(H, W, 3)` float32) and the renderer's statistics record so far (its
            tail diagnostics, computed once at the end, are NaN).
        checkpoint: a `restore.Checkpoint` or a file name (saved every 60 s). With an
            `evaluations` budget and a fixed `chunk`, a resumed render is bit-identical to
            an uninterrupted one; under a time budget, a valid continuation. A checkpoint of
            another render is refused with a `CheckpointError`.

    Returns:
        A `RenderResult`.

    Raises:
        ValueError: on bad budgets, lanes or chunk, a budget smaller than the
            initialisation plus one step, or a target the renderer cannot start on.
    """
    run = _RenderRun(
        target, renderer, key=key, seconds=seconds, evaluations=evaluations, num_lanes=num_lanes, chunk=chunk,
        progress=progress, on_update=on_update, checkpoint=checkpoint,
    )  # fmt: skip
    run.advance()
    run.finish()
    return run.result()


class _RenderRun:
    """One render: set up (budget, keys, checkpoint, compiled programs, start state), then
    `advance` through the budget, `finish` the open work, and read the `result`.

    The renderer's `init` and a chunk of `chunk` steps (`renderer.run`) are compiled once,
    ahead of the run (`compile_seconds`, not counted in `seconds`), and kept for the next
    renders of the same set-up in this process (the same target object, an equal renderer,
    the same lanes: see `_programs`), which then start at once. Between chunks the device
    tally is added to float64 host totals and zeroed, the progress bar advances, and
    `on_update(image_so_far, statistics)` is called.

    Budgets: `evaluations` counts every target evaluation, initialisation (bootstrap)
    included; the run takes the largest whole number of steps that fits, so it stops on the
    budget exactly when `evaluations - init_cost` is a multiple of the step cost (`num_lanes`
    for all but `ERPT`, whose step is a round). `seconds` is checked between chunks; near the
    end the chunk is shortened from the measured time per step, so the run overshoots by at
    most about one step. With both, the first spent stops the run.

    Finishing: a renderer with open work at the end of the budget (`renderer.finishes`:
    Restore with `finish_tours`) then starts nothing new and steps until that work is done.
    A finishing step evaluates a batch of points shared among the open lanes, so a few long
    tours do not cost a full batch per step: the smallest of `finishing_rungs(lanes)` (a
    quarter of the lanes, at least 64, then quarters of that down to the renderer's
    `smallest_finishing_batch()`) that holds one point per open tour, chosen again every
    `_FINISHING_CALL` steps. Restore renders run their open tours in the core's narrow
    batch (`restore._chunk.run_open_lanes`, as `restore.sample` does) by speculative steps
    (`restore.speculative_steps`). The finishing programs are
    compiled ahead too. Finishing comes on top of the budget: its steps and time are in
    `finishing_steps`, `finishing_seconds`, `evaluations` and `seconds`.
    """

    def __init__(self, target, renderer, *, key, seconds, evaluations, num_lanes, chunk, progress, on_update, checkpoint):
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
        self.fingerprint = {
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
            (state, totals), header = load_checkpoint(checkpoint.path, (state_shape, tally_like), self.fingerprint)
            state = jax.tree.map(jnp.asarray, state)
            steps, chunks, spent = header["steps"], header["chunks"], header["seconds_spent"]
            finishing, finished = header.get("finishing_steps", 0), header.get("finished", False)
            finishing_evaluations = header.get("finishing_evaluations", 0)
            finishing_seconds = header.get("finishing_seconds", 0.0)
        done = (max_steps is not None and steps >= max_steps) or (seconds is not None and spent >= seconds)

        t0 = time.perf_counter()
        programs = _programs(renderer, target, lanes, key_init, state_shape)
        new_init = state is None and programs.init is None
        new_chunk = not done and programs.chunk is None
        new_finisher = renderer.finishes and not finished and programs.finisher is None
        if new_init:
            programs.init = jax.jit(lambda k: renderer.init(target, k, lanes)).lower(key_init).compile(compiler_options(renderer=True))
        # One throwaway call of each newly compiled function, so that a target's own first-call work
        # (e.g. Dr.Jit recording its kernels for these batch sizes) is paid here, outside the budget.
        warm_key = jax.random.fold_in(key_init, 1)
        if new_init or new_chunk or new_finisher:
            warm_state = programs.init(warm_key) if state is None else state
        if new_chunk:
            programs.chunk = _compile_chunk(renderer, target, key_run, state_shape, warm_key, warm_state)
        if new_finisher:
            programs.finisher = _finisher(renderer, target, lanes, state_shape, warm_key, warm_state)
        self.compile_seconds = time.perf_counter() - t0

        start = time.perf_counter()
        if state is None:
            state = jax.block_until_ready(programs.init(key_init))
        self.params = host_params(state.params)
        renderer.check(self.params)
        spent += time.perf_counter() - start  # the initialisation counts against a time budget

        self.target, self.renderer, self.lanes, self.chunk, self.max_steps = target, renderer, lanes, chunk, max_steps
        self.seconds, self.evaluations, self.init_cost, self.step_cost = seconds, evaluations, init_cost, step_cost
        self.progress, self.on_update, self.checkpoint, self.key_run = progress, on_update, checkpoint, key_run
        self.chunk_fn, self.finisher = programs.chunk, programs.finisher
        self.state, self.totals, self.steps, self.chunks, self.spent = state, totals, steps, chunks, spent
        self.finishing, self.finishing_evaluations, self.finished = finishing, finishing_evaluations, finished
        self.finishing_seconds, self.interrupted, self.wall = finishing_seconds, False, spent

    def _advance(self, n: int) -> int:
        advanced = self.chunk_fn(jax.random.fold_in(self.key_run, self.chunks), self.state, jnp.asarray(n, jnp.int32))
        drained = host_tally(advanced.tally, self.totals)  # blocks until the chunk is done
        self.state, self.totals, self.chunks = zero_tally(advanced), drained, self.chunks + 1  # committed together
        return n

    def _report(self, steps: int, elapsed: float) -> tuple[float, str]:
        spent_evaluations = self.init_cost + steps * self.step_cost
        position = spent_evaluations if self.evaluations is not None else min(elapsed, self.seconds)
        return position, f"{spent_evaluations / max(elapsed, 1e-9):.3g} evals/s"

    def _update(self) -> None:
        if self.on_update is not None:
            image = np.asarray(self.renderer.image(self.target, self.state, self.totals), np.float32)
            self.on_update(image, self.renderer.statistics(self.params, self.totals))

    def _save(self, steps_done: int, elapsed: float) -> None:
        header = dict(
            self.fingerprint, steps=steps_done, chunks=self.chunks, seconds_spent=elapsed, finishing_steps=self.finishing,
            finishing_evaluations=self.finishing_evaluations, finished=self.finished, finishing_seconds=self.finishing_seconds,
        )  # fmt: skip
        assert self.checkpoint is not None  # the driver saves only with a checkpoint
        save_checkpoint(self.checkpoint.path, (self.state, self.totals), header)

    def advance(self) -> None:
        """Run chunks until the budget is spent or Ctrl-C (`_driver.drive`)."""
        checkpoint = self.checkpoint
        total, unit = (float(self.evaluations), "evals") if self.evaluations is not None else (self.seconds, "s")
        outcome = drive(
            self._advance,
            budget=Budget(self.max_steps, self.seconds),
            chunk=self.chunk,
            done=self.steps,
            spent=self.spent,
            meter=Meter(self.progress, f"render {type(self.renderer).__name__}", total, unit,
                        completed=self._report(self.steps, self.spent)[0] if self.steps else 0),
            report=self._report,
            on_chunk=self._update,
            save=self._save if checkpoint is not None else None,
            save_every_steps=None if checkpoint is None else checkpoint.every_steps,
            save_every_seconds=None if checkpoint is None else checkpoint.every_seconds,
        )  # fmt: skip
        if outcome.interrupted and self.totals is None:
            raise KeyboardInterrupt  # nothing finished to keep
        self.steps, self.interrupted, self.wall = outcome.steps, outcome.interrupted, outcome.elapsed

    def finish(self) -> None:
        """Complete the open work after the budget (a renderer that `finishes`), and save the finished run."""
        if not self.renderer.finishes or self.interrupted or self.finished:
            return
        # `state` stays the one at the end of the budget: the checkpoint keeps it, with the
        # totals, as the start of finishing (or, once done, with `finished` set)
        (self.totals, self.chunks, taken, taken_evaluations, seconds_taken), self.interrupted = _finish(
            self.renderer, self.finisher, self.state, self.totals, self.key_run, self.chunks,
            min(self.chunk, _FINISHING_CALL), self.progress,
            self.lanes, self.step_cost,
        )  # fmt: skip
        self.finishing, self.finishing_evaluations = self.finishing + taken, self.finishing_evaluations + taken_evaluations
        self.wall += seconds_taken
        self.finishing_seconds += seconds_taken
        if not self.interrupted:
            self.finished = True
            self._update()
            if self.checkpoint is not None:
                self._save(self.steps, self.wall)

    def result(self) -> RenderResult:
        """The image, the budget spent and the renderer's statistics (with its tail warning)."""
        image = np.asarray(self.renderer.image(self.target, self.state, self.totals), np.float32)
        statistics = self.renderer.statistics(self.params, self.totals, self.state)
        if not self.interrupted:
            self.renderer.warn_tail(statistics)
        return RenderResult(
            image=image,
            evaluations=self.init_cost + self.steps * self.step_cost + self.finishing_evaluations,
            seconds=self.wall,
            compile_seconds=self.compile_seconds,
            steps=self.steps,
            num_lanes=self.lanes,
            statistics=statistics,
            interrupted=self.interrupted,
            finishing_steps=self.finishing,
            finishing_seconds=self.finishing_seconds,
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
#: step (at most `lanes`), and fewer, down to the renderer's `smallest_finishing_batch()`, as
#: tours close.
_FINISHING_SLOTS = 64
_FINISHING_SHARE = 4
#: Finishing steps per call at most: the batch is chosen again between calls, as tours close.
_FINISHING_CALL = 64


def finishing_slots(lanes: int) -> int:
    """The most points evaluated per finishing step for a render of `lanes` lanes."""
    return min(lanes, max(_FINISHING_SLOTS, lanes // _FINISHING_SHARE))


def finishing_rungs(lanes: int, smallest: int = 256) -> tuple[int, ...]:
    """The batch sizes of the finishing steps, largest first: `finishing_slots(lanes)`, then
    quarters of it while they hold `smallest` points (the renderer's
    `smallest_finishing_batch()`).

    Why several: a step costs a fixed overhead plus a share per point, and most of the
    finishing time goes to the last few long tours. With thousands of tours open, the large
    batch gives each one a step; with a few hundred, a smaller batch still gives each one a
    step (or a tree of speculative steps) at a fraction of the cost. The ladder finished the
    pool scene's tours sooner than the largest batch alone (`docs/rendering.md`,
    `docs/benchmarks.md`).
    """
    rungs = [finishing_slots(lanes)]
    while rungs[-1] // _FINISHING_SHARE >= smallest:
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
    for slots in finishing_rungs(lanes, renderer.smallest_finishing_batch()):
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
    """Complete the open work (`_driver.drive_finishing`): no new work starts; each step
    evaluates the points of one finisher's batch (`_rung`: the smallest that holds the open
    tours), shared among the open lanes (Restore: speculative steps along each open tour),
    `chunk` steps a call, until nothing is open. The tallies are drained after every call.
    Returns `((totals, chunks, steps, evaluations, seconds), interrupted)`; Ctrl-C keeps every
    call that finished."""
    start = time.perf_counter()
    state = renderer.stop_starting(state)
    opened = still_open = renderer.open_tours(state)
    taken = evaluations = 0

    def call() -> tuple[int, int, bool]:  # one call of a finisher, drained and committed
        nonlocal state, totals, chunks, taken, evaluations, still_open
        slots, finish = _rung(finisher, still_open)
        advanced, n = finish(jax.random.fold_in(key_run, chunks), state, jnp.asarray(chunk, jnp.int32))
        drained, n = host_tally(advanced.tally, totals), int(n)
        state, totals, chunks = zero_tally(advanced), drained, chunks + 1
        taken, evaluations = taken + n, evaluations + n * slots * step_cost // lanes
        still_open = renderer.open_tours(state)
        return n, still_open, still_open == 0

    interrupted = False
    if opened > 0:
        try:
            drive_finishing(call, opened, progress)
        except KeyboardInterrupt:
            interrupted = True
    return (totals, chunks, taken, evaluations, time.perf_counter() - start), interrupted
