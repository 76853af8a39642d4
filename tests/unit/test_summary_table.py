"""The table of estimates in `summary()`: one row per component, the numbers of `estimate` and `ess`."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._estimates_table import component_names, estimates_table
from restore.local import RandomWalk
from restore.regeneration import Gaussian


def std_normal(x):
    return -0.5 * jnp.sum(x**2)


def _rows(text: str) -> dict[str, list[str]]:
    """The table's rows by their first cell, from the header line (`mean se ess k_hat reliable`) on."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split() == ["mean", "se", "ess", "k_hat", "reliable"])
    rows = {}
    for line in lines[start + 1 :]:
        if not line.startswith("    "):
            break
        cells = line.split()
        rows[cells[0]] = cells[1:]
    return rows


@pytest.fixture(scope="module")
def run():
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(3), 2.0), log_rate=0.0)
    observables = {"m": lambda x: jnp.stack([x, x**2]), "r": lambda x: jnp.sum(x**2)}
    return restore.sample(
        sampler, jax.random.key(0), num_lanes=64, num_steps=300, progress=False, observables=observables
    )


def test_one_row_per_component_with_the_estimates_numbers(run):
    rows = _rows(run.summary())
    # The position was only added to the user's observables: it gets no rows.
    assert list(rows) == ["m[0,0]", "m[0,1]", "m[0,2]", "m[1,0]", "m[1,1]", "m[1,2]", "r"]
    for row, name, index in (("m[1,2]", "m", (1, 2)), ("r", "r", ())):
        est, ess = run.estimate(name), run.ess(name)
        mean, se, ess_cell, k_hat, reliable = rows[row]
        places = len(se.split(".")[1])
        assert float(mean) == pytest.approx(float(est.value[index]), abs=0.51 * 10**-places)
        assert float(se) == pytest.approx(float(est.standard_error[index]), abs=0.51 * 10**-places)
        assert float(ess_cell.replace(",", "")) == pytest.approx(float(ess[index]), abs=0.51)
        assert float(k_hat) == pytest.approx(float(est.k_hat[index]), abs=0.0051)
        assert reliable == ("yes" if est.reliable[index] else "NO")


def test_default_observables_and_names():
    assert component_names("mu", ()) == ["mu"]
    assert component_names("alpha", (3,)) == ["alpha[0]", "alpha[1]", "alpha[2]"]
    assert component_names("w", (2, 2)) == ["w[0,0]", "w[0,1]", "w[1,0]", "w[1,1]"]
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
    result = restore.sample(sampler, jax.random.key(1), num_lanes=16, num_steps=200, progress=False)
    assert list(_rows(result.summary())) == ["x[0]", "x[1]", "x**2[0]", "x**2[1]"]


def test_wide_observables_are_summed_up_past_max_rows(run):
    rows = _rows("\n".join(estimates_table(run.observables, run.estimate, run.ess, "tours", max_rows=2)))
    assert list(rows)[:3] == ["m[0,0]", "m[0,1]", "..."] and "r" in rows
    ess = run.ess("m").reshape(-1)[2:]
    assert rows["..."][:2] == ["4", "more"] and f">={np.min(ess):,.0f}" in rows["..."]


def test_unreliable_rows_say_so_without_warning_again():
    # A regeneration far narrower than the target: a few long tours in the tails dominate.
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(3), 0.3), log_rate=3.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = restore.sample(sampler, jax.random.key(0), num_lanes=16, num_steps=100, progress=False)
        reliable = result.estimate("x").reliable
    assert not np.all(reliable)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the table replaces the estimates' warnings
        text = "\n".join(estimates_table(result.observables, result.estimate, result.ess, "tours"))
    rows = _rows(text)
    assert [rows[f"x[{i}]"][-1] for i in range(3)] == ["yes" if ok else "NO" for ok in reliable]
    assert "UNRELIABLE x:" in text and "tail shape k_hat" in text


def test_mh_runs_are_tabled_over_lanes():
    mh = restore.MixtureMH(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), 0.1)
    result = restore.sample(mh, jax.random.key(2), num_lanes=64, num_steps=300, progress=False)
    text = result.summary()
    assert "estimates (lanes" in text
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # 64 lanes are too few to check the tail: the row says so
        est = result.estimate("x", method="lanes")
    mean, se = _rows(text)["x[1]"][:2]
    assert float(mean) == pytest.approx(float(est.value[1]), abs=0.51 * 10 ** -len(se.split(".")[1]))
