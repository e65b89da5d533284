"""PPO on ``<Agent><Task>`` with one change to the env's observations or to the preset's
PPO config: the runs behind the locomotion policies' choices in docs/decisions.md.

One run per call, the locomotion preset's PPO for policies with ``--steps`` env steps (the
learning rate anneals over them) and the ``--set`` overrides, no evaluation or
checkpoints; it prints, every ``--every`` updates, PPO's approximate KL, clip fraction,
mean action std and the rollouts' episode return and length. With or without v5's extra
observations (contact forces and, for Humanoid, cinert/cvel/qfrc_actuator; "Ant does not
observe its contact forces")::

    .venv/bin/python scripts/ppo_ablation.py --agent Ant --extra 1 --steps 600000
    .venv/bin/python scripts/ppo_ablation.py --agent Ant --extra 0 --steps 600000
    .venv/bin/python scripts/ppo_ablation.py --agent Humanoid --extra 1 --steps 400000

A PPO recipe ("Humanoid's PPO")::

    .venv/bin/python scripts/ppo_ablation.py --agent Humanoid --steps 2000000 \
        --set lr=1e-4 --set minibatch_size=512 --set init_log_std=-1 \
        --set hidden_sizes=256,256
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import pved  # noqa: E402, F401  (before numpy loads: it pins OpenBLAS's kernel)

# isort: split
import argparse  # noqa: E402
import dataclasses  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import torch  # noqa: E402

from pved.envs import make_batched  # noqa: E402
from pved.envs.locomotion import default_config  # noqa: E402
from pved.envs.registry import env_id  # noqa: E402
from pved.errors import PvedError  # noqa: E402
from pved.rl.ppo import PPOConfig, train_ppo  # noqa: E402
from pved.runs import Run  # noqa: E402
from pved.spec import preset_for_agent  # noqa: E402


def parse_override(text: str, defaults: PPOConfig) -> tuple[str, object]:
    """``field=value`` into a PPOConfig field and its value, typed like the default's."""
    name, sep, value = text.partition("=")
    if not sep or name not in {f.name for f in dataclasses.fields(PPOConfig)}:
        raise PvedError(f"--set wants <PPOConfig field>=<value>, got {text!r}")
    default = getattr(defaults, name)
    if isinstance(default, tuple):
        return name, tuple(int(v) for v in value.split(","))
    if value == "None":
        return name, None
    if isinstance(default, bool):
        return name, value.lower() in ("1", "true")
    if isinstance(default, int):
        return name, int(value)
    if isinstance(default, float) or default is None:
        return name, float(value)
    return name, value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent", default="Ant", help="Ant or Humanoid")
    parser.add_argument("--task", default="Slope")
    parser.add_argument(
        "--extra", type=int, choices=(0, 1), help="v5's extra observations (default: the env's)"
    )
    parser.add_argument(
        "--set", action="append", default=[], help="PPOConfig field=value (tuples: 256,256)"
    )
    parser.add_argument("--steps", type=int, default=600_000)
    parser.add_argument("--every", type=int, default=20, help="updates between lines")
    parser.add_argument("--out", type=Path, help="run directory (default: a temporary one)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    never = 10**12
    base = preset_for_agent(args.agent).policy_config(args.agent, args.task)
    overrides: dict[str, Any] = dict(parse_override(text, base) for text in args.set)
    ppo = dataclasses.replace(
        base, **overrides, total_steps=args.steps, eval_every=never, checkpoint_every=never
    )
    config = default_config(args.agent)
    if args.extra is not None:
        config = dataclasses.replace(config, extra_observations=bool(args.extra))
    env = make_batched(env_id(args.agent, args.task), ppo.num_envs, config=config)
    obs_dim = env.single_observation_space.shape[0]
    print(f"{args.agent}{args.task} extra_observations={config.extra_observations}: obs dim "
          f"{obs_dim}; overrides {overrides}", flush=True)  # fmt: skip
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
