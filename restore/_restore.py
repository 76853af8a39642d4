"""The general Restore process: local dynamics killed at `gamma = L* p / p + c_tilde q / p`, then transferred.

One `step` is one event of one lane. Jump dynamics use competing exponentials (exact);
diffusions use Poisson thinning with a bound `Gamma` on the kill rate (exact when the
bound holds; every violation is counted). Tours may cycle through phases, each with its
own dynamics, transfer kernel and constant.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, NamedTuple, Self, cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ._point import Point, evaluate
from ._random import log_uniform
from ._rate import (
    PilotEstimate,
    jump_event,
    log_kill_rate,
    log_total_kill_rate,
    pilot_log_z,
)
from ._sampler import AbstractSampler, RunFacts, StepInfo
from ._sparse_draws import draw_slots, draw_where
from ._validation import check_integer, check_logdensity, check_point, check_positive
from .dynamics import AbstractDiffusion, AbstractDynamics, AbstractJumpDynamics
from .transfer import AbstractTransfer


class RestoreState(NamedTuple):
    """State of one Restore lane.

    Attributes:
        position: current state `x`.
        logdensity: `log p(x)` (`-inf` for zero density).
        logdensity_grad: gradient of `log p` at `x`, or `None` if no part needs it.
        log_kill_rate: `log(c_tilde q(x) / p(x))`, the transfer part of the kill rate (the
            whole kill rate when the local dynamics leave the target invariant).
        adjoint_ratio: `L* p / p` at `x` (zero for invariant dynamics).
        phase: which `(dynamics, transfer, constant)` the current tour uses.
        tour: index of the current tour in this lane.
        pending: a diffusion tour was just killed at `position`; the next step draws the
            start of the next tour (always false for jump dynamics).
        aux: the log density's extra output at `position` (`has_aux`), else `None`.
        geometry: what the local kernel keeps at `position` (`Point.geometry`), else `None`.
    """

    position: Float[Array, " d"]
    logdensity: Float[Array, ""]
    logdensity_grad: Float[Array, " d"] | None
    log_kill_rate: Float[Array, ""]
    adjoint_ratio: Float[Array, ""]
    phase: Int[Array, ""]
    tour: Int[Array, ""]
    pending: Bool[Array, ""]
    aux: Any = None
    geometry: Any = None


class _JumpKeys(NamedTuple):
    """The keys of one jump step, split from the step's key in this order."""

    event: PRNGKeyArray
    hold: PRNGKeyArray
    propose: PRNGKeyArray
    accept: PRNGKeyArray
    regenerate: PRNGKeyArray


class _JumpMove(NamedTuple):
    """A jump step before the kill rate's terms at its new point: the event, and the point the
    lane moved to (its old one after a rejected candidate; a new tour's start after a kill)."""

    holding_time: Array
    expected_holding_time: Array
    killed: Array
    negative_rate: Array
    point: Point
    invalid: Array
    phase: Array
    accepted: Array
    acceptance_probability: Array


#: `step_lanes` computes the kill terms of the lanes that moved or started a tour in batches of
#: this share of the lanes (as many batches as they need; any size gives the same results).
TERM_BATCH_SHARE = 0.25


#: Floating-point operations (XLA's cost estimate, a transcendental function counted as
#: `TRANSCENDENTAL_FLOPS`) of the reference densities from which `step_lanes` computes kill
#: terms only where lanes moved: a 10-d Gaussian (about 400) is cheaper to evaluate at every
#: lane; a mixture of three 10-d Student-t components (about 3,100) or a 32-d product of
#: 8-component mixtures (about 5,000) is not.
COSTLY_TERMS = 1000.0
TRANSCENDENTAL_FLOPS = 10.0


