"""Statistical checks for samplers: run them on your own kernels.

The three checks every sampler of this package passes, with negative controls in its
test suite that must fail them:

1. `stationarity_test`: started from exact target draws, the state at a fixed time is
   still target-distributed (KS tests on projections and on the log density,
   chi-square on modes).
2. `ergodicity_test`: from regeneration-started lanes, estimates agree with known
   expectations within their standard errors, and the mean tour duration is `1/c`.
3. `calibration_test`: over independent replications, z-scores are standard normal.

All use fixed keys and are deterministic; each has a stated family-wise level.
"""

from ._calibration import calibration_test as calibration_test
from ._ergodicity import ergodicity_test as ergodicity_test
from ._fixed_time import fixed_time_states as fixed_time_states
from ._stationarity import CheckReport as CheckReport
from ._stationarity import stationarity_test as stationarity_test
