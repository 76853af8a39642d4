"""Energy redistribution path tracing (Cline et al. 2005) in primary sample space, in rounds."""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PRNGKeyArray

from .._point import Point
from ..local import AbstractTorusMutation, KelemenMutation
from ._film import empty_film, splat
from ._pss import check_target, contributions, empty_points, evaluate_points, luminance, pixels, small_step
from ._renderer import AbstractRenderer, RenderStatistics, check_count, check_lanes, ratio


class ERPTParams(NamedTuple):
    lanes: Float[Array, ""]


class ERPTTally(NamedTuple):
    """Sums: film of deposits, seeds drawn, chains run, mutations, acceptances, deposit energies."""

    film: Float[Array, "P 3"]
    seeds: Int[Array, ""]
    chains: Int[Array, ""]
    mutations: Int[Array, ""]
    accepted: Int[Array, ""]
    energy: Float[Array, ""]


@dataclasses.dataclass(frozen=True)
class ERPTStatistics(RenderStatistics):
    """`ERPT`'s diagnostics.

    Attributes:
        seeds: uniform seed paths drawn (`N_seeds`, the image's divisor).
        chains: Metropolis chains run.
        acceptance_rate: the fraction of the chains' mutations accepted.
        mean_deposition_energy: the mean deposition energy `e_d` of the rounds, in luminance.
        chain_length: `M`, mutations per chain.
        chains_per_seed: chains run per seed drawn.
    """

    seeds: int
    chains: int
    acceptance_rate: float
    mean_deposition_energy: float
    chain_length: int
    chains_per_seed: float


class ERPTState(NamedTuple):
    """The chains at the end of the last round (zeros before the first), constants and sums."""

    point: Point
    params: ERPTParams
    tally: ERPTTally


