"""PPO on ``<Agent>Slope`` with and without v5's extra observations (contact forces and,
for Humanoid, cinert/cvel/qfrc_actuator): the comparison behind Ant's default in
docs/decisions.md ("Ant does not observe its contact forces").

One run per call, the locomotion preset's PPO for policies with ``--steps`` env steps (the
learning rate anneals over them), no evaluation or checkpoints; it prints, every
``--every`` updates, PPO's approximate KL, clip fraction, mean action std and the
rollouts' episode return and length::

    .venv/bin/python scripts/extra_obs_ablation.py --agent Ant --extra 1 --steps 600000
    .venv/bin/python scripts/extra_obs_ablation.py --agent Ant --extra 0 --steps 600000
    .venv/bin/python scripts/extra_obs_ablation.py --agent Humanoid --extra 1 --steps 400000
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import torch  # noqa: E402

from pved.config import preset_for_agent  # noqa: E402
from pved.envs import make_batched  # noqa: E402
from pved.envs.locomotion import default_config  # noqa: E402
from pved.envs.registry import env_id  # noqa: E402
from pved.rl.ppo import train_ppo  # noqa: E402
from pved.runs import Run  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent", default="Ant", help="Ant or Humanoid")
    parser.add_argument("--extra", type=int, choices=(0, 1), required=True)
    parser.add_argument("--steps", type=int, default=600_000)
    parser.add_argument("--every", type=int, default=20, help="updates between lines")
    parser.add_argument("--out", type=Path, help="run directory (default: a temporary one)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    never = 10**12
    ppo = dataclasses.replace(
        preset_for_agent(args.agent).policy_config(args.agent, "Slope"),
        total_steps=args.steps,
        eval_every=never,
        checkpoint_every=never,
    )
    config = dataclasses.replace(default_config(args.agent), extra_observations=bool(args.extra))
    env = make_batched(env_id(args.agent, "Slope"), ppo.num_envs, config=config)
    print(f"{args.agent} extra_observations={bool(args.extra)}: obs dim "
          f"{env.single_observation_space.shape[0]}", flush=True)  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="pved-ablation-") as tmp:
        run = Run(args.out or Path(tmp), {"agent": args.agent, "extra": args.extra, "ppo": ppo})
        train_ppo(env, ppo, run, progress=False)
        updates = [r for r in run.read_metrics() if "loss/approx_kl" in r]
        for r in updates[:: args.every]:
            print(
                f"step {r['step']:>9,}  kl {r['loss/approx_kl']:.3f}  "
                f"clip {r['loss/clip_fraction']:.2f}  std {r['loss/std_mean']:.2f}  "
                f"return {r.get('episode/return_mean') or float('nan'):8.1f}  "
                f"length {r.get('episode/length_mean') or float('nan'):6.0f}"
            )


if __name__ == "__main__":
    main()
