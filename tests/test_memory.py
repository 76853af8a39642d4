"""Bounded memory: a run of 10^6 steps needs no more memory than one of 10^4 steps."""

import json
import os
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).parent / "_memory_run.py"


def test_peak_memory_does_not_grow_with_the_number_of_steps():
    completed = subprocess.run(
        [sys.executable, str(SCRIPT), "1000000"], capture_output=True, text=True, env=dict(os.environ), timeout=600
    )
    assert completed.returncode == 0, completed.stderr
    report = json.loads(completed.stdout.strip().splitlines()[-1])
    assert report["num_steps"] == 1_000_000
    # Streaming sums and a fixed draws budget: the 100x longer run allocates nothing new.
    growth = report["peak_after_long_mib"] - report["peak_after_short_mib"]
    assert growth < 16.0, report
    # The draws budget (1000 over 2 lanes) holds for both runs; the long one is thinned, and says so.
    assert report["short_draws"] == report["long_draws"] == [500, 2, 1]
    assert report["long_thin"] == 2000
    assert "max_draws=1,000" in report["draws_note"] and "every 2000th step" in report["draws_note"]
    assert abs(report["mean_x2"] - 1.0) < 0.05  # and the 2 x 10^6 states give the right answer
