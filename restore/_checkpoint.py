"""Checkpoint files: a pytree of arrays and a JSON header, written atomically, read back checked.

A checkpoint is a NumPy `.npz` archive holding every array leaf of a run's state (PRNG
keys as their key data) and a header with the run's fingerprint (key, sizes, sampler
parameters...) and progress. Resuming checks the fingerprint against the run being
resumed, and every leaf's shape and dtype against the state it replaces, so a checkpoint
is never silently applied to a different run.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._io import atomic_write

FORMAT = "restore-checkpoint/1"


class CheckpointError(ValueError):
    """A checkpoint file cannot be read, or belongs to another run."""


def _is_key(x) -> bool:
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _to_numpy(x) -> np.ndarray:
    return np.asarray(jax.random.key_data(x) if _is_key(x) else x)


def key_fingerprint(key) -> list[int]:
    """The key's raw data as a JSON-friendly list (typed or raw uint32 keys alike)."""
    data = jax.random.key_data(key) if _is_key(key) else key
    return np.asarray(data).ravel().astype(np.int64).tolist()


def array_digest(tree) -> str:
    """A SHA-256 digest of every array leaf of `tree` (shape, dtype and bytes), e.g. a sampler's parameters."""
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(eqx.filter(tree, eqx.is_array)):
        array = _to_numpy(leaf)
        digest.update(repr((array.shape, str(array.dtype))).encode())
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:16]


def save_checkpoint(path: str | os.PathLike, tree, header: dict[str, Any]) -> Path:
    """Write `tree`'s array leaves and `header` to `path` atomically (temporary file, then rename)."""
    leaves = jax.tree.leaves(tree)
    arrays: dict[str, Any] = {f"leaf{i:05d}": _to_numpy(leaf) for i, leaf in enumerate(leaves)}  # `Any`: as `savez` types its keywords
    text = json.dumps({"format": FORMAT, **header}, sort_keys=True)
    arrays["header"] = np.frombuffer(text.encode(), np.uint8)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as handle:  # a handle, so NumPy does not append `.npz` to the name
            np.savez(handle, **arrays)

    return atomic_write(path, write)


def read_header(path: str | os.PathLike) -> dict[str, Any]:
    """The header of the checkpoint at `path` (raises `CheckpointError` if it is not one)."""
    header, _ = _read(path)
    return header


def _read(path: str | os.PathLike) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
        header = json.loads(arrays.pop("header").tobytes().decode())
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, UnicodeDecodeError) as error:
        raise CheckpointError(
            f"cannot read checkpoint {path}: {error}. It is damaged or not a restore checkpoint; "
            "delete it (or pass Checkpoint(path, resume=False)) to start the run afresh"
        ) from error
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a {FORMAT} checkpoint (format {header.get('format')!r})")
    return header, arrays


def load_checkpoint(path: str | os.PathLike, like, expected: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
    """Read the checkpoint at `path` into the structure of `like`, checking it belongs to this run.

    Arguments:
        path: the checkpoint file.
        like: a pytree with the structure, shapes and dtypes of the saved one (e.g. the
            freshly initialised state); PRNG key leaves are rebuilt with its key type.
        expected: header entries that must match (the run's fingerprint).

    Returns:
        The restored pytree (NumPy leaves, typed keys as JAX arrays) and the full header.

    Raises:
        CheckpointError: if the file is unreadable, belongs to another run (the message
            lists what differs), or holds arrays of other shapes or dtypes.
    """
    header, arrays = _read(path)
    differ = [
        f"{name}: checkpoint has {header.get(name)!r}, this run has {value!r}"
        for name, value in expected.items()
        if header.get(name) != value
    ]
    if differ:
        raise CheckpointError(
            f"checkpoint {path} belongs to another run ({'; '.join(differ)}). Resume with the same key and "
            "arguments, or give another checkpoint path (or Checkpoint(path, resume=False) to overwrite it)"
        )
    leaves, treedef = jax.tree.flatten(like)
    if len(arrays) != len(leaves):
        raise CheckpointError(f"checkpoint {path} holds {len(arrays)} arrays, this run's state has {len(leaves)}")
    restored = []
    for i, leaf in enumerate(leaves):
        saved = arrays[f"leaf{i:05d}"]
        reference = jax.random.key_data(leaf) if _is_key(leaf) else leaf
        shape = tuple(np.shape(reference))
        dtype = np.dtype(reference.dtype) if hasattr(reference, "dtype") else np.asarray(reference).dtype
        if saved.shape != shape or saved.dtype != dtype:
            raise CheckpointError(
                f"checkpoint {path}: array {i} has shape {saved.shape} and dtype {saved.dtype}, this run expects "
                f"{shape} and {dtype}"
            )
        restored.append(jax.random.wrap_key_data(jnp.asarray(saved), impl=jax.random.key_impl(leaf)) if _is_key(leaf) else saved)
    return jax.tree.unflatten(treedef, restored), header
