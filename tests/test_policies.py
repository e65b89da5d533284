"""``train_policy`` keeps the best evaluation point and stops early when the pair's preset
asks for it."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from pved.config import PairPreset
from pved.experiments import stages
from pved.rl.policy import load_policy
from pved.spec import get_preset


def _use_small_hopper_preset(
    monkeypatch: pytest.MonkeyPatch, eval_every: int, **preset_changes: Any
) -> PairPreset:
    """The walker-hopper preset with a tiny PPO (2 envs x 64 steps, evaluations every
    ``eval_every`` steps, no checkpoints), patched in for ``train_policy``."""
    preset = get_preset("walker-hopper")
    ppo = dataclasses.replace(
        preset.policy_config("Hopper", "Slope"),
        num_envs=2,
        steps_per_env=64,
        minibatch_size=64,
        eval_every=eval_every,
        checkpoint_every=0,
    )
    small = dataclasses.replace(
        preset, policy=ppo, policy_overrides=(), policy_eval_episodes=2, **preset_changes
    )
    monkeypatch.setattr(stages, "preset_for_agent", lambda agent: small)
    return preset


def _script_evaluations(
    monkeypatch: pytest.MonkeyPatch, returns: dict[int, float], completion: dict[int, float]
) -> list[int]:
    """Replace the policy evaluations by scripted results per env step; returns the list
    the evaluated steps are appended to."""
    seen: list[int] = []

    def fake_eval_fn(*args: Any, **kwargs: Any):
        def evaluate(policy: Any, env_steps: int) -> dict[str, float]:
            seen.append(env_steps)
            return {
                "eval/return_mean": returns[env_steps],
                "eval/completion_rate": completion[env_steps],
            }

        return evaluate

    monkeypatch.setattr(stages, "_eval_fn", fake_eval_fn)
    return seen


def test_keep_best_saves_the_policy_of_the_best_evaluation(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    preset = _use_small_hopper_preset(monkeypatch, 256, policy_stop_completion=None)
    assert preset.policy_keep_best
    # scripted evaluation: the return peaks at the second evaluation point (step 512)
    scripted = {0: 1.0, 256: 5.0, 512: 9.0, 768: 3.0, 1024: 2.0}
    seen = _script_evaluations(monkeypatch, scripted, dict.fromkeys(scripted, 1.0))
    path = stages.train_policy("Hopper", "Slope", steps=1024, runs_root=tmp_path, progress=False)
    assert seen == [0, 256, 512, 768, 1024]
    result = json.loads((path.parent / "result.json").read_text())
    assert result["selected_step"] == 512 and result["eval/return_mean"] == 9.0
    assert path.read_bytes() == (path.parent / "best_policy.pt").read_bytes()
    assert load_policy(path).metadata["selected_step"] == 512


def test_training_stops_once_it_neither_falls_nor_improves(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    preset = _use_small_hopper_preset(monkeypatch, 128)
    assert preset.policy_stop_completion == 0.98 and preset.policy_stop_evaluations == 2
    assert preset.policy_stop_gain == 0.02
    # one evaluation at the bar, a relapse, then two in a row (384 and 512) while the
    # return still grows 12%, and a third (640) where it does not: training ends at 640
    completion = {0: 0.0, 128: 1.0, 256: 0.9, 384: 0.98, 512: 1.0, 640: 1.0, 768: 1.0}
    returns = {0: 1.0, 128: 2.0, 256: 3.0, 384: 8.0, 512: 9.0, 640: 8.9, 768: 9.5}
    seen = _script_evaluations(monkeypatch, returns, completion)
    path = stages.train_policy("Hopper", "Slope", steps=2048, runs_root=tmp_path, progress=False)
    assert seen == [0, 128, 256, 384, 512, 640]
    result = json.loads((path.parent / "result.json").read_text())
    assert result["steps"] == 2048 and result["trained_steps"] == 640
    # the best return among the points evaluated is still the one kept
    assert result["selected_step"] == 512
