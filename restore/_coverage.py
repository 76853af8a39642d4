"""Mass that a run's tours would not reach: the regeneration checked against draws of another run.

A Restore run's diagnostics see only the tours it ran. Where the regeneration `u` is much
thinner than the target (a mode that `u` leaves to its defensive component, say), tours
start too rarely to be met in the run, yet each would last long enough to carry that
region's share of the time: the estimates miss the region's mass, and nothing in the run
shows it. Draws of the target from another process (an earlier stage of `autosample`, run
with another regeneration) do show it. For draws `x_i` of the target with weights `w_i`,
`q_i = u(x_i) / pi(x_i)` (with `pi = p / Z`) gives, for the region `R` of the draws where
`q` is smallest, its target mass `sum_R w / sum w` and its regeneration mass
`sum_R w q / sum w` (an importance estimate). A run of `N` tours expects `N u(R)` tours to
start in `R`; the largest target mass of such a region in which it expects fewer than one
start is mass the run cannot have seen.
"""

from __future__ import annotations

import numpy as np


def unseen_mass(log_p, log_u, weights, log_z: float, tours: float) -> float:
    """The largest share of the target's mass, among the draws where `u / pi` is smallest, in
    which a run of `tours` tours expects fewer than one tour to start (0 if there is none).

    Arguments:
        log_p: `(n,)` the unnormalised log density at draws of the target.
        log_u: `(n,)` the regeneration's log density there.
        weights: `(n,)` the draws' weights.
        log_z: `log Z`, the normaliser of `p` (the run's estimate).
        tours: the number of tours of the run.
    """
    log_p, log_u, w = (np.asarray(a, np.float64).reshape(-1) for a in (log_p, log_u, weights))
    ok = np.isfinite(log_p) & np.isfinite(w) & (w > 0) & ~np.isnan(log_u)
    log_p, log_u, w = log_p[ok], log_u[ok], w[ok]
    if w.size == 0 or not tours > 0:
        return 0.0
    log_q = log_u - log_p + log_z  # log u / pi
    order = np.argsort(log_q)
    total = np.sum(w)
    mass = np.cumsum(w[order]) / total
    starts = tours * np.cumsum(w[order] * np.exp(np.minimum(log_q[order], 700.0))) / total
    unseen = mass[starts < 1.0]
    return float(unseen[-1]) if unseen.size else 0.0
