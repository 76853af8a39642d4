"""`restore.sample` compiles the start states and the run loop while its pilot runs, each once."""

import logging
import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._ahead import compile_ahead, wait, wait_lowered
from restore.local import RandomWalk
from restore.regeneration import Gaussian


@pytest.fixture
def compilations(caplog):
    """The names of the programs XLA compiles inside the block, from every thread."""
    jax.config.update("jax_log_compiles", True)
    caplog.set_level(logging.WARNING)

    def names() -> list[str]:
        found = [r.getMessage() for r in caplog.records if "Finished XLA compilation of" in r.getMessage()]
        caplog.clear()
        return [m.split("compilation of ")[1].split(" in ")[0] for m in found]

    try:
        yield names
    finally:
        jax.config.update("jax_log_compiles", False)


def fresh_sampler(scale: float = 1.0):
    """A sampler with a log density of its own, so that no program of it is compiled yet."""

    def logdensity(x):
        return -0.5 * jnp.sum(x**2) / scale

    return restore.JumpRestore(logdensity, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), tour_length=2.0)


def run(sampler, seed: int):
    return restore.sample(sampler, jax.random.key(seed), num_lanes=16, num_steps=60, progress=False)


def test_each_program_compiles_once_and_a_repeated_call_compiles_none(compilations):
    sampler = fresh_sampler()
    first = run(sampler, 0)
    names = compilations()
    assert names.count("jit(advance)") == 1 and names.count("jit(_init)") == 1, names
    second = run(sampler, 1)
    assert not [n for n in compilations() if n in ("jit(advance)", "jit(_init)", "jit(_pilot_terms)")]
    assert first.sums.num_tours.sum() > 0 and second.sums.num_tours.sum() > 0


def test_a_stand_in_of_another_structure_only_costs_a_second_compilation(compilations, monkeypatch):
    """Negative control: a stand-in that does not match the calibrated sampler (its rate in
    float32) compiles a loop that the call cannot use, so the call compiles its own; the
    results are those of a run without compiling ahead."""
    sampler = fresh_sampler(2.0)
    monkeypatch.setattr(restore._run, "calibrated_like", _float32_rate)
    ahead_of_the_wrong_program = run(sampler, 3)
    assert compilations().count("jit(advance)") == 2
    monkeypatch.setenv("RESTORE_COMPILE_AHEAD", "0")
    plain = run(fresh_sampler(2.0), 3)
    np.testing.assert_array_equal(np.asarray(ahead_of_the_wrong_program.sums.sum_f), np.asarray(plain.sums.sum_f))


def _float32_rate(sampler):
    calibrated = sampler.calibrated_to(0.0)
    return eqx.tree_at(lambda s: s.log_rate, calibrated, calibrated.log_rate.astype(jnp.float32))


class _Program:
    """A stand-in for a jitted function: records when it is lowered and compiled; its
    lowering waits for `release` (or raises, `broken`)."""

    def __init__(self, name: str, events: list, release: threading.Event | None = None, broken: bool = False):
        self.name, self.events, self.release, self.broken = name, events, release, broken

    def lower(self, *args):
        if self.release is not None:
            assert self.release.wait(10)
        if self.broken:
            raise RuntimeError(f"{self.name} cannot be lowered")
        self.events.append(f"{self.name} lowered")
        return self

    def compile(self):
        self.events.append(f"{self.name} compiled")


@pytest.mark.parametrize("broken", [False, True], ids=["lowered", "failed"])
def test_a_compilation_after_another_is_traced_once_the_other_is_lowered(broken):
    """The start states' program is traced only after the run loop's is lowered, or has failed
    (a failure must not hold the other back); the pilot's caller waits the same way."""
    events: list[str] = []
    release = threading.Event()
    tag = f"test-after-{broken}"  # inputs of their own: not compiled ahead by this process before
    program = _Program("loop", events, release, broken)
    loop = compile_ahead(program, lambda: (), (tag, "loop"))
    init = compile_ahead(_Program("init", events), lambda: events.append("init traced") or (), (tag, "init"), after=loop)
    assert loop is not None and init is not None
    try:
        assert not init.lowered.wait(0.3) and events == []  # the loop is held in its lowering, so is the start
    finally:
        release.set()  # whatever the outcome: a held worker would hold up the tests after this one
    wait_lowered(loop)
    init.done.result(timeout=10)  # a failed lowering releases the waiting program too
    wait(loop)
    assert events.index("init traced") > (-1 if broken else events.index("loop lowered"))
    assert init.done.result() is True and loop.done.result() is (not broken)
    assert compile_ahead(program, lambda: (), (tag, "loop")) is None  # once per program and signature
