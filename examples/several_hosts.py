"""One Restore run split over several processes (hosts) with `jax.distributed`.

Every process runs this same script; the lanes are split over the devices of all the
processes (`devices="all"`) and every process receives the full result. Process 0 prints
it (and writes the checkpoint, if one is given).

On one machine, two processes with two CPU devices each (CPU collectives through gloo):

    export XLA_FLAGS=--xla_force_host_platform_device_count=2 JAX_PLATFORMS=cpu
    python examples/several_hosts.py --coordinator 127.0.0.1:12345 --num-processes 2 --process-id 0 &
    python examples/several_hosts.py --coordinator 127.0.0.1:12345 --num-processes 2 --process-id 1

On a Slurm cluster (one process per node; `jax.distributed.initialize()` reads the
coordinator, the process count and the process index from Slurm's variables):

    srun --nodes=2 --ntasks-per-node=1 python examples/several_hosts.py

Compare with one process: `python examples/several_hosts.py --one-process` prints the
same numbers.
"""

from __future__ import annotations

import argparse

import jax


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coordinator", help="host:port of process 0 (found by JAX on Slurm, Open MPI, TPU pods)")
    parser.add_argument("--num-processes", type=int)
    parser.add_argument("--process-id", type=int)
    parser.add_argument("--one-process", action="store_true", help="no jax.distributed: the reference run")
    parser.add_argument("--num-lanes", type=int, default=256, help="divisible by the number of devices")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--checkpoint", help="checkpoint file, on a file system every process sees")
    args = parser.parse_args()

    jax.config.update("jax_enable_x64", True)
    if not args.one_process:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU devices only; GPUs use NCCL
        jax.distributed.initialize(
            coordinator_address=args.coordinator, num_processes=args.num_processes, process_id=args.process_id
        )

    import jax.numpy as jnp

    import restore

    sampler = restore.JumpRestore(
        lambda x: -0.5 * jnp.sum(x**2),
        restore.local.RandomWalk(1.0),
        restore.regeneration.Gaussian(jnp.zeros(2), 2.0),
        log_rate=0.0,
    )
    result = restore.sample(
        sampler,
        jax.random.key(0),  # the same key in every process
        num_lanes=args.num_lanes,
        num_steps=args.steps,
        devices=None if args.one_process else "all",
        checkpoint=args.checkpoint,
        progress=jax.process_index() == 0,
    )
    if jax.process_index() == 0:
        print(f"{jax.process_count()} process(es), {jax.device_count()} device(s), {args.num_lanes} lanes")
        print(result.summary())
        print("E[x]   =", result.estimate("x"))
        print("log Z  =", result.normalising_constant(), "(truth log 2 pi = 1.8379)")


if __name__ == "__main__":
    main()
