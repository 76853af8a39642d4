"""Speculative jump-Restore steps: run a few open tours many events ahead in one batched evaluation.

When only a few lanes still have work (the last open tours of a render, say), a batch
call of the log density costs about as much for one point as for a batch of them. If
the local kernel's candidate depends on the position and the key alone
(`proposes_from_position`: random-walk and torus Metropolis), a lane can draw candidates
for events it has not reached yet and evaluate them all at once (pre-fetching, Brockwell
2006). Each lane gets a tree of `d` slots: the root is the event at its current state;
a node's children are the next event if the node's candidate is accepted (held state:
that candidate) and if it is rejected (held state: the node's own); every node proposes
from its held state. After the batched evaluation the lane's events are replayed from
the root: at each node the tour is killed with probability `gamma / (r + gamma)`, else the
candidate is accepted or rejected by the kernel's own test, and the lane moves to the
child on that branch, until it is killed or the branch leaves the tree. The other
nodes are discarded. Every event uses fresh randomness and a candidate is only used from
the state it was proposed from, so the lane's path has exactly the law of plain steps,
whatever the tree.

The tree only decides how far a call gets: it holds the `d` most probable nodes for a
predicted acceptance probability `a` (a node at the end of `i` accepted and `j`
rejected moves is reached with probability about `a^i (1 - a)^j`), which is the accept
path for `a` near 1 and the reject path (independent candidates from the current state)
for `a` near 0. A call then advances a lane by about `log2(d) / H(a)` events (`H` the
binary entropy) instead of one.

A kernel whose candidate needs more than the position (MALA, H2MC: the gradient at the
current state) cannot propose from a candidate before it is evaluated, but a rejected
move leaves the lane where it was: its tree is the reject path alone (`reject_chains`),
`d` independent candidates from the current state, and a call advances the lane by
about `1 / a` events (at most `d`), one where its moves are mostly accepted.

Speculative steps never start a tour: a killed lane stops (`active` false) at its kill
point. They finish tours; they do not replace `step` while tours still start.
"""

from __future__ import annotations

import functools
import heapq
from typing import NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ._jump_restore import JumpRestore
from ._point import Point
from ._random import log_uniform
from ._rate import jump_event
from ._restore import RestoreState
from ._sampler import StepInfo
from .dynamics import AbstractJumpDynamics

#: Predicted acceptance probabilities are rounded to one of this many trees.
ACCEPTANCE_BUCKETS = 16


class SpeculativeSteps(NamedTuple):
    """What `speculative_steps` did, slot by slot (`S` slots, `N` lanes).

    Attributes:
        states: the lanes' states after the call (`N` lanes; a lane killed in this call
            holds its kill point).
        active: lanes whose tour is still open.
        info: one `StepInfo` per slot: the event replayed there (`position`, `aux` and
            `expected_holding_time` of the state held before it, `regenerated` for a kill).
        log_kill_rate: per slot, `log gamma` at the state held before the event.
        valid: the slot's event happened (slots off the lane's replayed path, and slots no
            lane uses, are not events).
        last: the slot holds its lane's final event of this call.
        lane: the lane each slot belongs to.
        level: events of the lane before the slot's event in this call (its tree depth).
        parent: the slot of the event before it in the tree (the slot itself at a root).
        accepted_branch: the slot's event follows the acceptance of its parent's candidate
            (else its rejection).
    """

    states: RestoreState
    active: Bool[Array, " N"]
    info: StepInfo
    log_kill_rate: Float[Array, " S"]
    valid: Bool[Array, " S"]
    last: Bool[Array, " S"]
    lane: Int[Array, " S"]
    level: Int[Array, " S"]
    parent: Int[Array, " S"]
    accepted_branch: Bool[Array, " S"]


@functools.lru_cache(maxsize=16)
def speculation_trees(size: int, buckets: int = ACCEPTANCE_BUCKETS) -> tuple[np.ndarray, ...]:
    """Per predicted acceptance `a = (b + 1/2) / buckets`, the `size` most probable nodes of the
    event tree, in the order a greedy search adds them (so its first `d` nodes form a tree).

    Returns `(parent, accepted, depth, child_accepted, child_rejected)`, each `(buckets, size)`
    int32: node `k`'s parent (`-1` for the root), whether it hangs on the parent's accepted
    branch, its depth, and its children's node numbers (`size` where absent).
    """
    parent = np.full((buckets, size), -1, np.int32)
    accepted = np.zeros((buckets, size), np.int32)
    depth = np.zeros((buckets, size), np.int32)
    child = np.full((2, buckets, size), size, np.int32)
    for b in range(buckets):
        a = (b + 0.5) / buckets
        frontier = [(-1.0, 0, -1, 0, 0)]  # (-probability, tie-break, parent, branch, depth)
        count = 0
        for k in range(size):
            neg_p, _, par, branch, level = heapq.heappop(frontier)
            parent[b, k], accepted[b, k], depth[b, k] = par, branch, level
            if par >= 0:
                child[branch, b, par] = k
            for branch_of_child, p in ((1, a), (0, 1.0 - a)):
                count += 1
                heapq.heappush(frontier, (neg_p * p, count, k, branch_of_child, level + 1))
    return parent, accepted, depth, child[1], child[0]


