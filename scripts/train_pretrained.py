"""Reproduce the policies shipped in ``src/pved/pretrained/`` (used by ``make demo``).

Each one is an ordinary ``pved train-policy`` run; this script runs it, evaluates the
result on 500 fresh episodes, and copies the policy file into the package beside a
``.json`` saying how it was made and how well it does:

    .venv/bin/python scripts/train_pretrained.py                    # the Reacher pair's three
    .venv/bin/python scripts/train_pretrained.py --only Jaco:Reach Fetch4:Reach

The equivalent commands by hand (then ``pved evaluate`` and a copy) are
``pved train-policy --agent Reacher3 --task Reach --seed 0`` and so on.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import pved  # noqa: E402, F401  (before numpy loads: it pins OpenBLAS's kernel)

# isort: split
import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
from pathlib import Path  # noqa: E402

import torch  # noqa: E402

from pved import __version__  # noqa: E402
from pved.envs.registry import env_id  # noqa: E402
from pved.experiments.stages import evaluate, train_policy  # noqa: E402
from pved.pretrained import PRETRAINED_DIR  # noqa: E402
from pved.runs import atomic_write_json  # noqa: E402
from pved.spec import preset_for_agent  # noqa: E402

#: What ``make demo`` needs: both agents on the training task, the source on the target task.
DEFAULT_POLICIES: tuple[tuple[str, str, int], ...] = (
    ("Reacher3", "Reach", 1_000_000),
    ("Reacher4", "Reach", 1_000_000),
    ("Reacher3", "Push", 1_000_000),
)
FINAL_EVAL_EPISODES = 500
FINAL_EVAL_SEED = 3 * 10**6  # apart from training's (seed) and its evaluations' (seed + 1e6)


def ship(agent: str, task: str, seed: int, steps: int, runs_root: Path) -> dict[str, object]:
    """Train (or reuse a finished run), evaluate and copy one policy into the package."""
    policy_file = train_policy(agent, task, seed=seed, steps=steps, runs_root=runs_root)
    name = env_id(agent, task)
    preset = preset_for_agent(agent)
    # the pair's own measure: 500 episodes for success rates, 100 for the locomotion
    # distance (paper IV.A), on seeds no training or selection has seen
    episodes = min(FINAL_EVAL_EPISODES, preset.transfer.final_eval_episodes)
    stats = evaluate(policy_file, name, episodes=episodes, seed=FINAL_EVAL_SEED)
    training = json.loads((policy_file.parent / "result.json").read_text())
    stem = f"{agent.lower()}_{task.lower()}_seed{seed}"
    shutil.copyfile(policy_file, PRETRAINED_DIR / f"{stem}.pt")
    meta: dict[str, object] = {
        "env_id": name,
        "agent": agent,
        "task": task,
        "seed": seed,
        "steps": steps,
        # less than ``steps`` where the preset's early stop ended training
        "trained_steps": training.get("trained_steps", steps),
        # with the preset's policy_keep_best: the evaluation point that was kept
        "selected_step": training.get("selected_step", steps),
        "command": f"pved train-policy --agent {agent} --task {task} --seed {seed} --steps {steps}",
        "evaluation": {"episodes": episodes, "seed": FINAL_EVAL_SEED, **stats},
        # a checksum of the shipped file as it is (file_digest hashes the state it holds)
        "sha256_16": hashlib.sha256(policy_file.read_bytes()).hexdigest()[:16],
        "pved_version": __version__,
    }
    atomic_write_json(PRETRAINED_DIR / f"{stem}.json", meta)
    return meta


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("runs/pretrained"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--only",
        nargs="*",
        help="Agent:Task entries, e.g. Jaco:Reach (default: the Reacher pair's three); "
        "steps are the pair preset's unless --steps is given",
    )
    parser.add_argument("--steps", type=int, help="override every entry's env steps")
    args = parser.parse_args()
    torch.set_num_threads(1)
    entries = DEFAULT_POLICIES
    if args.only:
        entries = tuple(
            (agent, task, preset_for_agent(agent).policy_config(agent, task).total_steps)
            for agent, task in (entry.split(":") for entry in args.only)
        )
    for agent, task, steps in entries:
        meta = ship(agent, task, args.seed, args.steps or steps, args.runs)
        print(json.dumps(meta["evaluation"]), flush=True)


if __name__ == "__main__":
    main()
