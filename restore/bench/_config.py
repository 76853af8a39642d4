"""Suite configurations (tiny, quick, full) and the roster of runners each one builds per problem."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from ._blackjax_runner import BlackJAXRunner
from ._emcee_runner import EmceeRunner
from ._exact_runner import ExactRunner
from ._problems import PROBLEMS, Problem
from ._restore_runners import KERNELS, JumpRestoreRunner, MixtureMHRunner
from ._runner import Runner


@dataclass(frozen=True)
class SuiteConfig:
    """What a suite run covers and how big its budgets are.

    The full budget is `lanes * steps` target evaluations (jump Restore with a
    random walk: `lanes` lanes of `steps` steps); `fractions` of it give the points of
    the error-versus-time curves. Every other sampler gets the evaluations and the wall
    time jump Restore actually used in the same seed. `walkers` lists emcee ensemble
    sizes; 0 stands for the smallest sensible one, `max(2 d, 8)`; sizes below `2 d` are
    skipped. BlackJAX RMH runs `lanes` chains, NUTS `nuts_chains` chains (each adapts
    for `nuts_warmup` steps, counted in its budget). `samplers`, when given, keeps only
    runners whose names start with one of its entries (the jump-Restore runners they are
    matched to are always kept). `kernel_problems`, when given, limits the MALA and HMC
    runners (jump Restore and MH) to those problems; elsewhere only the random walk runs.
    """

    name: str
    problems: tuple[str, ...]
    seeds: int = 2
    lanes: int = 128
    steps: int = 600
    fractions: tuple[float, ...] = (0.25, 0.5, 1.0)
    kernels: tuple[str, ...] = ("rw",)
    kernel_problems: tuple[str, ...] | None = None
    mh_factors: tuple[float, ...] = (1.0,)
    chains: bool = False
    emcee_moves: tuple[str, ...] = ("stretch",)
    walkers: tuple[int, ...] = (0, 64)
    blackjax: tuple[str, ...] = ()
    exact: bool = True
    samplers: tuple[str, ...] | None = None
    max_points: int = 1000
    pilot_size: int = 4096
    nuts_chains: int = 16
    nuts_warmup: int = 100
    base_seed: int = 0

    def __post_init__(self):
        for name in self.problems:
            if name not in PROBLEMS:
                raise ValueError(f"unknown problem {name!r}; choose from {sorted(PROBLEMS)}")
        if not self.problems:
            raise ValueError("choose at least one problem")
        if self.seeds < 1 or self.lanes < 2 or self.steps < 10:
            raise ValueError(f"need seeds >= 1, lanes >= 2 and steps >= 10; got {self.seeds}, {self.lanes}, {self.steps}")
        if not self.fractions or any(not 0 < f <= 1 for f in self.fractions) or max(self.fractions) != 1.0:
            raise ValueError(f"fractions must lie in (0, 1] and include 1, got {self.fractions}")
        bad = [k for k in self.kernels if k not in KERNELS]
        if bad or "rw" not in self.kernels:
            raise ValueError(f"kernels must be among {KERNELS} and include 'rw', got {self.kernels}")

    @property
    def full_evaluations(self) -> int:
        return self.lanes * self.steps

    def replace(self, **changes) -> SuiteConfig:
        return dataclasses.replace(self, **changes)

    @classmethod
    def tiny(cls) -> SuiteConfig:
        """Smaller than quick: for the smoke test (one problem, three samplers, tiny budgets)."""
        return cls("tiny", ("gmm2",), seeds=1, lanes=32, steps=160, fractions=(0.5, 1.0), walkers=(8,), max_points=300, pilot_size=512)

    @classmethod
    def quick(cls) -> SuiteConfig:
        """A few minutes on 2 cores: 2-d and 10-d mixtures, jump Restore RW, MH RW and emcee stretch."""
        return cls("quick", ("gmm2", "gmm10"))

    @classmethod
    def full(cls) -> SuiteConfig:
        """Every problem and sampler: three kernels, the MH sweep, emcee (two move sets), BlackJAX."""
        return cls(
            "full", tuple(PROBLEMS), seeds=3, lanes=256, steps=1500, kernels=KERNELS, mh_factors=(0.5, 1.0, 2.0),
            chains=True, emcee_moves=("stretch", "de"), walkers=(0, 64, 256), blackjax=("rmh", "nuts"), max_points=2000,
        )

    @classmethod
    def medium(cls) -> SuiteConfig:
        """Every problem and sampler family at `quick`'s budgets, 2 seeds: about 20-25 minutes on 2 cores.

        Cut from `full` to save compilations and slow runs: MALA and HMC only on the 10-d
        mixture and the funnel, emcee with the smallest and the largest ensemble only.
        """
        return cls.full().replace(
            name="medium", seeds=2, lanes=128, steps=600, max_points=1000, kernel_problems=("gmm10", "funnel5"), walkers=(0, 256)
        )

    def runners(self, problem: Problem) -> list[Runner]:
        """The runners of this configuration that apply to `problem`, jump Restore first."""
        span = min(self.fractions) * self.full_evaluations
        common: dict[str, Any] = dict(lanes=self.lanes, span_evaluations=span)
        kernels = self.kernels if self.kernel_problems is None or problem.name in self.kernel_problems else ("rw",)
        out: list[Runner] = [JumpRestoreRunner(k, pilot_size=self.pilot_size, **common) for k in kernels]
        out += [MixtureMHRunner(k, factor=1.0, **common) for k in kernels]
        out += [MixtureMHRunner("rw", factor=f, **common) for f in self.mh_factors if f != 1.0]
        if self.chains:
            out.append(MixtureMHRunner("rw", factor=0.0, **common))
        sizes = sorted({max(2 * problem.dim, 8) if w == 0 else int(w) for w in self.walkers})
        out += [EmceeRunner(m, w + w % 2) for m in self.emcee_moves for w in sizes]
        out += [BlackJAXRunner(a, self.lanes if a == "rmh" else self.nuts_chains, warmup_steps=self.nuts_warmup) for a in self.blackjax]
        if self.exact:
            out.append(ExactRunner())
        out = [r for r in out if r.supports(problem)]
        if self.samplers is not None:
            keep = {r.name for r in out if any(r.name.startswith(s) for s in self.samplers)}
            keep |= {r.matches for r in out if r.name in keep and r.matches}
            out = [r for r in out if r.name in keep]
        return out
