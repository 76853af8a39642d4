"""Several processes (hosts) on one machine: the same numbers as one process, also across a restart.

Two processes join with `jax.distributed.initialize` on localhost with CPU collectives
(gloo), each with two forced CPU devices, and split 8 lanes over the 4 global devices
(`devices="all"`). Their sums, estimates and draws must equal, bit for bit, those of one
process running the same lanes on one device. A checkpointed run interrupted in both
processes after two chunks resumes from its checkpoint to the same numbers.
"""

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests._runs import forced_devices_flags

ROOT = str(Path(__file__).resolve().parents[2])  # the scripts import tests._runs

SCRIPT = r"""
import os, sys, warnings
mode, out = sys.argv[1], sys.argv[2]
import jax
jax.config.update("jax_enable_x64", True)
if mode != "single":
    process_id, port = int(sys.argv[3]), sys.argv[4]
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=f"127.0.0.1:{port}", num_processes=2, process_id=process_id)
    assert jax.process_count() == 2 and jax.device_count() == 4 and jax.local_device_count() == 2
import jax.numpy as jnp, numpy as np
import restore
from restore.dynamics import BrownianMotion
from restore.local import RandomWalk
from restore.regeneration import Gaussian
from tests._runs import ctrl_c_after, record as record_run

def logdensity(x):
    return -0.5 * jnp.sum(x**2)

jump = restore.JumpRestore(logdensity, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), tour_length=3.0)
brownian = restore.Restore(logdensity, BrownianMotion(), Gaussian(jnp.zeros(2), 1.0), log_rate=2.0, bound=50.0)
devices = None if mode == "single" else "all"
kwargs = dict(num_lanes=8, num_steps=160, num_chunks=20, progress=False, devices=devices)

def record(arrays, name, result):
    record_run(arrays, name, result)
    arrays[f"{name}/log_rate"] = np.asarray(result.log_rate)
    arrays[f"{name}/num_steps"] = np.asarray([result.num_steps, result.finishing_steps])

arrays = {}
for name, sampler in (("jump", jump), ("brownian", brownian)):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        record(arrays, name, restore.sample(sampler, jax.random.key(7), **kwargs))
if mode == "hosts":  # interrupted in both processes after two chunks, then resumed from the checkpoint
    with warnings.catch_warnings(), ctrl_c_after(2):
        warnings.simplefilter("ignore")
        partial = restore.sample(jump, jax.random.key(7), checkpoint=out + ".ckpt", **kwargs)
    arrays["partial"] = np.asarray([partial.interrupted, partial.num_steps])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        record(arrays, "resumed", restore.sample(jump, jax.random.key(7), checkpoint=out + ".ckpt", **kwargs))
suffix = "" if mode == "single" else f".{jax.process_index()}"
np.savez(out + suffix + ".npz", **arrays)
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _launch(mode: str, out, process_id=None, port=None) -> subprocess.Popen:
    env = {
        **os.environ,
        "XLA_FLAGS": forced_devices_flags(2),
        "JAX_PLATFORMS": "cpu",
        "PYTHONPATH": os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH")) if p),
    }
    args = [sys.executable, "-c", SCRIPT, mode, str(out)]
    if process_id is not None:
        args += [str(process_id), str(port)]
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _load(path) -> dict:
    with np.load(path) as data:
        return dict(data)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("multihost")
    port = _free_port()
    procs = {"single": _launch("single", tmp / "single")}
    procs.update({f"process {i}": _launch("hosts", tmp / "hosts", i, port) for i in (0, 1)})
    logs = {name: proc.communicate(timeout=300)[0] for name, proc in procs.items()}
    for name, proc in procs.items():
        assert proc.returncode == 0, f"{name} failed:\n{logs[name]}"
    return _load(tmp / "single.npz"), [_load(tmp / f"hosts.{i}.npz") for i in (0, 1)]


def _assert_same(reference: dict, other: dict, names) -> None:
    for name in names:
        if name.endswith("histogram_times"):  # partial histograms of the devices are added in another order
            np.testing.assert_allclose(other[name], reference[name], rtol=1e-12, err_msg=name)
        else:
            np.testing.assert_array_equal(other[name], reference[name], err_msg=name)


def test_two_processes_give_every_process_the_one_process_result(runs):
    single, hosts = runs
    for arrays in hosts:
        assert {name for name in arrays if not name.startswith(("resumed/", "partial"))} == set(single)
        _assert_same(single, arrays, single)
    assert single["jump/sums/num_tours"].sum() > 100 and single["brownian/sums/num_tours"].sum() > 20
    assert single["jump/draws"].shape[:2] == (160, 8)


def test_an_interrupted_two_process_run_resumes_bit_for_bit(runs):
    single, hosts = runs
    for arrays in hosts:
        assert arrays["partial"].tolist() == [True, 16]  # two chunks of 8 steps, then Ctrl-C
        resumed = {name.replace("resumed/", "jump/"): value for name, value in arrays.items() if name.startswith("resumed/")}
        assert set(resumed) == {name for name in single if name.startswith("jump/")}
        _assert_same(single, resumed, resumed)


def test_processes_that_see_different_checkpoints_are_refused(tmp_path, monkeypatch):
    import jax
    import jax.numpy as jnp

    import restore
    import restore._run as run_module
    from restore._checkpoint import CheckpointError

    # Process 0 finds the checkpoint of step 8, process 1 none (e.g. a folder that is not shared).
    monkeypatch.setattr(run_module, "from_every_process", lambda values: np.asarray([values, [0, -1, -1]]))
    checkpoint = tmp_path / "run.ckpt"
    checkpoint.write_bytes(b"")
    sampler = restore.JumpRestore(
        lambda x: -0.5 * jnp.sum(x**2), restore.local.RandomWalk(1.0), restore.regeneration.Gaussian(jnp.zeros(2), 2.0), log_rate=0.0
    )
    with pytest.raises(CheckpointError, match=r"processes disagree .*1: 'no checkpoint'.*file system that every process sees"):
        restore.sample(sampler, jax.random.key(0), num_lanes=4, num_steps=8, progress=False, checkpoint=checkpoint)