class ERPT(AbstractRenderer):
    """Energy redistribution path tracing: short equal-deposition Metropolis chains from seeds.

    One `step` is a round. It draws `B` uniform seed paths; a seed of luminance `F` gets
    `n` chains with `E[n] = F / e_d` (`n` is `floor(F / e_d)` or one more); each chain
    makes `M = chain_length` small-step Metropolis mutations on luminance and after each
    one deposits `e_d / M * rgb / lum` at its current pixel (equal deposition).

    Batching: the deposition energy is `e_d = (sum of the round's F) / C` with `C = lanes`
    chains per round, and the counts are drawn by systematic (stratified) rounding over the
    round's seeds, with one shared uniform offset: each `n` is still `floor(F / e_d + xi)`
    in law (`E[n] = F / e_d` exactly), and they add up to exactly `C`. The chains therefore
    fill the `C` lanes with no padding and no overflow, and a round costs exactly
    `B + M C` evaluations. `B = round(lanes / chains_per_seed)`: `e_d` is the round's mean
    seed luminance divided by `chains_per_seed`, the usual choice of `e_d` from the mean
    path energy and a target number of chains per seed.

    Estimator: `I_j = W H F_j / N_seeds`. Unbiased: given a round's seeds, seed `i`
    deposits `E[n_i] e_d / M sum_m E[h(X_m) | x_i] = F_i (1/M) sum_m (K^m h)(x_i)` with
    `h = rgb / lum 1{pixel = j}` and `K` the Metropolis kernel; over uniform seeds
    `E[F (K^m h)(x)] = ∫ p K^m h = Z E_p[h]` because `K` leaves `p` invariant. So each seed
    deposits `Z E_p[h] = I_j / (W H)` in expectation, whatever `M` and `e_d`. Only whole
    rounds are run, so there is no truncation bias.

    Arguments:
        mutation: the small step (default `KelemenMutation()`).
        chain_length: `M`, mutations per chain (default 32: one fresh seed per 33
            evaluations with one chain per seed, like Metropolis Restore's default tours).
        chains_per_seed: average chains per seed `C / B`, positive (default 1).
    """

    mutation: AbstractTorusMutation
    chain_length: int
    chains_per_seed: float

    def __init__(
        self, mutation: AbstractTorusMutation | None = None, *, chain_length: int = 32, chains_per_seed: float = 1.0
    ):
        mutation = KelemenMutation() if mutation is None else mutation
        if not isinstance(mutation, AbstractTorusMutation):
            raise TypeError(
                f"mutation must be a torus mutation (e.g. KelemenMutation()), got {type(mutation).__name__}"
            )
        chains_per_seed = float(chains_per_seed)
        if not (math.isfinite(chains_per_seed) and chains_per_seed > 0):
            raise ValueError(f"chains_per_seed must be positive and finite, got {chains_per_seed!r}")
        self.mutation = mutation
        self.chain_length = check_count(chain_length, "chain_length")
        self.chains_per_seed = chains_per_seed

    def seeds_per_round(self, lanes: int) -> int:
        return max(1, round(lanes / self.chains_per_seed))

    def init_cost(self, lanes: int) -> int:
        return 0

    def step_cost(self, lanes: int) -> int:
        return self.seeds_per_round(lanes) + self.chain_length * lanes

    def init(self, target, key: PRNGKeyArray, lanes: int) -> ERPTState:
        check_target(target)
        lanes = check_lanes(lanes)
        point = empty_points(target, lanes)
        i0, f0 = jnp.zeros((), jnp.int32), jnp.zeros((), jnp.float32)
        tally = ERPTTally(empty_film(target.num_pixels), i0, i0, i0, i0, f0)
        return ERPTState(point, ERPTParams(jnp.asarray(lanes, jnp.float32)), tally)

    def step(self, target, key: PRNGKeyArray, state: ERPTState) -> ERPTState:
        k_seed, k_chain = jax.random.split(key)
        lanes, d = state.point.position.shape
        b, m = self.seeds_per_round(lanes), self.chain_length
        draw = jax.random.uniform(k_seed, (b * d + 1,), jnp.float32)  # one draw: seeds and the rounding offset
        seeds = evaluate_points(target, draw[:-1].reshape(b, d))
        seed_lum = luminance(seeds)
        total = jnp.sum(seed_lum)
        energy = total / lanes
        # systematic rounding: chain c starts at the seed whose slice of [0, C) holds c + xi
        cumulative = jnp.cumsum(seed_lum) * (lanes / jnp.where(total > 0, total, 1.0))
        slots = jnp.arange(lanes, dtype=jnp.float32) + draw[-1]
        owner = jnp.clip(jnp.searchsorted(cumulative, slots, side="right"), 0, b - 1)
        chains = jax.tree.map(lambda x: x[owner], seeds)
        weight = jnp.full((lanes,), energy / m, jnp.float32)
        kernel = small_step(self.mutation, target)

        def mutate(i, carry):
            chains, film, accepted = carry
            k_move, k_accept = jax.random.split(jax.random.fold_in(k_chain, i))
            moves = jax.vmap(lambda k, p: kernel.propose(k, p, None)[0])(jax.random.split(k_move, lanes), chains)
            candidate = evaluate_points(target, moves)
            accept_one = lambda k, p, q: kernel.accept(k, p, q, None)  # noqa: E731
            chains, info = jax.vmap(accept_one)(jax.random.split(k_accept, lanes), chains, candidate)
            film = splat(film, pixels(target, chains.position, chains.aux), weight, contributions(chains.aux))
            return chains, film, accepted + jnp.sum(info.accepted, dtype=jnp.int32)

        tally = state.tally
        chains, film, accepted = jax.lax.fori_loop(0, m, mutate, (chains, tally.film, tally.accepted))
        tally = ERPTTally(
            film=film,
            seeds=tally.seeds + jnp.int32(b),
            chains=tally.chains + jnp.int32(lanes),
            mutations=tally.mutations + jnp.int32(lanes * m),
            accepted=accepted,
            energy=tally.energy + energy,
        )
        return ERPTState(chains, state.params, tally)

    def scale(self, target, params: ERPTParams, tally: ERPTTally):
        """`W H / N_seeds`."""
        return ratio(target.num_pixels, tally.seeds)

    def statistics(self, params: ERPTParams, tally: ERPTTally, state=None) -> ERPTStatistics:
        return ERPTStatistics(
            seeds=int(tally.seeds),
            chains=int(tally.chains),
            acceptance_rate=float(ratio(tally.accepted, tally.mutations)),
            mean_deposition_energy=float(ratio(tally.energy * params.lanes, tally.chains)),
            chain_length=self.chain_length,
            chains_per_seed=float(ratio(tally.chains, tally.seeds)),
        )
