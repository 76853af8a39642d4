"""`restore.autosample` against BlackJAX adaptive tempered SMC, side by side in one process.

On the evidence problems `manywell32` (32-d Many Well, 2^16 modes) and `gmm40` (2-d, 40
separated Gaussians), each with its exact `log Z` and the box a user would state, it runs

- BlackJAX adaptive tempered SMC with HMC moves, 4,096 particles, from the uniform prior
  on the box (`restore.bench.TemperedSMCRunner`, as the evidence benchmark runs it);
- `restore.autosample(problem.logdensity, key, box=problem.box)` with its defaults (1,024
  lanes, 1,000 steps) and the problem's observables, as the evidence benchmark runs it;

each twice: the process's first call (compilation included) and a second call with another
key (its programs compiled already). SMC runs first, so the process's one-time start-up is
charged to it. It prints the wall time of each call, the compile time inside it, the
`log Z` error against the exact value, autosample's standard error, `|error| / SE` and
whether the estimate is marked reliable, and the ratio of wall times autosample / SMC.

Then, per autosample call, where the time went: each part (the seeding chains, the mode search, every
choice of a regeneration, every `restore.sample` run) with its wall time, the programs XLA
compiled in it (from JAX's compile events) and their compile time, and the stages'
reports.

Each problem runs in a fresh process of its own (so that its first call is a fresh
process's first call), with float64 on, as in the evidence benchmark. JAX's persistent
compilation cache is left off.

Usage: python examples/benchmark_autosample.py [--problems manywell32,gmm40] [--seed 0] [--particles 4096]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
import warnings
from contextlib import contextmanager

import jax

jax.config.update("jax_enable_x64", True)

import jax.monitoring as monitoring  # noqa: E402

import restore  # noqa: E402
import restore._autosample as autosample_module  # noqa: E402
from restore.bench import TemperedSMCRunner, get_evidence_problem  # noqa: E402
from restore.bench._timing import Stopwatch  # noqa: E402

_BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"


class Profile:
    """Where an autosample call's time went: timed parts (wrapped functions of `restore._autosample`)
    and the XLA compilations inside each (JAX's backend-compile events, by the time they ended)."""

    PARTS = ("seed_draws", "laplace_candidates", "choose_regeneration", "refit_regeneration", "sample")

    def __init__(self) -> None:
        self.parts: list[tuple[str, float, float]] = []  # (name, start, end), perf_counter
        self.compiles: list[tuple[str, float, float]] = []  # (program, end, seconds)

    def _listen(self, event: str, duration: float, **kwargs) -> None:
        if event == _BACKEND_COMPILE:
            self.compiles.append((str(kwargs.get("fun_name")), time.perf_counter(), float(duration)))

    @contextmanager
    def recording(self):
        originals = {name: getattr(autosample_module, name) for name in self.PARTS if hasattr(autosample_module, name)}

        def timed(name, fn):
            def wrapper(*args, **kwargs):
                start = time.perf_counter()
                try:
                    return fn(*args, **kwargs)
                finally:
                    self.parts.append((name, start, time.perf_counter()))

            return wrapper

        for name, fn in originals.items():
            setattr(autosample_module, name, timed(name, fn))
        monitoring.register_event_duration_secs_listener(self._listen)
        self.start = time.perf_counter()
        try:
            yield self
        finally:
            self.end = time.perf_counter()
            monitoring.unregister_event_duration_listener(self._listen)
            for name, fn in originals.items():
                setattr(autosample_module, name, fn)

    def rows(self) -> list[dict]:
        """One row per timed part in order, and one for the time outside them ("other")."""
        rows, used = [], set()
        for name, start, end in sorted(self.parts, key=lambda p: p[1]):
            inside = [i for i, (_, t, _) in enumerate(self.compiles) if start <= t <= end and i not in used]
            used.update(inside)
            programs = [self.compiles[i] for i in inside]
            rows.append(dict(part=name, wall=end - start, compiles=len(programs), compile_time=sum(c[2] for c in programs),
                             programs=_by_program(programs)))
        rest = [c for i, c in enumerate(self.compiles) if i not in used]
        covered = sum(end - start for _, start, end in self.parts)
        rows.append(dict(part="other", wall=self.end - self.start - covered, compiles=len(rest), compile_time=sum(c[2] for c in rest),
                         programs=_by_program(rest)))
        return rows


def _by_program(compiles: list[tuple[str, float, float]]) -> dict[str, list[float]]:
    """Compile times by program name."""
    out: dict[str, list[float]] = {}
    for name, _, seconds in compiles:
        out.setdefault(name.removeprefix("jit(").removesuffix(")"), []).append(seconds)
    return out


def run_autosample(problem, key) -> dict:
    lower, upper = problem.box
    profile = Profile()
    with warnings.catch_warnings(record=True) as caught, Stopwatch() as clock, profile.recording():
        warnings.simplefilter("always")
        result = restore.autosample(
            problem.logdensity, key, box=(lower, upper), observables=problem.observables, progress=False
        )
    log_z = result.normalising_constant()
    error = float(log_z.value) - problem.log_normalising_constant
    return dict(
        wall=clock.wall, compile=clock.compile, error=error, se=float(log_z.standard_error), k_hat=float(log_z.k_hat),
        reliable=bool(log_z.reliable), evaluations=int(result.evaluations), healthy=bool(result.healthy),
        stages=[s._asdict() for s in result.stages], profile=profile.rows(),
        warnings=sorted({str(w.message).split(";")[0][:100] for w in caught}),
    )


def run_smc(runner, problem, key) -> dict:
    out = runner.run(problem, key)
    return dict(wall=out.wall_time, compile=out.compile_time, error=out.log_z - problem.log_normalising_constant, status=out.status,
                evaluations=out.evaluations, notes=out.notes)


def one_problem(name: str, seed: int, particles: int) -> dict:
    """Both methods on one problem, each called twice (first call, then a second with another key)."""
    problem = get_evidence_problem(name)
    jax.block_until_ready(jax.numpy.zeros(()) + 1)  # start the backend before any timing
    runner = TemperedSMCRunner(particles=particles)
    calls = []
    for call in range(2):
        key = jax.random.key(1000 * seed + call)
        smc = run_smc(runner, problem, key)
        auto = run_autosample(problem, key)
        calls.append(dict(smc=smc, autosample=auto))
    return dict(problem=name, dim=problem.dim, log_z=problem.log_normalising_constant, calls=calls)


def _report(out: dict) -> None:
    print(f"\n=== {out['problem']} (d = {out['dim']}, exact log Z = {out['log_z']:.6f})")
    print(f"{'call':<7} {'method':<11} {'wall (s)':>9} {'compile':>8} {'log Z error':>12} {'SE':>9} {'|err|/SE':>9} "
          f"{'k_hat':>6} {'reliable':>8} {'evals':>11} {'ratio':>7}")
    for i, call in enumerate(out["calls"]):
        label = "first" if i == 0 else "second"
        s, a = call["smc"], call["autosample"]
        print(f"{label:<7} {'smc-hmc':<11} {s['wall']:>9.2f} {s['compile']:>8.2f} {s['error']:>+12.5f} {'-':>9} {'-':>9} "
              f"{'-':>6} {'-':>8} {s['evaluations']:>11,} {'':>7}  {s['status']}; {s['notes']}")
        z = abs(a["error"]) / a["se"] if a["se"] > 0 else math.inf
        print(f"{label:<7} {'autosample':<11} {a['wall']:>9.2f} {a['compile']:>8.2f} {a['error']:>+12.5f} {a['se']:>9.5f} {z:>9.2f} "
              f"{a['k_hat']:>6.2f} {a['reliable']!s:>8} {a['evaluations']:>11,} {a['wall'] / s['wall']:>6.2f}x"
              + (f"  ({'; '.join(a['warnings'])})" if a["warnings"] else ""))
    for i, call in enumerate(out["calls"]):
        a = call["autosample"]
        print(f"\n  autosample, {'first' if i == 0 else 'second'} call: where the time went")
        print(f"  {'part':<22} {'wall (s)':>9} {'programs':>9} {'compile (s)':>12}  largest compilations")
        for row in a["profile"]:
            top = sorted(row["programs"].items(), key=lambda kv: -sum(kv[1]))[:4]
            names = ", ".join(f"{n} {sum(t):.2f}" + (f" (x{len(t)})" if len(t) > 1 else "") for n, t in top)
            print(f"  {row['part']:<22} {row['wall']:>9.2f} {row['compiles']:>9} {row['compile_time']:>12.2f}  {names}")
        print(f"  {'stage':>5} {'kind':<6} {'regeneration':<34} {'evals':>10} {'wall (s)':>9} {'k_hat(T)':>9} {'k_hat(w)':>9}  log Z")
        for st in a["stages"]:
            zs = "" if math.isnan(st["log_z"]) else f"{st['log_z']:.4f} +- {st['log_z_se']:.4f}"
            print(f"  {st['stage']:>5} {st['kind']:<6} {st['family'] + ' x' + str(st['num_components']):<34} {st['evaluations']:>10,} "
                  f"{st['wall_time']:>9.2f} {st['duration_k_hat']:>9.2f} {st['importance_k_hat']:>9.2f}  {zs}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", default="manywell32,gmm40", help="comma-separated evidence problems")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--particles", type=int, default=4096, help="tempered SMC's particles")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # run one problem here and print JSON (the child process)
    args = parser.parse_args()
    if args.one:
        print("@@" + json.dumps(one_problem(args.one, args.seed, args.particles)))
        return
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, {jax.device_count()} {jax.default_backend()} "
          f"device(s), jax {jax.__version__}, float64; restore {restore.__version__}")
    ratios = []
    for name in (p.strip() for p in args.problems.split(",") if p.strip()):
        command = [sys.executable, os.path.abspath(__file__), "--one", name, "--seed", str(args.seed), "--particles", str(args.particles)]
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        line = next((x for x in done.stdout.splitlines() if x.startswith("@@")), None)
        if done.returncode != 0 or line is None:
            print(f"\n=== {name}: failed\n{done.stderr[-3000:]}")
            continue
        out = json.loads(line[2:])
        _report(out)
        ratios += [(name, i, c["autosample"]["wall"] / c["smc"]["wall"]) for i, c in enumerate(out["calls"])]
    print("\nwall time autosample / SMC: " + ", ".join(f"{n} {'first' if i == 0 else 'second'} {r:.2f}x" for n, i, r in ratios))


if __name__ == "__main__":
    main()