def _term_slots(num_lanes: int) -> int | None:
    """Lanes per batch of kill terms (a multiple of 8), or `None` for too few lanes to gather."""
    slots = -(-max(8, math.ceil(TERM_BATCH_SHARE * num_lanes)) // 8) * 8
    return slots if 2 * slots <= num_lanes else None


def _uncovered(log_regeneration: Array, logdensity: Array) -> Array:
    """The regeneration density vanishes where the target's is positive (the lane is never killed there)."""
    return (log_regeneration == -jnp.inf) & jnp.isfinite(logdensity)


def _jump_keys(key: PRNGKeyArray) -> _JumpKeys:
    return _JumpKeys(*jax.random.split(key, 5))


def _as_phases(value, name: str) -> tuple:
    return tuple(value) if isinstance(value, (list, tuple)) else (value,)


def cycle(tour: Array, num_phases: int) -> Array:
    """The default phase rule: tour `i` uses phase `i mod K`."""
    return jnp.mod(tour, num_phases)


class KillTerms(NamedTuple):
    """The terms of a Restore lane's kill rate at an evaluated point (`AbstractRestore.kill_terms`).

    Attributes:
        point: the point (its log density `-inf` where the adjoint ratio was NaN).
        invalid: the point's density or adjoint ratio could not be evaluated.
        log_regeneration: `log q(x)`, the phase's reference density.
        log_kill_rate: `log(c_tilde q(x) / p(x))`, the regeneration part of the kill rate.
        adjoint_ratio: `L* p / p` at the point (zero for pi-invariant dynamics).
    """

    point: Point
    invalid: Array
    log_regeneration: Array
    log_kill_rate: Array
    adjoint_ratio: Array


class AbstractRestore(AbstractSampler):
    """Shared machinery of `Restore` and `JumpRestore`: init, step, calibration."""

    logdensity: Callable[[Array], Array]
    dynamics: tuple[AbstractDynamics, ...]
    transfers: tuple[AbstractTransfer, ...]
    log_rate: Float[Array, "*K"] | None
    tour_length: tuple[float, ...] | None = eqx.field(static=True)
    bound: tuple[float | None, ...] = eqx.field(static=True)
    phase_rule: Callable[[Array], Array] | None = eqx.field(static=True)
    pilot_size: int = eqx.field(static=True)
    has_aux: bool = eqx.field(static=True)

    has_tours: ClassVar[bool] = True

    # ------------------------------------------------------------------ construction
    def _setup(self, logdensity, dynamics, transfers, log_rate, tour_length, bound, phase_rule, pilot_size, has_aux=False):
        dynamics, transfers = _as_phases(dynamics, "dynamics"), _as_phases(transfers, "transfer")
        K = max(len(dynamics), len(transfers))
        for name, parts in (("dynamics", dynamics), ("transfer", transfers)):
            if len(parts) not in (1, K):
                raise ValueError(f"{name} has {len(parts)} phases but another part has {K}")
        dynamics = dynamics * K if len(dynamics) == 1 else dynamics
        transfers = transfers * K if len(transfers) == 1 else transfers
        for d in dynamics:
            if not isinstance(d, AbstractDynamics):
                raise TypeError(f"dynamics must be restore.dynamics objects, got {type(d).__name__}")
        for t in transfers:
            if not isinstance(t, AbstractTransfer):
                raise TypeError(f"transfer must be restore.transfer kernels, got {type(t).__name__}")
        kinds = {isinstance(d, AbstractDiffusion) for d in dynamics}
        if len(kinds) > 1:
            raise ValueError("all phases must use the same kind of dynamics (all jump processes or all diffusions)")
        dims = {t.dim for t in transfers}
        if len(dims) > 1:
            raise ValueError(f"the transfer kernels live in different dimensions {sorted(dims)}")
        dim = dims.pop()
        check_logdensity(logdensity, dim, with_grad=any(d.uses_gradient for d in dynamics), has_aux=has_aux)
        if len({id(d) for d in dynamics if d.keeps_geometry}) > 1:
            raise ValueError(
                "two phases' dynamics keep their own geometry at a point (as H2MC keeps its Gaussian); a state "
                "holds one: give such dynamics to one phase, or the same object to every phase"
            )
        for d, t in zip(dynamics, transfers):
            d.check_dim(dim)
            if not d.is_invariant and not t.is_independent:
                raise ValueError(
                    f"{type(d).__name__} does not leave the target invariant, and {type(t).__name__} depends on the "
                    "exit point: no kill rate of closed form makes that pair exact. Use pi-invariant local "
                    "dynamics with exit-dependent transfers, or an independent transfer (restore.transfer.Independent)"
                )
        if (log_rate is None) == (tour_length is None):
            raise ValueError("give exactly one of log_rate (log c_tilde) or tour_length (mean tour duration)")
        if log_rate is not None:
            if isinstance(log_rate, (bool, str, bytes)):
                raise TypeError(f"log_rate must be a real number (log c_tilde), got {log_rate!r}")
            try:
                rates = jnp.atleast_1d(jnp.asarray(log_rate))
            except (TypeError, ValueError) as err:
                raise TypeError(f"log_rate must be a real number (log c_tilde), got {log_rate!r}") from err
            if jnp.issubdtype(rates.dtype, jnp.integer):
                rates = rates.astype(jnp.result_type(float))
            if not jnp.issubdtype(rates.dtype, jnp.floating):
                raise TypeError(f"log_rate must be a real number (log c_tilde), got dtype {rates.dtype}")
            # A Python float gives a weakly typed array; a calibrated rate is strongly typed. Make
            # both strong, so that samplers built either way share one compiled program.
            rates = rates.astype(rates.dtype)
            if rates.ndim != 1 or rates.shape[0] not in (1, K):
                raise ValueError(f"log_rate must be a scalar or one value per phase ({K}), got shape {rates.shape}")
            if not isinstance(rates, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(rates))):
                raise ValueError(f"log_rate must be finite, got {log_rate!r}")
            log_rate = rates[0] if K == 1 else jnp.broadcast_to(rates, (K,))
        if tour_length is not None:
            lengths = _as_phases(tour_length, "tour_length")
            if len(lengths) not in (1, K):
                raise ValueError(f"tour_length must be a scalar or one value per phase ({K})")
            tour_length = tuple(check_positive(v, "tour_length") for v in (lengths * K if len(lengths) == 1 else lengths))
        bounds = _as_phases(bound, "bound")
        if len(bounds) not in (1, K):
            raise ValueError(f"bound must be a scalar or one value per phase ({K})")
        bounds = bounds * K if len(bounds) == 1 else bounds
        if kinds == {True}:
            if any(b is None for b in bounds):
                raise ValueError(
                    "diffusion dynamics need a bound Gamma >= gamma on the kill rate for Poisson thinning: pass "
                    "bound=..., e.g. from restore.rate_bound over the region the tours explore"
                )
            bounds = tuple(check_positive(b, "bound") for b in bounds)
        if phase_rule is not None and not callable(phase_rule):
            raise TypeError("phase_rule must be a function from the tour index to a phase index")
        pilot_size = check_integer(pilot_size, "pilot_size", minimum=2)
        self.logdensity = logdensity
        self.dynamics = dynamics
        self.transfers = transfers
        self.log_rate = log_rate
        self.tour_length = tour_length
        self.bound = bounds
        self.phase_rule = phase_rule
        self.pilot_size = int(pilot_size)
        self.has_aux = bool(has_aux)

    # ------------------------------------------------------------------ facts
    @property
    def dim(self) -> int:
        return self.transfers[0].dim

    @property
    def dtype(self) -> jnp.dtype:
        """The floating dtype the process runs in: that of the first phase's reference draws.

        Positions (given starts, proposals, transfers) and the log density's values are cast
        to it, so a float32 regeneration distribution gives a float32 run even when
        `jax_enable_x64` is on, and a log density that computes in another precision cannot
        change the dtypes of a state.
        """
        reference = self.transfers[0].reference
        return jax.eval_shape(reference.sample, jax.random.key(0)).dtype

    @property
    def log_value(self) -> Callable[[Array], Array]:
        """The log density's value alone (what the local dynamics and the pilot use)."""
        if not self.has_aux:
            return self.logdensity
        return lambda x: self.logdensity(x)[0]

    @property
    def num_phases(self) -> int:
        return len(self.dynamics)

    @property
    def is_diffusion(self) -> bool:
        return isinstance(self.dynamics[0], AbstractDiffusion)

    @property
    def is_regenerative(self) -> bool:
        """Tours start independently of the past (every transfer is independent): lanes are
        regenerative and tour-based standard errors are valid."""
        return all(t.is_independent for t in self.transfers)

    @property
    def effective_log_rate(self) -> float | None:
        """`log c_eff` with `1 / c_eff` the mean of `1 / c_tilde_k` over phases, so that the mean
        tour duration is `Z / c_eff` under the default cycle (`log c_tilde` with one phase).
        With another phase rule the tours' own phases count (`expected_tour_times`)."""
        if self.log_rate is None:
            return None
        rates = np.atleast_1d(np.asarray(self.log_rate, np.float64))  # on the host: no eager device ops to compile
        if not jax.config.read("jax_enable_x64"):
            rates = rates.astype(np.float32)
        top = np.max(-rates)
        return float(-(top + np.log(np.sum(np.exp(-rates - top))) - math.log(rates.shape[0])))

    def phase_of_tour(self, tour: Int[Array, "*n"]) -> Int[Array, "*n"]:
        """The phase that tour number `tour` of a lane uses (tour 0, started by `init`, uses phase 0)."""
        tour = jnp.asarray(tour, jnp.int32)
        if self.num_phases == 1:
            return jnp.zeros_like(tour)
        return jnp.where(tour == 0, 0, jax.vmap(self._next_phase)(tour.reshape(-1)).reshape(tour.shape))

    def expected_tour_times(self, last_tour, num_tours) -> np.ndarray | None:
        """Per lane, `sum_k 1 / c_tilde_{phase(k)}` over its `num_tours` complete tours, those just
        before tour `last_tour` (the lane's open tour): their expected total duration over `Z`.

        Each complete tour `k` of phase `j` lasts `Z / c_tilde_j` on average whatever the phase
        rule, so the total duration of the tours divided by this sum estimates `Z`. `None`
        with one phase (then it is `num_tours / c_tilde`).
        """
        if self.num_phases == 1 or self.log_rate is None:
            return None
        last, count = np.asarray(last_tour, np.int64), np.asarray(num_tours, np.int64)
        if np.max(last, initial=0) == 0:
            return np.zeros(last.shape)
        phases = np.asarray(self.phase_of_tour(jnp.arange(int(np.max(last)))))
        inverse = np.exp(-np.asarray(self.log_rate, np.float64))[phases]
        cumulative = np.concatenate([[0.0], np.cumsum(inverse)])
        return cumulative[last] - cumulative[last - count]

    @property
    def uses_gradient(self) -> bool:
        return any(d.uses_gradient for d in self.dynamics)

    def evaluate_point(self, position: Array) -> tuple[Point, Array]:
        """The point at `position` evaluated with all the dynamics need there (the gradient, or
        the geometry a kernel keeps: `Point.geometry`), and whether the evaluation was invalid."""
        for d in self.dynamics:
            if d.keeps_geometry:  # evaluates the gradient too, as the other phases may need
                return d.evaluate_point(self.logdensity, position, self.has_aux)
        return evaluate(self.logdensity, position, self.uses_gradient, self.has_aux)

    def calibrate(self, key: PRNGKeyArray) -> tuple[AbstractRestore, PilotEstimate | None]:
        """The sampler with `log_rate` set from `tour_length` by a pilot estimate of `Z`, and the pilot.

        The pilot is importance sampling from the first phase's reference distribution;
        phase `k` then gets `log c_tilde_k = log Z_hat - log T_k`. A sampler that already
        has a `log_rate` is returned unchanged, with no pilot. `restore.sample` calls this
        for you and keeps the pilot in its result (`SampleResult.pilot`).
        """
        if self.log_rate is not None:
            return self, None
        pilot = pilot_log_z(key, self.log_value, self.transfers[0].reference, self.pilot_size)
        return self.calibrated_to(pilot.log_z), pilot

    def calibrated_to(self, log_z: float | Array) -> Self:
        """The sampler with `log_rate` set from `tour_length` and an estimate of `log Z` you have.

        What `calibrate` does with its pilot's estimate, for an estimate from elsewhere (an
        earlier run of the same target): phase `k` gets `log c_tilde_k = log_z - log T_k`.
        The sampler keeps its `tour_length`, so a run of it reuses the compiled programs of
        a run of the same sampler calibrated by a pilot.
        """
        if self.tour_length is None:
            raise ValueError("calibrated_to needs a sampler given a tour_length; this one was given a log_rate")
        if self.log_rate is not None:
            raise ValueError("this sampler is calibrated already (it has a log_rate)")
        rates = jnp.asarray([log_z - math.log(t) for t in self.tour_length])
        rates = rates[0] if self.num_phases == 1 else rates
        return eqx.tree_at(lambda s: s.log_rate, self, rates, is_leaf=lambda x: x is None)

    def run_facts(self) -> RunFacts:
        return RunFacts(self.effective_log_rate, self.tour_length)

    def calibrated_log_rates(self) -> Array:
        """`log c_tilde` (one per phase); a `ValueError` that says what to do if the sampler has
        a `tour_length` but was not calibrated yet."""
        if self.log_rate is None:
            raise ValueError(
                "this sampler has a tour_length but no log_rate yet: call sampler.calibrate(key) "
                "first, which returns the calibrated sampler and its pilot (restore.sample does it for you)"
            )
        return self.log_rate

    # ------------------------------------------------------------------ phase helpers
    def _by_phase(self, phase: Array | int, fn: Callable[[int], object]):
        if self.num_phases == 1:
            return fn(0)
        return jax.lax.switch(phase, [lambda k=k: fn(k) for k in range(self.num_phases)])

    def _next_phase(self, tour: Array) -> Array:
        if self.num_phases == 1:
            return jnp.zeros((), jnp.int32)
        rule = self.phase_rule or (lambda i: cycle(i, self.num_phases))
        return jnp.clip(jnp.asarray(rule(tour), jnp.int32), 0, self.num_phases - 1)

    def kill_terms(self, phase: Array | int, point: Point, invalid: Array, log_rates: Array) -> KillTerms:
        """The kill rate's terms at an evaluated `point` of phase `phase`, for `log_rates`
        (`calibrated_log_rates()`): a `KillTerms`. A point where the adjoint ratio is NaN is
        marked invalid and given zero density."""

        def one(k: int):
            log_q = self.transfers[k].reference.log_prob(point.position)
            if self.dynamics[k].is_invariant:
                adjoint = jnp.zeros((), point.logdensity.dtype)
            else:
                adjoint = self.dynamics[k].adjoint_ratio(self.log_value, point).astype(point.logdensity.dtype)
            return log_q, jnp.atleast_1d(log_rates)[k], adjoint

        log_q, log_rate, adjoint = self._by_phase(phase, one)
        dtype = point.logdensity.dtype
        log_q, log_rate, adjoint = log_q.astype(dtype), log_rate.astype(dtype), adjoint.astype(dtype)
        if all(d.is_invariant for d in self.dynamics):
            return KillTerms(point, invalid, log_q, log_kill_rate(log_rate, log_q, point.logdensity), adjoint)
        finite = jnp.isfinite(point.logdensity)
        bad = finite & jnp.isnan(adjoint)
        point = point._replace(logdensity=jnp.where(bad, -jnp.inf, point.logdensity))
        adjoint = jnp.where(finite & ~bad, adjoint, 0.0)
        return KillTerms(point, invalid | bad, log_q, log_kill_rate(log_rate, log_q, point.logdensity), adjoint)

    # ------------------------------------------------------------------ init / step
    def init(self, key: PRNGKeyArray, position: Array | None = None, phase: int | Array = 0) -> RestoreState:
        """Start a lane at `position`, or at a draw of the first phase's reference (a tour start)."""
        log_rates = self.calibrated_log_rates()
        phase = jnp.asarray(phase, jnp.int32)
        if position is None:
            position = self._by_phase(phase, lambda k: self.transfers[k].reference.sample(key).astype(self.dtype))
        else:
            position = check_point(position, self.dim, "position", finite=True)
        position = position.astype(self.dtype)
        point, invalid = self.evaluate_point(position)
        point, _, _, log_kill, adjoint = self.kill_terms(phase, point, invalid, log_rates)
        zero = jnp.zeros((), jnp.int32)
        return RestoreState(
            point.position, point.logdensity, point.grad, log_kill, adjoint, phase, zero, jnp.zeros((), bool), point.aux,
            point.geometry,
        )  # fmt: skip

    def step(self, key: PRNGKeyArray, state: RestoreState) -> tuple[RestoreState, StepInfo]:
        """One event of the lane: a local move or a kill (jump dynamics), or one thinning candidate (diffusions)."""
        if self.is_diffusion:
            return self._in_phase(state, lambda k, log_rates: self._diffusion_step(k, key, state, log_rates))
        return self._decided_step(_jump_keys(key), state)

    def step_lanes(self, keys: PRNGKeyArray, states: RestoreState) -> tuple[RestoreState, StepInfo]:
        """`vmap(step)`, with the work only some lanes need done for those lanes alone.

        Equal to `vmap(step)` lane by lane. The next tours' starts are drawn only for the
        lanes killed in this step (each start from its lane's own key), and the kill rate's
        terms (`kill_terms`: the regeneration density `u`, which can cost many times the
        target's density), when they are costly (`COSTLY_TERMS`), only where a lane moved
        or started a tour; a lane whose candidate was rejected keeps its state's.
        """
        if self.is_diffusion:
            return super().step_lanes(keys, states)
        slots = draw_slots(keys.shape[0], self._kill_fraction())
        term_slots = _term_slots(keys.shape[0])
        if term_slots is not None and not self._costly_terms():  # (asked only where the lanes are enough to gather)
            term_slots = None
        if slots is None and term_slots is None:
            return super().step_lanes(keys, states)
        slots = slots or keys.shape[0]  # (one batch of every lane: the same program as with sparse draws)

        def decide(key, state):
            split = _jump_keys(key)
            killed = self._in_phase(state, lambda k, _: self._killed(k, split.event, state))
            return split, killed, self._next_phase(state.tour + 1)

        split, killed, phases = jax.vmap(decide)(keys, states)
        starts = draw_where(self._regenerate, killed, slots, phases, split.regenerate, states.position)

        if term_slots is None:
            return jax.vmap(self._decided_step)(split, states, killed, starts)

        def move(keys, state, killed, start):
            return self._in_phase(state, lambda k, log_rates: self._jump_move(k, keys, state, log_rates, killed, start))

        moves = jax.vmap(move)(split, states, killed, starts)
        log_rates = self.calibrated_log_rates()
        changed = moves.killed | jnp.any(moves.point.position != states.position, axis=-1)

        def terms_at(phase, point, invalid):  # the point's log density alone may change
            terms = self.kill_terms(phase, point, invalid, log_rates)
            return terms.point.logdensity, terms.invalid, terms.log_regeneration, terms.log_kill_rate, terms.adjoint_ratio

        computed = draw_where(terms_at, changed, term_slots, moves.phase, moves.point, moves.invalid)
        kept = (moves.point.logdensity, moves.invalid, jnp.zeros_like(states.log_kill_rate), states.log_kill_rate, states.adjoint_ratio)
        logdensity, invalid, log_q, log_kill, adjoint = (jnp.where(changed, new, old) for new, old in zip(computed, kept, strict=True))
        terms = KillTerms(moves.point._replace(logdensity=logdensity), invalid, log_q, log_kill, adjoint)
        # a state's `u` vanishes exactly where its kill rate is `-inf` at a positive density
        uncovered = jnp.where(
            changed,
            _uncovered(terms.log_regeneration, terms.point.logdensity),
            (states.log_kill_rate == -jnp.inf) & jnp.isfinite(states.logdensity),
        )
        return jax.vmap(self._jump_end)(states, moves, terms, uncovered)

    def _costly_terms(self) -> bool:
        """Whether the kill rate's terms cost enough (XLA's estimate for the phases' reference
        densities, `COSTLY_TERMS`) that `step_lanes` computes them only where lanes moved;
        the gathering costs more than it saves for a cheap density, and it compiles longer."""
        point = jax.ShapeDtypeStruct((self.dim,), self.dtype)
        total = 0.0
        for transfer in self.transfers:
            arrays, static = eqx.partition(transfer.reference, eqx.is_array)
            shapes = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), arrays)
            try:
                cost = jax.jit(lambda a, x, static=static: eqx.combine(a, static).log_prob(x)).lower(shapes, point).cost_analysis()
            except Exception:  # no estimate from this backend: assume it is costly
                return True
            if not cost:
                return True
            total += float(cost.get("flops") or 0.0) + TRANSCENDENTAL_FLOPS * float(cost.get("transcendentals") or 0.0)
        return total >= COSTLY_TERMS

    def _in_phase(self, state: RestoreState, fn: Callable[[int, Array], Any]):
        """`fn(k, log_rates)` for the lane's phase `k`."""
        log_rates = self.calibrated_log_rates()
        if self.num_phases == 1:
            return fn(0, log_rates)
        return jax.lax.switch(state.phase, [lambda k=k: fn(k, log_rates) for k in range(self.num_phases)])

    def _decided_step(self, keys: _JumpKeys, state: RestoreState, killed: Array | None = None, start: Array | None = None):
        """A jump step from its keys; `killed` and the next tour's `start`, if given, were drawn
        from these keys beforehand (as the step would draw them)."""
        return self._in_phase(state, lambda k, log_rates: self._jump_step(k, keys, state, log_rates, killed, start))

    def tour_end_fraction(self) -> float | None:
        """The share of a stationary run's jump events that are kills (`None` for diffusions,
        whose kills and starts fall on separate candidate events)."""
        return None if self.is_diffusion else self._kill_fraction()

    def _kill_fraction(self) -> float | None:
        """The share of a stationary run's events that are kills, `1 / (1 + r T)` for tours of
        mean duration `T` and local rate `r` (`None` when the tours' length is not known)."""
        if self.tour_length is None:
            return None
        rates = [cast(AbstractJumpDynamics, d).rate for d in self.dynamics]  # jump dynamics: callers ask only when not `is_diffusion`
        return max(1.0 / (1.0 + float(r) * float(t)) for r, t in zip(rates, self.tour_length, strict=True))

    def _event_rates(self, k: int, state: RestoreState):
        """`log gamma` (the total kill rate), the negative-rate flag and `log r` of phase `k`."""
        dynamics = cast(AbstractJumpDynamics, self.dynamics[k])
        log_r = jnp.log(jnp.asarray(dynamics.rate, state.logdensity.dtype))
        if dynamics.is_invariant:
            return state.log_kill_rate, jnp.zeros((), bool), log_r
        return (*log_total_kill_rate(state.log_kill_rate, state.adjoint_ratio), log_r)

    def _killed(self, k: int, key: PRNGKeyArray, state: RestoreState) -> Array:
        """Whether the event is a kill (against a local move), decided as the step decides it."""
        log_gamma, _, log_r = self._event_rates(k, state)
        dtype = state.logdensity.dtype
        return jump_event(log_uniform(key, dtype), jnp.ones((), dtype), log_gamma, log_r).killed

    def _regenerate(self, phase: Array, key: PRNGKeyArray, position: Array) -> Array:
        """The start of the next tour, of phase `phase`, after a kill at `position`."""
        return self._by_phase(phase, lambda j: self.transfers[j].sample(key, position)).astype(position.dtype)

    def _jump_step(self, k: int, keys: _JumpKeys, state: RestoreState, log_rates: Array, killed=None, fresh=None):
        return self._jump_end_here(state, self._jump_move(k, keys, state, log_rates, killed, fresh))

    def _jump_move(self, k: int, keys: _JumpKeys, state: RestoreState, log_rates: Array, killed=None, fresh=None) -> _JumpMove:
        """A jump step of phase `k` up to the kill rate's terms at the point it leads to."""
        dynamics = cast(AbstractJumpDynamics, self.dynamics[k])
        dtype = state.logdensity.dtype
        log_gamma, negative, log_r = self._event_rates(k, state)
        event = jump_event(log_uniform(keys.event, dtype), jax.random.exponential(keys.hold, dtype=dtype), log_gamma, log_r)
        if killed is None:
            killed = event.killed

        point = Point(state.position, state.logdensity, state.logdensity_grad, state.aux, state.geometry)
        candidate, aux = dynamics.propose(keys.propose, point, self.log_value)
        candidate = candidate.astype(state.position.dtype)
        next_phase = self._next_phase(state.tour + 1)
        if fresh is None:
            fresh = self._regenerate(next_phase, keys.regenerate, state.position)
        evaluated, invalid = self.evaluate_point(jnp.where(killed, fresh, candidate))
        moved, local_info = dynamics.accept(keys.accept, point, evaluated, aux)
        new_point = jax.tree.map(lambda a, b: jnp.where(killed, a, b), evaluated, moved)
        new_phase = jnp.where(killed, next_phase, state.phase) if self.num_phases > 1 else state.phase
        return _JumpMove(
            event.holding_time, event.expected_holding_time, killed, negative, new_point, invalid, new_phase,
            local_info.accepted & ~killed, jnp.where(killed, 0.0, local_info.acceptance_probability).astype(dtype),
        )  # fmt: skip

    def _jump_end_here(self, state: RestoreState, move: _JumpMove):
        """`_jump_end` with the kill rate's terms computed at the move's point."""
        terms = self.kill_terms(move.phase, move.point, move.invalid, self.calibrated_log_rates())
        return self._jump_end(state, move, terms, _uncovered(terms.log_regeneration, terms.point.logdensity))

    def _jump_end(self, state: RestoreState, move: _JumpMove, terms: KillTerms, uncovered: Array) -> tuple[RestoreState, StepInfo]:
        """The new state and the step's report from a move and the kill rate's terms at its point."""
        new_point, killed, dtype = terms.point, move.killed, state.logdensity.dtype
        new_state = RestoreState(
            new_point.position,
            new_point.logdensity,
            new_point.grad,
            terms.log_kill_rate,
            terms.adjoint_ratio,
            move.phase,
            state.tour + killed.astype(jnp.int32),
            state.pending,
            new_point.aux,
            new_point.geometry,
        )
        log_weight = jnp.where(killed, new_point.logdensity - terms.log_regeneration, -jnp.inf)
        info = StepInfo(
            position=state.position,
            holding_time=move.holding_time,
            expected_holding_time=move.expected_holding_time,
            regenerated=killed,
            accepted=move.accepted,
            acceptance_probability=move.acceptance_probability,
            invalid=terms.invalid,
            uncovered=uncovered,
            log_importance_weight=jnp.where(jnp.isnan(log_weight), -jnp.inf, log_weight),
            start_drawn=killed,
            negative_rate=move.negative_rate,
            bound_ratio=jnp.zeros((), dtype),
            aux=state.aux,
        )
        return new_state, info

    def _diffusion_step(self, k: int, key: PRNGKeyArray, state: RestoreState, log_rates: Array):
        dynamics = cast(AbstractDiffusion, self.dynamics[k])
        k_gap, k_move, k_kill = jax.random.split(key, 3)
        dtype = state.logdensity.dtype
        bound = jnp.asarray(self.bound[k], dtype)
        gap = jax.random.exponential(k_gap, dtype=dtype) / bound
        pending = state.pending
        start = self.transfers[k].sample(k_move, state.position)
        moved = dynamics.advance(k_move, state.position, gap, self.log_value).astype(dtype)
        evaluated, invalid = self.evaluate_point(jnp.where(pending, start.astype(dtype), moved))
        evaluated, invalid, log_q, log_kill, adjoint = self.kill_terms(state.phase, evaluated, invalid, log_rates)

        log_gamma, negative = log_total_kill_rate(log_kill, adjoint)
        log_ratio = log_gamma - jnp.log(bound)
        killed = ~pending & (log_uniform(k_kill, dtype) < log_ratio)
        next_phase = self._next_phase(state.tour + 1)
        new_state = RestoreState(
            evaluated.position,
            evaluated.logdensity,
            evaluated.grad,
            log_kill,
            adjoint,
            jnp.where(killed, next_phase, state.phase) if self.num_phases > 1 else state.phase,
            state.tour + killed.astype(jnp.int32),
            killed,
            evaluated.aux,
            evaluated.geometry,
        )
        log_weight = jnp.where(pending, evaluated.logdensity - log_q, -jnp.inf)
        zero = jnp.zeros((), dtype)
        info = StepInfo(
            position=evaluated.position,
            holding_time=jnp.where(pending, zero, gap),
            expected_holding_time=jnp.where(pending, zero, 1.0 / bound),
            regenerated=killed,
            accepted=~pending,
            acceptance_probability=jnp.where(pending, zero, 1.0).astype(dtype),
            invalid=invalid,
            uncovered=(log_q == -jnp.inf) & jnp.isfinite(evaluated.logdensity) & ~pending,
            log_importance_weight=jnp.where(jnp.isnan(log_weight), -jnp.inf, log_weight),
            start_drawn=pending,
            negative_rate=negative & ~pending,
            bound_ratio=jnp.where(pending, zero, jnp.exp(log_ratio)),
            aux=evaluated.aux,
        )
        return new_state, info

    def kill_rate(self, position: Float[Array, " d"], phase: int | Array = 0) -> Float[Array, ""]:
        """The kill rate `gamma(x) = L* p / p + c_tilde q / p` at one point (`+inf` where `p = 0`).

        Negative values are returned as they are (there `c_tilde` is too small). Pass it
        to `restore.rate_bound` to find a thinning bound over a region, e.g.
        `restore.rate_bound(process.kill_rate, lower, upper, key=key).bound`.
        """
        log_rates = self.calibrated_log_rates()
        position = check_point(position, self.dim, "position", finite=True).astype(self.dtype)
        point, invalid = self.evaluate_point(position)
        phase = jnp.asarray(phase, jnp.int32)
        _, _, _, log_kill, adjoint = self.kill_terms(phase, point, invalid, log_rates)
        return adjoint + jnp.exp(log_kill)

    def advance_position(self, key: PRNGKeyArray, state: RestoreState, duration: Array) -> Array:
        """The position `duration` time units after `state`, given that no event happens before.

        Jump dynamics hold still between events; a diffusion moves on (exactly for
        Brownian motion and Ornstein-Uhlenbeck). Used to read the state at fixed times.
        """
        if not self.is_diffusion:
            return state.position
        diffusions = cast(tuple[AbstractDiffusion, ...], self.dynamics)  # `is_diffusion`, and `_setup` made all phases one kind
        return self._by_phase(state.phase, lambda k: diffusions[k].advance(key, state.position, duration, self.log_value))


