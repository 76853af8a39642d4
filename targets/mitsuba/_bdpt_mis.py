"""MIS weights of bidirectional path tracing from per-vertex forward and reverse densities.

Write a path of `k` segments as `x_0` (on a light) .. `x_k` (the camera). Strategy `s`
(`0 <= s <= k`) takes `x_0 .. x_{s-1}` from the light subpath and `x_s .. x_k` from the
camera subpath, so its density is `p_s = prod_{j<s} pL_j prod_{j>=s} pE_j`, with
`pL_j` (`pE_j`) the area density of `x_j` given its neighbours towards the light
(camera). Then `p_{s+1} / p_s = pL_s / pE_s`, and the weight is
`w_s = p_s^b / sum_i p_i^b` over the strategies `i` that can produce the path
(`b = 1` balance, `b = 2` power heuristic). Strategy `i` connects `x_{i-1}` and `x_i`,
so it cannot produce a path where either is a delta (specular) vertex; those are left
out of the sum, exactly as in pbrt-v4. The strategy `s = k + 1` (a light subpath
hitting the pinhole) is impossible and never counted. The ratios are formed relative to
`p_s` (no products of many densities, which could overflow in float32).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

#: Heuristic names and their exponents.
HEURISTICS = {"balance": 1, "power": 2}

#: Deliberately wrong variants, for negative controls only.
#: `"unit"`: every strategy gets weight 1 (counts each path up to k + 1 times);
#: `"unnormalised_power"`: `p_s^2 / (sum_i p_i)^2`, whose weights sum to less than 1.
DEFECTIVE_WEIGHTS = ("unit", "unnormalised_power")


def mis_weight(
    p_light: Sequence[Any],
    p_camera: Sequence[Any],
    delta: Sequence[Any],
    k: Any,
    s: Any,
    heuristic: str,
) -> Any:
    """The weight `w_s` per lane.

    Arguments:
        p_light, p_camera, delta: per path index `j = 0 .. M-1` (Python lists), `pL_j`,
            `pE_j` and whether `x_j` is a delta vertex, for each lane.
        k, s: the lane's number of segments and light vertices (`mi.Int32`).
        heuristic: a key of `HEURISTICS` or of `DEFECTIVE_WEIGHTS`.
    """
    import drjit as dr
    import mitsuba as mi

    if heuristic == "unit":
        return mi.Float(1.0)
    power = HEURISTICS.get(heuristic, 1)
    m = len(p_light)
    up, down = [], []
    for j in range(m):
        ok = (p_camera[j] > 0) & (p_light[j] > 0)
        up.append(dr.select(p_camera[j] > 0, p_light[j] / dr.select(ok, p_camera[j], 1.0), 0.0))
        down.append(dr.select(p_light[j] > 0, p_camera[j] / dr.select(ok, p_light[j], 1.0), 0.0))
    total = mi.Float(0.0)
    for i in range(m + 1):
        ratio = mi.Float(1.0)
        for j in range(m):
            ratio = dr.select((s <= j) & (j < i), ratio * up[j], ratio)
            ratio = dr.select((i <= j) & (j < s), ratio * down[j], ratio)
        possible = i <= k
        if i >= 1:
            possible &= ~delta[i - 1]
        if i < m:
            possible &= ~(delta[i] & (i < k))
        total += dr.select(possible, ratio if power == 1 else dr.square(ratio), 0.0)
    if heuristic == "unnormalised_power":
        return dr.select(total > 0, dr.rcp(dr.square(total)), 0.0)
    ok = dr.isfinite(total) & (total > 0)
    return dr.select(ok, dr.rcp(dr.select(ok, total, 1.0)), 0.0)
