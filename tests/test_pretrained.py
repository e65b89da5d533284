"""The policies shipped in ``pved/pretrained``: each one is what its ``.json`` says, fits
its env, and met the bar its issue set when it was evaluated on fresh episodes."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from pved.envs import make_batched
from pved.errors import PvedError
from pved.pretrained import PRETRAINED_DIR, pretrained_policy_path, shipped_seeds
from pved.rl.policy import load_policy

SHIPPED = sorted(PRETRAINED_DIR.glob("*.pt"))

# What a shipped policy must have shown on its final evaluation, per task: success on the
# arms' Peg (issue 4: >= 80% of 500 episodes), no fall on the locomotion terrains (issue 3:
# >= 90% of 100 episodes reach the 1000-step limit).
BARS: dict[str, tuple[str, float, int]] = {
    "Peg": ("success_rate", 0.8, 500),
    "Slope": ("completion_rate", 0.9, 100),
    "Curve": ("completion_rate", 0.9, 100),
}


def test_something_is_shipped() -> None:
    assert len(SHIPPED) >= 5


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_policy_matches_its_record(path: Path) -> None:
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["sha256_16"] == hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    assert path.stem == f"{meta['agent'].lower()}_{meta['task'].lower()}_seed{meta['seed']}"
    policy = load_policy(path)
    env = make_batched(meta["env_id"], 1)
    assert policy.obs_dim == env.single_observation_space.shape[0]
    assert policy.act_dim == env.single_action_space.shape[0]
    evaluation = meta["evaluation"]
    if meta["task"] in BARS:
        key, bar, episodes = BARS[meta["task"]]
        assert evaluation["episodes"] >= episodes
        assert evaluation[key] >= bar, f"{path.name}: {key} {evaluation[key]} < {bar}"


def test_a_task_defaults_to_its_lowest_shipped_seed() -> None:
    # seeds that missed their bar are not shipped, so a task's seeds may start above 0
    for path in SHIPPED:
        meta = json.loads(path.with_suffix(".json").read_text())
        seeds = shipped_seeds(meta["agent"], meta["task"])
        assert meta["seed"] in seeds
        assert pretrained_policy_path(meta["agent"], meta["task"]).stem.endswith(
            f"_seed{min(seeds)}"
        )
    with pytest.raises(PvedError, match="no pretrained policy for Hopper on Curve"):
        pretrained_policy_path("Hopper", "Curve")
