"""Checkpoint and resume: interrupted runs (Ctrl-C, SIGINT, SIGKILL) resume bit for bit."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

import restore
from restore._checkpoint import CheckpointError, read_header

sys.path.insert(0, str(Path(__file__).parents[1]))
import _checkpoint_run as child  # noqa: E402

SCRIPT = Path(__file__).parents[1] / "_checkpoint_run.py"


@pytest.fixture(scope="module")
def reference():
    """The uninterrupted run, without any checkpoint."""
    return child.arrays(child.run())


def assert_identical(result_arrays, reference):
    assert result_arrays.keys() == reference.keys()
    for name, value in reference.items():
        np.testing.assert_array_equal(result_arrays[name], value, err_msg=name)


def test_checkpointing_does_not_change_the_run(reference, tmp_path):
    result = child.run(tmp_path / "run.ckpt")
    assert_identical(child.arrays(result), reference)
    header = read_header(tmp_path / "run.ckpt")
    assert header["finished"] and header["done"] == child.NUM_STEPS
    again = child.run(tmp_path / "run.ckpt")  # a finished checkpoint gives its result at once
    assert_identical(child.arrays(again), reference)


def _start(checkpoint: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(SCRIPT), str(checkpoint), str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=dict(os.environ),
    )


def _wait_for_checkpoint(process: subprocess.Popen, checkpoint: Path, beyond: int, timeout: float = 240.0) -> int:
    """Poll until `checkpoint` records more than `beyond` steps; return that step count."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if checkpoint.exists():
            try:
                header = read_header(checkpoint)
            except CheckpointError:  # cannot happen with atomic writes; fail loudly below if it persists
                header = None
            if header is not None and header["done"] > beyond:
                return header["done"]
        if process.poll() is not None:
            output = process.stdout.read().decode()
            pytest.fail(f"the run ended before a new checkpoint (exit {process.returncode}):\n{output}")
        time.sleep(0.005)
    process.kill()
    pytest.fail("no checkpoint appeared in time")


