"""Threefry-2x32 keys whose hash is unrolled in the compiled program: JAX's default bits, fewer kernels.

On the CPU, JAX lowers its Threefry-2x32 hash (Salmon et al. 2011, 20 rounds) as a rolled
loop of five iterations, to keep compilation short. Inside a sampler's loop, where every
step makes several draws for every lane, each draw then costs a small loop of kernels
rather than one fused elementwise kernel. `unrolled_keys` re-wraps the key data of JAX's
default keys in a PRNG implementation (`jax.extend.random.define_prng_impl`) that computes
the same hash, split, fold-in and random bits with plain elementwise operations, which
XLA fuses. The bits are the same (tests compare them with JAX's own), so every stream, and
every result, stays bit-identical; only the compiled program changes.

JAX's gamma sampler runs its draws one after another for any keys but its own, so gamma
draws go through `loggamma`, which hands it JAX's keys with the same bits.

It follows JAX's `jax_threefry_partitionable` layout (the default since JAX 0.5); with that
flag off, or for keys of another implementation, the keys are left as they are.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.extend.random import define_prng_impl
from jaxtyping import Array, PRNGKeyArray

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_PARITY = np.uint32(0x1BD11BDA)


def _rotate_left(x: Array, distance: int) -> Array:
    return lax.shift_left(x, np.uint32(distance)) | lax.shift_right_logical(x, np.uint32(32 - distance))


def threefry2x32(k1: Array, k2: Array, x1: Array, x2: Array) -> tuple[Array, Array]:
    """The Threefry-2x32 block cipher (20 rounds) of the counters `(x1, x2)` under the key `(k1, k2)`."""
    schedule = (k1, k2, k1 ^ k2 ^ _PARITY)
    x1, x2 = x1 + schedule[0], x2 + schedule[1]
    for block in range(5):
        for distance in _ROTATIONS[block % 2]:
            x1 = x1 + x2
            x2 = x1 ^ _rotate_left(x2, distance)
        x1 = x1 + schedule[(block + 1) % 3]
        x2 = x2 + schedule[(block + 2) % 3] + np.uint32(block + 1)
    return x1, x2


def _counters(shape: tuple[int, ...]) -> tuple[Array, Array]:
    """The high and low words of a `uint64` iota of `shape` (JAX's partitionable counters)."""
    size = int(np.prod(shape, dtype=np.int64))
    if size >= 2**32:
        raise NotImplementedError("more than 2**32 random words from one key")
    low = lax.iota(np.uint32, size).reshape(shape)
    return jnp.zeros(shape, np.uint32), low


def _hash(key: Array, shape: tuple[int, ...]) -> tuple[Array, Array]:
    high, low = _counters(shape)
    return threefry2x32(key[0], key[1], high, low)


def _seed(seed: Array) -> Array:
    seed = jnp.asarray(seed)
    high = lax.convert_element_type(lax.shift_right_logical(seed, lax.full_like(seed, 32)), np.uint32)
    low = lax.convert_element_type(jnp.bitwise_and(seed, lax.full_like(seed, 0xFFFFFFFF)), np.uint32)
    return jnp.stack([high, low])


def _split(key: Array, shape: tuple[int, ...]) -> Array:
    first, second = _hash(key, tuple(shape))
    return jnp.stack([first, second], axis=-1)


def _fold_in(key: Array, data: Array | int) -> Array:
    data = lax.convert_element_type(jnp.asarray(data), np.uint32)
    first, second = threefry2x32(key[0], key[1], jnp.zeros((), np.uint32), data)
    return jnp.stack([first, second])


def _random_bits(key: Array, bit_width: int, shape: tuple[int, ...]) -> Array:
    first, second = _hash(key, tuple(shape))
    if bit_width == 64:
        high, low = (lax.convert_element_type(b, np.uint64) for b in (first, second))
        return lax.shift_left(high, np.uint64(32)) | low
    bits = first ^ second
    return bits if bit_width == 32 else lax.convert_element_type(bits, np.dtype(f"uint{bit_width}"))


UNROLLED_THREEFRY = define_prng_impl(
    key_shape=(2,),
    seed=_seed,
    split=_split,
    random_bits=_random_bits,
    fold_in=_fold_in,
    name="threefry2x32_unrolled",
    tag="fru",
)
"""The PRNG implementation of `unrolled_keys`: JAX's Threefry-2x32 bits (partitionable layout),
the hash as plain elementwise operations. `jax.random.key(seed, impl=UNROLLED_THREEFRY)`
makes such a key directly."""


def unrolled_keys(keys: PRNGKeyArray) -> PRNGKeyArray:
    """`keys` (JAX's default Threefry keys) as keys of `UNROLLED_THREEFRY`, with the same bits.

    Keys of another implementation, and all keys when `jax_threefry_partitionable` is off
    (another layout of the bits), are returned unchanged.
    """
    partitionable = getattr(jax.config, "jax_threefry_partitionable")  # noqa: B009 (not in JAX's type stubs)
    if not jnp.issubdtype(keys.dtype, jax.dtypes.prng_key) or not partitionable:
        return keys
    if str(jax.random.key_impl(keys)) != "threefry2x32":
        return keys
    return jax.random.wrap_key_data(jax.random.key_data(keys), impl=UNROLLED_THREEFRY)


def loggamma(key: PRNGKeyArray, a, shape: tuple[int, ...], dtype) -> Array:
    """`jax.random.loggamma`, drawn on JAX's own Threefry keys when given unrolled ones (the same bits).

    JAX's gamma sampler batches its rejection loop with `vmap` only for JAX's own Threefry
    keys; for any other implementation it runs the draws one after another (`lax.map`).
    """
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) and jax.random.key_impl(key) == UNROLLED_THREEFRY:
        key = jax.random.wrap_key_data(jax.random.key_data(key), impl="threefry2x32")
    return jax.random.loggamma(key, a, shape, dtype=dtype)
