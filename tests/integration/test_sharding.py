"""Lanes sharded over several devices: the same per-lane paths and sums as on one device.

Several devices are forced on the CPU (`XLA_FLAGS=--xla_force_host_platform_device_count=4`),
which must be set before JAX starts, so the runs happen in subprocesses. The run on one
device and the run on four devices go in two processes side by side (each compiles two
samplers), and the test compares what they write.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore.local import RandomWalk
from restore.regeneration import Gaussian
from tests._runs import forced_devices_flags

NUM_DEVICES = 4
ROOT = str(Path(__file__).resolve().parents[2])  # the script imports tests._runs


def std_normal(x):
    return -0.5 * jnp.sum(x**2)


SCRIPT = r"""
import json, sys, warnings
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
import restore
import restore._run as run_module
from restore.dynamics import BrownianMotion
from restore.local import RandomWalk
from restore.regeneration import Gaussian
from tests._runs import ctrl_c_after, record

mode, out = sys.argv[1], sys.argv[2]
assert len(jax.devices()) == 4, jax.devices()
report = {}

# Record how the per-lane sums are laid out when the run is gathered to the host (once, at the end).
gather = run_module.to_host
def spy(tree):
    sums = tree.sums if hasattr(tree, "sums") else tree[0]
    report.setdefault("shards", []).append([s.data.shape[0] for s in sums.sum_t.addressable_shards])
    return gather(tree)
run_module.to_host = spy

if mode == "sharded":
    try:
        sampler = restore.JumpRestore(
            lambda x: -0.5 * jnp.sum(x**2), RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0
        )
        restore.sample(sampler, jax.random.key(0), num_lanes=6, num_steps=10, progress=False, devices=4)
    except ValueError as err:
        report["error"] = str(err)

def logdensity(x):
    return -0.5 * jnp.sum(x**2)

