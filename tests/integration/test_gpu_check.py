"""`examples/gpu_check.py`: throughput on a GPU, right mode weights, and a clear message without one.

The test marked `gpu` is deselected by default (`pytest -m gpu` runs it) and skipped on a
machine where JAX sees no GPU; the default suite checks what happens without one, and that
the check of the printed mode weights rejects wrong ones.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "examples" / "gpu_check.py"
MODE_WEIGHTS = re.compile(r"mode weights \[([^\]]*)\] \+- \[([^\]]*)\] \(truth \[([^\]]*)\]\)")


def mode_weight_z(stdout: str) -> np.ndarray:
    """z-scores of the mode weights the check prints, against the truth it prints with them."""
    found = MODE_WEIGHTS.search(stdout)
    assert found is not None, stdout
    value, se, truth = (np.array(group.split(), float) for group in found.groups())
    return (value - truth) / se


def _has_gpu() -> bool:
    try:
        return bool(jax.devices("gpu"))
    except RuntimeError:
        return False


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)}
    return subprocess.run([sys.executable, str(SCRIPT), *args], env=env, capture_output=True, text=True, timeout=900, check=False)


@pytest.mark.skipif(_has_gpu(), reason="this machine has a GPU")
def test_without_a_gpu_the_check_says_so_and_skips():
    done = _run()
    assert done.returncode == 0, done.stderr
    assert "skipped, no GPU" in done.stdout and "pip install -e '.[cuda]'" in done.stdout
    assert "steps/s" not in done.stdout
    assert _run("--require-gpu").returncode == 1


@pytest.mark.gpu
@pytest.mark.skipif(not _has_gpu(), reason="JAX sees no GPU")
def test_sampler_and_renderer_run_on_the_gpu():
    done = _run("--quick", "--require-gpu")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "GPU(s)" in done.stdout and "steps/s" in done.stdout
    assert np.all(np.abs(mode_weight_z(done.stdout)) < 5), done.stdout
    if "render: skipped" not in done.stdout:
        assert "cuda_ad_rgb" in done.stdout and "paths/s" in done.stdout


def test_the_mode_weight_check_rejects_wrong_weights():
    """Weights within their errors pass; swapped modes, or errors ten times too small, fail."""
    line = "  mode weights [{}] +- [0.0064 0.0111 0.0119] (truth [0.1667 0.3333 0.5   ])"
    assert np.all(np.abs(mode_weight_z(line.format("0.1598 0.3458 0.4944"))) < 5)
    assert np.abs(mode_weight_z(line.format("0.3333 0.1667 0.5"))).max() > 5
    assert np.abs(10 * mode_weight_z(line.format("0.1598 0.3458 0.4944"))).max() > 5
