"""Export of a run's stored draws to ArviZ: `xarray.DataTree` with ArviZ 1.x, `InferenceData` with 0.x.

Lanes are grouped into a few chains (4 by default), each chain its lanes' draws one after
another. A lane is a regenerative process started at a regeneration: its tours are
independent and identically distributed, so lanes laid end to end are distributed as one
longer run (up to each lane's last, unfinished tour). One chain per lane would make R-hat
measure how short each lane is: with `n` draws and an autocorrelation time of `tau` draws,
R-hat is about `sqrt(1 + 2 (tau - 1) / n)` even for a run whose estimates are exact, above the
usual 1.01 for the few hundred draws a lane keeps. Over chains of many lanes, R-hat and ESS
mean what they mean for MCMC chains: R-hat asks whether independent parts of the run agree
within their error, and ArviZ's ESS agrees with the run's own tour-based `ess`.

The stored draws of a Restore run are *weighted*: a draw's weight is its (expected) holding
time. ArviZ expects equally weighted draws, so by default each lane's draws are resampled in
proportion to their weights; the groups say which kind of draws they hold.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping

import numpy as np

from ._validation import check_integer

#: Chains the lanes are grouped into by default: as many as a usual run of MCMC chains.
CHAINS = 4

#: What the posterior group holds, written into its attributes (`restore_draws`).
RESAMPLED = "resampled"
WEIGHTED = "weighted"

_NOTES = {
    RESAMPLED: (
        "each lane's stored draws were resampled (systematic resampling) in proportion to their holding-time "
        "weights, so these draws are equally weighted; sample_stats.source_draw is the stored draw of its lane "
        "(sample_stats.lane) each one copies and sample_stats.source_weight its weight"
    ),
    WEIGHTED: (
        "the stored draws as the run kept them: draw i of a lane carries the weight sample_stats.weight "
        "(its expected holding time); weight them in every average"
    ),
}


def resample_lanes(weights: np.ndarray, seed: int) -> np.ndarray:
    """Per lane `(L, n)` weights, the indices `(L, n)` of a systematic resample of each lane's draws.

    A lane whose weights sum to zero keeps its draws in order.
    """
    rng = np.random.default_rng(seed)
    num_lanes, n = weights.shape
    index = np.tile(np.arange(n), (num_lanes, 1))
    for lane in range(num_lanes):
        w = weights[lane]
        if not w.sum() > 0:
            continue
        cdf = np.cumsum(w / w.sum())
        index[lane] = np.minimum(np.searchsorted(cdf, (rng.uniform() + np.arange(n)) / n), n - 1)
    return index


def chain_count(num_lanes: int, chains: int) -> int:
    """How many chains `num_lanes` lanes are grouped into: the largest divisor of `num_lanes` up to
    `chains` (chains must be equally long; `chains >= num_lanes` gives one chain per lane)."""
    chains = check_integer(chains, "chains")
    return max(c for c in range(1, min(chains, num_lanes) + 1) if num_lanes % c == 0)


def as_chains(values: np.ndarray, chains: int) -> np.ndarray:
    """`(lanes, n, ...)` as `(chains, lanes // chains * n, ...)`: consecutive lanes end to end."""
    return values.reshape(chains, -1, *values.shape[2:])


def to_arviz(
    draws: np.ndarray,
    draw_weights: np.ndarray,
    resample: bool = True,
    seed: int = 0,
    transform: Callable[[np.ndarray], Mapping[str, np.ndarray]] | None = None,
    attrs: Mapping[str, object] | None = None,
    chains: int = CHAINS,
):
    """Stored draws `(slots, lanes, d)` and weights `(slots, lanes)` as an ArviZ object.

    Arguments:
        draws: the stored draws, `(slots, lanes, d)`.
        draw_weights: their weights, `(slots, lanes)`.
        resample: resample each lane's draws in proportion to their weights (equally
            weighted draws, what ArviZ's diagnostics assume), or keep them weighted.
        seed: the seed of the resampling.
        transform: optional map from draws `(lanes, n, d)` to named arrays with leading axes
            `(lanes, n)` (e.g. a NumPyro model's constrained parameters); default one
            variable `"x"`.
        attrs: more attributes for the posterior group.
        chains: how many chains the lanes are grouped into (the largest divisor of the
            number of lanes up to this), each chain its lanes' draws one after another; the
            number of lanes for one chain per lane. `sample_stats.lane` says which lane each
            draw is from.

    Returns:
        `xarray.DataTree` with ArviZ 1.x, `arviz.InferenceData` with ArviZ 0.x.
    """
    import arviz as az

    if draws.shape[0] == 0:
        raise ValueError("no draws were stored: pass save=restore.SaveDraws(max_draws > 0) to restore.sample")
    draws = np.swapaxes(np.asarray(draws), 0, 1)  # (lane, draw, d)
    weights = np.swapaxes(np.asarray(draw_weights, np.float64), 0, 1)
    kind = RESAMPLED if resample else WEIGHTED
    if resample:
        index = resample_lanes(weights, seed)
        draws = np.take_along_axis(draws, index[:, :, None], axis=1)
        stats: dict[str, np.ndarray] = {
            "weight": np.ones_like(weights),
            "source_draw": index,
            "source_weight": np.take_along_axis(weights, index, axis=1),
        }
    else:
        stats = {"weight": weights}
    stats["lane"] = np.repeat(np.arange(draws.shape[0]), draws.shape[1]).reshape(draws.shape[:2])
    if transform is None:
        posterior = {"x": draws}
    else:
        posterior = {name: np.asarray(value) for name, value in transform(draws).items()}
        bad = [name for name, value in posterior.items() if value.shape[:2] != draws.shape[:2]]
        if bad:
            raise ValueError(f"transform must keep the leading (lane, draw) axes {draws.shape[:2]}; {bad} do not")
    num_chains = chain_count(draws.shape[0], chains)
    posterior = {name: as_chains(value, num_chains) for name, value in posterior.items()}
    stats = {name: as_chains(value, num_chains) for name, value in stats.items()}
    group_attrs = {
        "restore_draws": kind,
        "restore_note": _NOTES[kind],
        "restore_chains": f"{num_chains} chains of {draws.shape[0] // num_chains} lanes each, a chain's lanes one after another",
        **(attrs or {}),
    }
    with warnings.catch_warnings():  # ArviZ warns when there are more chains (lanes) than draws: normal here
        warnings.filterwarnings("ignore", message="(More chains|Found chain dimension)", category=UserWarning)
        if int(az.__version__.split(".")[0]) >= 1:  # ArviZ 1.x: a DataTree, attributes per group
            groups = {"posterior": posterior, "sample_stats": stats}
            return az.from_dict(groups, attrs={"posterior": group_attrs, "sample_stats": group_attrs})
        return az.from_dict(
            posterior=posterior, sample_stats=stats, posterior_attrs=group_attrs, sample_stats_attrs=group_attrs
        )
