"""How the protocol's runner scales with cores: the same grid of transfer runs on 1 worker
and on all cores, in one invocation; the last line is the speed-up.

The grid is what the protocol runs most: plain-PPO transfer runs of the Reacher pair
(``pved.experiments.stages.transfer``), one per seed, each ``--steps`` env steps, all
through :func:`pved.protocol.runner.run_jobs` (Ray, or ``--backend processes`` where
Ray is not installed; one CPU per run). Wall times exclude the backend's start-up
(measured from the first submission); each setting writes to its own fresh directory, so
nothing is reused.

    .venv/bin/python benchmarks/protocol_scaling.py                 # runs = cores
    .venv/bin/python benchmarks/protocol_scaling.py --runs 32 --steps 100000
    .venv/bin/python benchmarks/protocol_scaling.py --backend processes
    .venv/bin/python benchmarks/protocol_scaling.py --address HEAD:6379 --runs 64

On a running Ray cluster (``--address``, the one ``pved protocol --address`` would use)
both passes run there: the first with each run waiting for the one before (one at a
time, wherever Ray places it), the second all at once on every CPU of the cluster; the
run directories go to ``--root``, which every node must see (a shared file system).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pved.experiments.stages import transfer
from pved.protocol.runner import Job, resolve_backend, run_jobs


class Grid:
    """A fixed set of transfer runs (a runner ``Planner``)."""

    def __init__(self, root: Path, runs: int, steps: int, one_at_a_time: bool = False):
        self.steps = steps
        self.jobs = [
            Job(
                key=f"ppo/seed{seed}",
                fn=transfer,
                kwargs={
                    "pair": "reacher",
                    "method": "ppo",
                    "seed": seed,
                    "steps": steps,
                    "eval_every": steps,  # curves are not the point here
                    "eval_episodes": 16,
                    "final_eval_episodes": 16,
                    "runs_root": root,
                    "progress": False,
                },
                steps=steps,
                # each run after the one before: one worker's pass on a whole cluster
                deps=(f"ppo/seed{seed - 1}",) if one_at_a_time and seed > 0 else (),
            )
            for seed in range(runs)
        ]

    def expand(self, results: Mapping[str, Any]) -> list[Job]:
        return self.jobs

    def expected_steps(self) -> int:
        return self.steps * len(self.jobs)


def main() -> None:
    cores = os.cpu_count() or 1
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=cores, help="runs in the grid")
    parser.add_argument("--steps", type=int, default=50_000, help="env steps per run")
    parser.add_argument("--workers", type=int, default=cores, help="the parallel setting")
    parser.add_argument("--backend", default="auto", help="auto | ray | processes")
    parser.add_argument("--address", help="a running Ray cluster: measure it instead")
    parser.add_argument(
        "--root", type=Path, help="where the runs go (default: a temporary directory)"
    )
    args = parser.parse_args()
    backend = resolve_backend(args.backend, args.address)
    if args.address:
        import ray

        ray.init(address=args.address, log_to_driver=False)
        cores = int(ray.cluster_resources().get("CPU", 1))
        ray.shutdown()
        args.workers = cores

    walls: dict[int, float] = {}
    for workers in (1, args.workers):
        with tempfile.TemporaryDirectory(prefix="pved-scaling-", dir=args.root) as tmp:
            serial = bool(args.address) and workers == 1
            grid = Grid(Path(tmp), args.runs, args.steps, one_at_a_time=serial)
            report = run_jobs(
                grid,
                workers=None if args.address else workers,
                address=args.address,
                live=False,
                backend=backend,
            )
            if report.failed:
                raise SystemExit(f"runs failed at {workers} workers: {report.failed}")
            walls[workers] = report.wall_s
            rate = args.runs * args.steps / report.wall_s
            print(
                f"workers {workers:>3}: {args.runs} runs x {args.steps:,} steps in "
                f"{report.wall_s:7.1f} s ({rate:,.0f} env steps/s)",
                flush=True,
            )
    speedup = walls[1] / walls[args.workers]
    print(f"cores {cores}; backend {backend}; ideal speed-up {min(args.workers, args.runs)}")
    print(f"speed-up {args.workers} workers / 1 worker: {speedup:.2f}")


if __name__ == "__main__":
    main()