def check_speculative(sampler: JumpRestore) -> None:
    """Raise a `ValueError` unless `speculative_steps` can run `sampler` (a one-phase
    `JumpRestore`; any local kernel)."""
    if not isinstance(sampler, JumpRestore):
        raise ValueError(f"speculative steps need a JumpRestore sampler, got {type(sampler).__name__}")
    if sampler.num_phases != 1:
        raise ValueError("speculative steps need a sampler with one phase")


def reject_chains(size: int) -> tuple[np.ndarray, ...]:
    """The trees of a kernel whose candidate needs more than the position (a gradient): the
    reject path alone, node `k` the event after `k` rejections, every candidate proposed from
    the current state. The same layout as `speculation_trees`, one bucket."""
    k = np.arange(size, dtype=np.int32)[None]
    child_rejected = np.where(k + 1 < size, k + 1, size).astype(np.int32)
    return k - 1, np.zeros_like(k), k, np.full_like(k, size), child_rejected


def _rows(mask: Array, x: Array) -> Array:
    return mask.reshape(mask.shape + (1,) * (x.ndim - mask.ndim))


def speculative_steps(
    sampler: JumpRestore,
    key: PRNGKeyArray,
    states: RestoreState,
    active: Bool[Array, " N"],
    slots: int,
    acceptance: Float[Array, " N"] | float = 0.5,
) -> SpeculativeSteps:
    """Advance the open tours (`active` lanes of the batched `states`) with one batched
    evaluation of `slots` candidates (module docstring).

    The slots are shared out evenly: with `n` open lanes each gets a tree of
    `d = max(1, slots // n)` slots (lanes beyond `slots` wait for a later call), shaped
    for the lane's predicted `acceptance` probability (a guess: any value is exact), or
    the reject path alone for a kernel that needs the gradient (module docstring).
    """
    check_speculative(sampler)
    log_rates = sampler.calibrated_log_rates()
    dynamics = cast(AbstractJumpDynamics, sampler.dynamics[0])
    from_position = sampler.local.proposes_from_position and not sampler.uses_gradient
    n_lanes = active.shape[0]
    dtype = states.logdensity.dtype
    log_r = jnp.log(jnp.asarray(dynamics.rate, dtype))

    # slots: lane `rank` (the rank-th open lane) owns slots rank*d ... rank*d + d - 1
    n_open = jnp.sum(active, dtype=jnp.int32)
    d = jnp.maximum(slots // jnp.maximum(n_open, 1), 1).astype(jnp.int32)
    j = jnp.arange(slots, dtype=jnp.int32)
    rank, node = j // d, j % d
    used = rank < n_open
    ranks = jnp.cumsum(active, dtype=jnp.int32) - 1
    lane_of_rank = jnp.zeros(slots, jnp.int32).at[jnp.where(active, ranks, slots)].set(
        jnp.arange(n_lanes, dtype=jnp.int32), mode="drop"
    )
    lane = lane_of_rank[jnp.minimum(rank, slots - 1)]
    held = jax.tree.map(lambda x: x[lane], states)  # each slot's lane's current state

    # each slot's node in its lane's tree
    if from_position:
        tables = [jnp.asarray(t) for t in speculation_trees(slots)]
        predicted = jnp.broadcast_to(jnp.asarray(acceptance, jnp.float32), (n_lanes,))[lane]
        bucket = jnp.clip(jnp.floor(predicted * ACCEPTANCE_BUCKETS), 0, ACCEPTANCE_BUCKETS - 1).astype(jnp.int32)
    else:
        tables, bucket = [jnp.asarray(t) for t in reject_chains(slots)], jnp.zeros(slots, jnp.int32)
    parent_node, on_accept, depth, child_accept, child_reject = (t[bucket, node] for t in tables)
    start = j - node
    parent = jnp.where(parent_node >= 0, start + parent_node, j)
    levels = jnp.max(jnp.where(used, depth, 0)) + 1

    # candidates, level by level: a node proposes from its held state, which is its parent's
    # candidate (accepted branch) or its parent's held state (rejected branch); `source` is the
    # slot whose candidate a node holds (-1: the lane's current state)
    k_propose, k_event, k_accept, k_hold = jax.random.split(key, 4)
    propose_keys = jax.random.split(k_propose, slots)

    def propose(positions):
        point = Point(positions[0], jnp.full((), jnp.nan, dtype), None)
        return jax.vmap(lambda k, p: dynamics.propose(k, point._replace(position=p), sampler.log_value))(
            propose_keys, positions
        )

    source = jnp.full(slots, -1, jnp.int32)
    position = held.position

    def level_body(t, carry):
        position, source, candidates, proposal_aux = carry
        here = depth == t
        mine = jnp.where(_rows(on_accept == 1, position), candidates[parent], position[parent])
        position = jnp.where(_rows(here, position), mine, position)
        source = jnp.where(here, jnp.where(on_accept == 1, parent, source[parent]), source)
        new_candidates, new_aux = propose(position)
        pick = lambda a, b: jnp.where(_rows(here, a), a, b)  # noqa: E731
        return position, source, pick(new_candidates, candidates), jax.tree.map(pick, new_aux, proposal_aux)

    if from_position:
        candidates, proposal_aux = propose(held.position)
        position, source, candidates, proposal_aux = jax.lax.fori_loop(
            1, levels, level_body, (position, source, candidates, proposal_aux)
        )
    else:  # every node proposes from the current state, with its gradient
        own_point = Point(held.position, held.logdensity, held.logdensity_grad, held.aux, held.geometry)
        candidates, proposal_aux = jax.vmap(lambda k, p: dynamics.propose(k, p, sampler.log_value))(
            propose_keys, own_point
        )
    candidates = candidates.astype(states.position.dtype)
    evaluated, invalid = jax.vmap(sampler.evaluate_point)(candidates)
    _, invalid, _, candidate_log_kill, _ = jax.vmap(lambda p, bad: sampler.kill_terms(0, p, bad, log_rates))(
        evaluated, invalid
    )

    # the state held at each node: the lane's own, or the candidate of slot `source`
    own = source < 0
    src = jnp.maximum(source, 0)
    held_value = lambda mine, cand: jnp.where(_rows(own, mine), mine, cand[src])  # noqa: E731
    current = Point(
        position.astype(candidates.dtype),  # the held positions the proposals started from
        held_value(held.logdensity, evaluated.logdensity),
        jax.tree.map(held_value, held.logdensity_grad, evaluated.grad),
        jax.tree.map(held_value, held.aux, evaluated.aux),
        jax.tree.map(held_value, held.geometry, evaluated.geometry),
    )
    current_log_kill = held_value(held.log_kill_rate, candidate_log_kill)

    uniforms = jax.vmap(lambda k: log_uniform(k, dtype))(jax.random.split(k_event, slots))
    event = jump_event(uniforms, jax.random.exponential(k_hold, (slots,), dtype), current_log_kill, log_r)
    killed = event.killed
    moved, local = jax.vmap(dynamics.accept)(jax.random.split(k_accept, slots), current, evaluated, proposal_aux)
    took = local.accepted.astype(jnp.int32)

    # replay: a node's event happens when its parent's did, without a kill, on its branch
    def valid_body(t, valid):
        reached = valid[parent] & ~killed[parent] & (took[parent] == on_accept)
        return jnp.where(depth == t, reached, valid)

    valid = jax.lax.fori_loop(1, levels, valid_body, used & (node == 0))
    next_node = jnp.where(local.accepted, child_accept, child_reject)
    last = valid & (killed | (next_node >= d))
    end = jax.tree.map(lambda c, m: jnp.where(_rows(killed, c), c, m), current, moved)
    end_log_kill = jnp.where(killed | ~local.accepted, current_log_kill, candidate_log_kill)
    target = jnp.where(last, lane, n_lanes)  # out of range: dropped
    put = lambda s, v: s.at[target].set(v, mode="drop")  # noqa: E731
    new_states = states._replace(
        position=put(states.position, end.position),
        logdensity=put(states.logdensity, end.logdensity),
        log_kill_rate=put(states.log_kill_rate, end_log_kill),
        logdensity_grad=jax.tree.map(put, states.logdensity_grad, end.grad),
        aux=jax.tree.map(put, states.aux, end.aux),
        geometry=jax.tree.map(put, states.geometry, end.geometry),
    )
    new_active = active.at[target].set(~killed, mode="drop")

    info = StepInfo(
        position=current.position,
        holding_time=event.holding_time,
        expected_holding_time=event.expected_holding_time,
        regenerated=killed,
        accepted=local.accepted & ~killed,
        acceptance_probability=jnp.where(killed, 0.0, local.acceptance_probability).astype(dtype),
        invalid=invalid & ~killed,
        uncovered=jnp.zeros(slots, bool),
        log_importance_weight=jnp.full(slots, -jnp.inf, dtype),
        start_drawn=jnp.zeros(slots, bool),
        negative_rate=jnp.zeros(slots, bool),
        bound_ratio=jnp.zeros(slots, dtype),
        aux=current.aux,
    )
    return SpeculativeSteps(
        new_states, new_active, info, current_log_kill, valid, last, lane, depth, parent, (on_accept == 1) & (node > 0)
    )
