"""Does pved's PPO learn? Hopper-v5 for 1M env steps over several seeds.

Reference: CleanRL's ppo_continuous_action reaches 2383 ± 272 on Hopper at 1M steps; the
bar here is a mean final return of 2000 over 5 seeds. Settings are CleanRL's (64-64 tanh,
lr 3e-4 annealed, 10 epochs of minibatch 64 per 2048 steps, clip 0.2 with value clipping,
observation and reward normalisation), with the batch collected as 16 envs x 128 steps.
``--paper-net`` uses the paper's networks (three hidden layers of 64, ReLU) instead.

One process per seed (``--jobs`` at a time, each one torch/BLAS thread); each seed is a
pved run directory (metrics.jsonl, TensorBoard, checkpoints: an interrupted benchmark
resumes, a finished seed is skipped). "Final return" is the mean return of the training
episodes (stochastic policy) that ended in the last 10 updates, as CleanRL reports; the
final policy's deterministic return over 20 episodes is reported beside it.

    .venv/bin/python benchmarks/ppo_learning.py --seeds 0 1 2 3 4 --steps 1000000 --jobs 2
    .venv/bin/python benchmarks/ppo_learning.py --seeds 0 --steps 20000      # smoke test
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from pved.rl.ppo import PPOConfig  # noqa: E402

TARGET_RETURN = 2000.0
FINAL_WINDOW_UPDATES = 10


def hopper_learning_config(total_steps: int, seed: int, paper_net: bool = False) -> PPOConfig:
    """CleanRL's MuJoCo PPO settings, collected as 16 envs x 128 steps."""
    return PPOConfig(
        total_steps=total_steps,
        num_envs=16,
        steps_per_env=128,
        epochs=10,
        minibatch_size=64,
        lr=3e-4,
        anneal_lr=True,
        gamma=0.99,
        gae_lambda=0.95,
        clip=0.2,
        clip_value=0.2,
        ent_coef=0.0,
        vf_coef=0.5,
        max_grad_norm=0.5,
        hidden_sizes=(64, 64, 64) if paper_net else (64, 64),
        activation="relu" if paper_net else "tanh",
        normalize_obs=True,
        normalize_reward=True,
        seed=seed,
        checkpoint_every=100_000,
        eval_every=100_000,
    )