jump = restore.JumpRestore(logdensity, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
brownian = restore.Restore(logdensity, BrownianMotion(), Gaussian(jnp.zeros(2), 1.0), log_rate=2.0, bound=50.0)
runs = {
    "jump": (jump, 4 if mode == "sharded" else None),
    "brownian": (brownian, jax.devices()[:4] if mode == "sharded" else None),
}
arrays = {}
for name, (sampler, devices) in runs.items():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = restore.sample(sampler, jax.random.key(7), num_lanes=8, num_steps=200, progress=False, devices=devices)
    record(arrays, name, result)
    report[f"{name}/finishing_steps"] = result.finishing_steps
# The open tours finished in a batch narrower than the lanes (each device its own), as large runs do.
import restore._run_loop as run_loop
narrow_defaults = run_loop.NARROW_FINISH_LANES, run_loop.NARROW_FACTOR
run_loop.NARROW_FINISH_LANES, run_loop.NARROW_FACTOR = 1, 2
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    result = restore.sample(jump, jax.random.key(7), num_lanes=8, num_steps=200, progress=False, devices=runs["jump"][1])
run_loop.NARROW_FINISH_LANES, run_loop.NARROW_FACTOR = narrow_defaults
record(arrays, "narrow", result)
report["narrow/finishing_steps"] = result.finishing_steps
# A short run: the tours still open after the budget's 4 finishing steps of every lane go to the narrow batch.
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    result = restore.sample(jump, jax.random.key(7), num_lanes=8, num_steps=4, progress=False, devices=runs["jump"][1])
record(arrays, "handoff", result)
report["handoff/finishing_steps"], report["handoff/unfinished"] = result.finishing_steps, result.unfinished_tours
if mode == "sharded":  # interrupted after two chunks, then resumed from the checkpoint onto the devices
    kwargs = dict(num_lanes=8, num_steps=200, progress=False, devices=4, checkpoint=out + ".ckpt")
    with warnings.catch_warnings(), ctrl_c_after(2):
        warnings.simplefilter("ignore")
        partial = restore.sample(jump, jax.random.key(7), **kwargs)
    report["partial"] = [partial.interrupted, partial.num_steps]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        resumed = restore.sample(jump, jax.random.key(7), **kwargs)
    for field in resumed.sums._fields:
        arrays[f"resumed/sums/{field}"] = getattr(resumed.sums, field)
    arrays["resumed/draws"] = resumed.draws
np.savez(out + ".npz", **arrays)
with open(out + ".json", "w") as f:
    json.dump(report, f)
"""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sharding")
    env = {
        **os.environ,
        "XLA_FLAGS": forced_devices_flags(NUM_DEVICES),
        "JAX_PLATFORMS": "cpu",
        "JAX_ENABLE_X64": "1",
        "PYTHONPATH": os.pathsep.join(p for p in (ROOT, os.environ.get("PYTHONPATH")) if p),
    }
    procs = {
        mode: subprocess.Popen(
            [sys.executable, "-c", SCRIPT, mode, str(tmp / mode)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for mode in ("single", "sharded")
    }
    out = {}
    for mode, proc in procs.items():
        log, _ = proc.communicate(timeout=600)
        assert proc.returncode == 0, f"{mode} run failed:\n{log}"
        with np.load(tmp / f"{mode}.npz") as data:
            arrays = dict(data)
        out[mode] = (arrays, json.loads((tmp / f"{mode}.json").read_text()))
    return out


def test_sharded_lanes_match_one_device_bit_for_bit(runs):
    single, sharded = runs["single"][0], runs["sharded"][0]
    assert set(single) == {name for name in sharded if not name.startswith("resumed/")}
    for name in single:
        if name.endswith("histogram_times"):  # partial histograms are summed in another order
            np.testing.assert_allclose(sharded[name], single[name], rtol=1e-12, err_msg=name)
        else:
            np.testing.assert_array_equal(sharded[name], single[name], err_msg=name)
    report = runs["sharded"][1]
    for name in ("jump", "brownian", "narrow", "handoff"):
        assert report[f"{name}/finishing_steps"] == runs["single"][1][f"{name}/finishing_steps"]
        assert single[f"{name}/histogram_counts"].sum() == single[f"{name}/sums/num_tours"].sum() > (8 if name == "handoff" else 20)
    # The lanes stay split 2 per device through the run, and nothing per lane comes to the host
    # before the end: one gather of 4 shards for each of the four runs (the chunks of 20 steps
    # report a few scalars).
    assert report["shards"][:4] == [[2, 2, 2, 2]] * 4
    assert runs["single"][1]["shards"] == [[8]] * 4
    # the short run handed its longest tours to the narrow batch, on each device its own, and ended them all
    assert report["handoff/finishing_steps"] > 4 and report["handoff/unfinished"] == 0


def test_narrow_finishing_follows_the_same_paths(runs):
    """Finishing the open tours a few lanes at a time (on each device) gives every lane the steps a
    step of all lanes would: the same sums, draws and estimates as finishing at full width."""
    for mode in ("single", "sharded"):
        arrays, report = runs[mode]
        assert report["narrow/finishing_steps"] == report["jump/finishing_steps"] > 0
        for name in [n for n in arrays if n.startswith("narrow/")]:
            wide = arrays[name.replace("narrow/", "jump/")]
            if name.endswith("histogram_times") or "/estimate/" in name or name.endswith("log_z"):  # sums in another order
                np.testing.assert_allclose(arrays[name], wide, rtol=1e-12, err_msg=name)
            else:
                np.testing.assert_array_equal(arrays[name], wide, err_msg=f"{mode} {name}")


def test_sharded_run_resumes_from_its_checkpoint_bit_for_bit(runs):
    arrays, report = runs["sharded"]
    assert report["partial"] == [True, 8]  # two chunks of 4 steps, then Ctrl-C
    for name in [n for n in arrays if n.startswith("resumed/")]:
        np.testing.assert_array_equal(arrays[name], arrays[name.replace("resumed/", "jump/")], err_msg=name)


def test_sharded_estimates_are_right(runs):
    arrays = runs["sharded"][0]
    for name in ("jump", "brownian"):
        value, se = arrays[f"{name}/estimate/x**2"]
        assert np.all(np.abs(value - 1.0) < 5 * se), (name, value, se)
        value, se = arrays[f"{name}/estimate/x"]
        assert np.all(np.abs(value) < 5 * se), (name, value, se)
    assert abs(float(arrays["jump/log_z"]) - np.log(2 * np.pi)) < 0.5


def test_lanes_must_split_evenly_over_the_devices(runs):
    error = runs["sharded"][1]["error"]
    assert "num_lanes (6) must be divisible by the number of devices (4)" in error


def test_bad_devices_argument_is_rejected_before_any_work():
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
    count = len(jax.devices())
    with pytest.raises(ValueError, match="devices are available"):
        restore.sample(sampler, jax.random.key(0), num_lanes=8, num_steps=10, progress=False, devices=count + 1)
    with pytest.raises(ValueError, match="devices must be"):
        restore.sample(sampler, jax.random.key(0), num_lanes=8, num_steps=10, progress=False, devices="most")
    with pytest.raises(TypeError, match="devices must be"):
        restore.sample(sampler, jax.random.key(0), num_lanes=8, num_steps=10, progress=False, devices=[0, 1])