class Restore(AbstractRestore):
    """A general Restore process, one lane at a time.

    Tour `i` runs local `dynamics` from its start until it is killed at rate
    `gamma(x) = L* p(x) / p(x) + c_tilde q(x) / p(x)`, where `q` is the reference
    density of the `transfer` kernel; the next tour starts at a draw of
    `transfer.sample(key, x_exit)`. With pi-invariant dynamics (`L* p = 0`) any transfer
    that leaves `q` invariant is exact; non-invariant dynamics (Brownian motion, an
    unadjusted random walk) need an independent transfer. The mean tour duration is
    `Z / c_tilde` in every case, so tours estimate `Z`.

    Jump dynamics are simulated exactly with competing exponentials; diffusions by Poisson
    thinning: candidate events at rate `bound`, each a kill with probability
    `gamma / bound`. A candidate where `gamma > bound` (the bound was wrong there) and a
    state where `gamma < 0` (`c_tilde` too small) are counted and reported by
    `restore.sample`, never hidden.

    Schedules: pass sequences for `dynamics`, `transfer`, `log_rate`/`tour_length` and
    `bound` to give each phase its own; tour `i` uses phase `phase_rule(i)` (default
    `i mod K`, a deterministic cycle). The kill rate of a tour uses the reference of the
    transfer that started it.

    Arguments:
        logdensity: unnormalised log density of one point `(d,)`.
        dynamics: a `restore.dynamics` object (or one per phase).
        transfer: a `restore.transfer` kernel (or one per phase); a plain
            `restore.regeneration` distribution is wrapped in `Independent`.
        log_rate: `log c_tilde` (scalar or one per phase).
        tour_length: mean tour duration `T = Z / c_tilde` (scalar or one per phase),
            turned into `log_rate` by `calibrate` with a pilot estimate of `Z`.
        bound: the thinning bound `Gamma` (diffusions only; scalar or one per phase).
        phase_rule: function from the tour index (int array) to the phase index.
        pilot_size: number of reference draws of the pilot estimate of `Z`.
        has_aux: `logdensity` returns `(log density, aux)`; `aux` is reported in `StepInfo.aux`.
    """

    def __init__(
        self,
        logdensity: Callable[[Array], Array],
        dynamics: AbstractDynamics | Sequence[AbstractDynamics],
        transfer,
        *,
        log_rate=None,
        tour_length=None,
        bound=None,
        phase_rule: Callable[[Array], Array] | None = None,
        pilot_size: int = 4096,
        has_aux: bool = False,
    ):
        from .regeneration import AbstractRegeneration
        from .transfer import Independent

        wrap = lambda t: Independent(t) if isinstance(t, AbstractRegeneration) else t
        transfer = tuple(wrap(t) for t in transfer) if isinstance(transfer, (list, tuple)) else wrap(transfer)
        self._setup(logdensity, dynamics, transfer, log_rate, tour_length, bound, phase_rule, pilot_size, has_aux)