def run_seed(seed: int, steps: int, out: Path, paper_net: bool) -> dict[str, Any]:
    """Train one seed in this process; returns (and writes) its result."""
    import torch

    from pved.envs.hopper_v5 import HopperV5Batch
    from pved.rl.evaluate import evaluate_policy
    from pved.rl.policy import Policy
    from pved.rl.ppo import train_ppo
    from pved.runs import Run

    torch.set_num_threads(1)
    config = hopper_learning_config(steps, seed, paper_net)
    run = Run(out / f"seed{seed}", {"benchmark": "ppo_learning", "env": "Hopper-v5", "ppo": config})
    if run.is_done():
        return run.read_result()
    eval_env = HopperV5Batch(10)

    def eval_fn(policy: Policy, env_steps: int) -> dict[str, float]:
        return evaluate_policy(policy, eval_env, episodes=10, seed=10_000 + seed)

    t0 = time.perf_counter()
    policy = train_ppo(HopperV5Batch(config.num_envs), config, run, eval_fn=eval_fn, progress=False)
    wall = time.perf_counter() - t0
    final_eval = evaluate_policy(policy, HopperV5Batch(10), episodes=20, seed=20_000 + seed)

    records = run.read_metrics()
    train = [r for r in records if r.get("episode/return_mean") is not None]
    window = train[-FINAL_WINDOW_UPDATES:]
    weights = np.array([r["episode/count"] for r in window], dtype=np.float64)
    rets = np.array([r["episode/return_mean"] for r in window], dtype=np.float64)
    final_train = float((weights * rets).sum() / weights.sum()) if window else float("nan")
    curve = [
        (r["step"], r["eval/return_mean"]) for r in records if r.get("eval/return_mean") is not None
    ]
    steps_per_s = [r["time/steps_per_s_mean"] for r in records if "time/steps_per_s_mean" in r]
    result = {
        "seed": seed,
        "env_steps": int(policy.metadata["training_steps"]),
        "final_train_return": final_train,
        "final_eval_return_mean": final_eval["return_mean"],
        "final_eval_return_std": final_eval["return_std"],
        "eval_curve": curve,
        "wall_s_this_process": wall,
        "train_steps_per_s": steps_per_s[-1] if steps_per_s else float("nan"),
        "paper_net": paper_net,
    }
    return run.finish(result)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--jobs", type=int, default=1, help="seeds trained at the same time")
    parser.add_argument("--out", type=Path, default=Path("runs/benchmarks/ppo_learning"))
    parser.add_argument(
        "--json", type=Path, default=None, help="summary file (default OUT/summary.json)"
    )
    parser.add_argument("--paper-net", action="store_true", help="64-64-64 ReLU networks")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    out = args.out / ("paper_net" if args.paper_net else "cleanrl_net") / f"steps{args.steps}"

    if args.worker:
        (seed,) = args.seeds
        result = run_seed(seed, args.steps, out, args.paper_net)
        print(json.dumps({k: v for k, v in result.items() if k != "eval_curve"}), flush=True)
        return

    t0 = time.perf_counter()
    pending = list(args.seeds)
    running: list[tuple[int, subprocess.Popen[bytes]]] = []
    failed: list[int] = []
    while pending or running:
        while pending and len(running) < max(1, args.jobs):
            seed = pending.pop(0)
            cmd = [
                sys.executable,
                __file__,
                "--worker",
                "--seeds",
                str(seed),
                "--steps",
                str(args.steps),
                "--out",
                str(args.out),
            ]
            if args.paper_net:
                cmd.append("--paper-net")
            print(f"[seed {seed}] started", flush=True)
            running.append((seed, subprocess.Popen(cmd)))
        time.sleep(0.5)
        for seed, proc in list(running):
            if proc.poll() is not None:
                running.remove((seed, proc))
                if proc.returncode != 0:
                    failed.append(seed)
                    print(f"[seed {seed}] FAILED (exit {proc.returncode})", flush=True)
    wall = time.perf_counter() - t0

    results = []
    for seed in args.seeds:
        path = out / f"seed{seed}" / "result.json"
        if path.exists():
            results.append(json.loads(path.read_text()))
    finals = np.array([r["final_train_return"] for r in results])
    evals = np.array([r["final_eval_return_mean"] for r in results])
    summary = {
        "env": "Hopper-v5",
        "steps": args.steps,
        "seeds": [r["seed"] for r in results],
        "failed_seeds": failed,
        "final_train_return_mean": float(finals.mean()) if len(finals) else None,
        "final_train_return_std": float(finals.std()) if len(finals) else None,
        "final_eval_return_mean": float(evals.mean()) if len(evals) else None,
        "target": TARGET_RETURN,
        "passed": bool(len(finals) and finals.mean() >= TARGET_RETURN),
        "wall_s": wall,
        "jobs": args.jobs,
        "per_seed": results,
    }
    json_path = args.json or out / "summary.json"
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(summary, indent=2) + "\n")
    for r in results:
        print(
            f"seed {r['seed']}: final train return {r['final_train_return']:8.1f}   "
            f"deterministic eval {r['final_eval_return_mean']:8.1f}   "
            f"{r['train_steps_per_s']:6.0f} steps/s"
        )
    if len(finals):
        print(
            f"mean final return {finals.mean():.1f} ± {finals.std():.1f} over {len(finals)} seeds "
            f"(target {TARGET_RETURN:.0f}: {'PASS' if summary['passed'] else 'FAIL'}); "
            f"wall {wall:.0f} s; summary {json_path}"
        )
    if failed:
        sys.exit(1)


if __name__ == "__main__":
    main()