def test_sigkill_then_sigint_then_resume_is_bit_identical(reference, tmp_path):
    checkpoint, out = tmp_path / "run.ckpt", tmp_path / "out.npz"

    # 1. Killed outright (no chance to clean up) after its first checkpoint.
    first = _start(checkpoint, out)
    done = _wait_for_checkpoint(first, checkpoint, beyond=0)
    first.send_signal(signal.SIGKILL)
    first.wait(timeout=60)
    assert first.returncode == -signal.SIGKILL
    killed_at = read_header(checkpoint)
    assert not killed_at["finished"] and killed_at["done"] < child.NUM_STEPS, "the kill came too late to test anything"
    assert not out.exists()
    # A kill during a write can leave that write's temporary file, never a damaged checkpoint.
    leftover = [p.name for p in tmp_path.iterdir() if p.name != "run.ckpt"]
    assert all(name.startswith(".run.ckpt.") and name.endswith(".tmp.ckpt") for name in leftover), leftover

    # 2. Resumed, then interrupted with SIGINT (Ctrl-C) after it saved further progress.
    second = _start(checkpoint, out)
    _wait_for_checkpoint(second, checkpoint, beyond=max(done, killed_at["done"]))
    second.send_signal(signal.SIGINT)
    output = second.communicate(timeout=120)[0].decode()
    assert second.returncode == 0, output
    partial = np.load(out)
    assert bool(partial["interrupted"]), "SIGINT arrived after the run had finished"
    interrupted_at = read_header(checkpoint)
    assert interrupted_at["done"] == int(partial["num_steps"]) < child.NUM_STEPS
    assert not interrupted_at["finished"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.npz", "run.ckpt"], "a temporary file was left behind"

    # 3. Resumed to the end in this process: every sum, draw and histogram bin matches.
    result = child.run(checkpoint)
    assert not result.interrupted and result.num_steps == child.NUM_STEPS
    assert_identical(child.arrays(result), reference)


def test_ctrl_c_saves_the_partial_run(reference, tmp_path, monkeypatch):
    """KeyboardInterrupt between chunks: the partial result is returned and saved; resuming completes it.
    The interrupt comes as the fifth chunk is dispatched, while the fourth runs, which is waited for."""
    import restore._run as run_module

    original, calls = run_module.advance, []

    def interrupted_advance(*args, **kwargs):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(run_module, "advance", interrupted_advance)
    with pytest.warns(UserWarning, match="interrupted after 640 of 8000 steps"):
        partial = child.run(tmp_path / "run.ckpt")
    assert partial.interrupted and partial.num_steps == 640
    assert read_header(tmp_path / "run.ckpt")["done"] == 640
    monkeypatch.setattr(run_module, "advance", original)
    assert_identical(child.arrays(child.run(tmp_path / "run.ckpt")), reference)


def test_checkpoint_of_another_run_is_refused(tmp_path):
    checkpoint = tmp_path / "run.ckpt"
    sampler = child.sampler()
    kwargs = dict(num_lanes=4, num_steps=20, progress=False, checkpoint=checkpoint)
    restore.sample(sampler, jax.random.key(0), **kwargs)
    with pytest.raises(CheckpointError, match="key: checkpoint has"):
        restore.sample(sampler, jax.random.key(1), **kwargs)
    with pytest.raises(CheckpointError, match="num_lanes: checkpoint has 4, this run has 8"):
        restore.sample(sampler, jax.random.key(0), **{**kwargs, "num_lanes": 8})
    with pytest.raises(CheckpointError, match="observables"):
        restore.sample(sampler, jax.random.key(0), observables={"y": lambda x: x[0]}, **kwargs)
    fresh = restore.sample(sampler, jax.random.key(1), **{**kwargs, "checkpoint": restore.Checkpoint(checkpoint, resume=False)})  # overwrites it
    assert read_header(checkpoint)["key"] == np.asarray(jax.random.key_data(jax.random.key(1))).tolist()
    assert fresh.num_steps == 20


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_damaged_checkpoint_gives_a_clear_error(tmp_path, damage):
    checkpoint = tmp_path / "run.ckpt"
    kwargs = dict(num_lanes=4, num_steps=20, progress=False, checkpoint=checkpoint)
    restore.sample(child.sampler(), jax.random.key(0), **kwargs)
    data = checkpoint.read_bytes()
    checkpoint.write_bytes({"truncate": data[: len(data) // 2], "garbage": os.urandom(300), "empty": b""}[damage])
    with pytest.raises(CheckpointError, match="cannot read checkpoint .* delete it"):
        restore.sample(child.sampler(), jax.random.key(0), **kwargs)


def test_bad_checkpoint_settings_are_rejected():
    with pytest.raises(ValueError, match="every_steps must be a positive integer"):
        restore.Checkpoint("unused.ckpt", every_steps=0)
    with pytest.raises(ValueError, match="every_seconds must be a positive number"):
        restore.Checkpoint("unused.ckpt", every_seconds=-1.0)
    with pytest.raises(TypeError, match="checkpoint must be a restore.Checkpoint or a file name"):
        restore.sample(child.sampler(), jax.random.key(0), num_lanes=4, num_steps=20, progress=False, checkpoint=3)
    assert not Path("unused.ckpt").exists()


def test_a_stale_temporary_file_is_removed_by_the_next_write(tmp_path):
    """A process killed outright while writing leaves its temporary file; the next write of that file removes it."""
    from restore._io import atomic_write

    (tmp_path / ".run.ckpt.k1ll3d.tmp.ckpt").write_bytes(b"half a checkpoint")
    (tmp_path / ".other.ckpt.k1ll3d.tmp.ckpt").write_bytes(b"another file's")
    atomic_write(tmp_path / "run.ckpt", lambda tmp: tmp.write_bytes(b"new"))
    assert sorted(p.name for p in tmp_path.iterdir()) == [".other.ckpt.k1ll3d.tmp.ckpt", "run.ckpt"]
    assert (tmp_path / "run.ckpt").read_bytes() == b"new"
