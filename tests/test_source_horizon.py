"""Issue 64, item 1: the source bank covers the target's whole episode on the pairs' time
base, and a target step past the end of its source episode is compared with nothing
(docs/decisions/transfer.md, "A target step past the source's end").

Why: a Humanoid bank episode of 1000 steps lasts 15 s, an Ant episode 50 s; read at the
same moment, from Ant step 300 on every step met the Humanoid's frozen last row.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import push_bank_and_model
from pved.envs import make_batched
from pved.errors import PvedError
from pved.experiments import stages
from pved.models import PVED
from pved.pair import resolve_pair
from pved.rl.guide import GUIDE_CONTEXT, GUIDE_MASK
from pved.run_layout import bank_rollout_steps
from pved.runs import Run
from pved.transfer.shaping import SOURCE_ENDED, LatentShaping, ShapedBatchedEnv
from pved.transfer.source_bank import (
    SourceBank,
    bank_step_limit,
    bank_time_scale,
    source_covered,
)

TARGET_PUSH = "pved/Reacher4Push-v0"
MATCH_KEYS = ("button_start",)


@pytest.fixture(scope="module")
def inputs() -> tuple[SourceBank, PVED]:
    bank, model = push_bank_and_model(episodes=4)
    # the first episode ends (the source fell) after 3 of its 100 recorded steps: its rows
    # from step 3 on are real rows, so reading them would give a term
    short = SourceBank(bank.x, np.array([3, 100, 100, 100]), bank.keys, bank.header)
    return short, model


def test_the_step_limit_reaches_as_far_as_the_target_s_episode() -> None:
    humanoid_per_ant = bank_time_scale("time", 0.015, 0.05)
    assert bank_step_limit(1000, humanoid_per_ant) == 3334  # 50 s of 0.015 s steps
    assert round(999 * humanoid_per_ant) < 3334  # the Ant's last step meets a taken one
    assert bank_step_limit(1000, 1.0) == 1000
    assert bank_step_limit(10, 0.4) == 5  # ceil(4.0) = 4, but step 9 reads source step 4
    for bad in ((0, 1.0), (10, 0.0), (10, float("nan"))):
        with pytest.raises(PvedError, match="step limit"):
            bank_step_limit(*bad)


class _Started(Exception):
    """Raised where the stage would make its run directory: its config is resolved."""


def test_humanoid_ant_s_bank_runs_as_long_as_an_ant_episode(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    configs: list[dict[str, Any]] = []
    limits: list[int] = []

    def record_and_stop(run: Run) -> None:
        configs.append(run.config)
        raise _Started

    def rollouts(env: Any, *args: Any, **kwargs: Any) -> None:
        limits.append(env.max_episode_steps)
        raise _Started

    monkeypatch.setattr(Run, "start", record_and_stop)
    with pytest.raises(_Started):
        stages.build_bank("humanoid-ant", episodes=2, runs_root=tmp_path)
    assert configs[0]["step_limit"] == 3334
    # and the env the rollouts run on truncates there, not at the Humanoid's 1000
    monkeypatch.setattr(Run, "start", lambda run: None)
    monkeypatch.setattr(stages, "build_source_bank", rollouts)
    with pytest.raises(_Started):
        stages.build_bank("humanoid-ant", episodes=2, runs_root=tmp_path / "b")
    assert limits == [3334]
    # the other pairs' agents share a control period and a horizon: their banks as before
    for pair in ("reacher", "jaco-fetch", "walker-hopper"):
        assert bank_rollout_steps(resolve_pair(pair)) is None, pair


@pytest.mark.parametrize("env_id", [TARGET_PUSH, "Pendulum-v1"])
def test_a_batched_env_truncates_at_the_step_limit_it_is_given(env_id: str) -> None:
    env = make_batched(env_id, 2, step_limit=3)
    env.reset(seed=0)
    act = np.zeros((2, env.single_action_space.shape[0]))
    truncated = [bool(env.step(act)[3].all()) for _ in range(4)]
    assert env.max_episode_steps == 3 and truncated == [False, False, True, False]
    with pytest.raises(PvedError, match="step_limit"):
        make_batched(env_id, 1, step_limit=0)


def test_a_target_step_past_the_source_s_end_pays_no_term(
    inputs: tuple[SourceBank, PVED],
) -> None:
    bank, model = inputs
    env = make_batched(TARGET_PUSH, 2)
    obs, _ = env.reset(seed=1)
    act = np.zeros((2, env.single_action_space.shape[0]))
    episode = np.array([0, 1])
    for form in ("eq10", "log1p"):
        shaping = LatentShaping(model, bank, 0.5, env.robot_state_indices, form=form)
        before = shaping.values(obs, act, episode, np.full(2, 2), 2)
        after = shaping.values(obs, act, episode, np.full(2, 3), 2)
        # episode 0 ended after step 2: step 3 meets nothing; episode 1 goes on
        assert (before < 0).all() and after[0] == 0.0 and after[1] < 0
    assert source_covered(np.array([2, 3, 3]), np.array([3, 3, 4])).tolist() == [1, 0, 1]
    # on the time base: target step 1 reads source step round(1 · 3.33) = 3, past a 3-step end
    assert source_covered(np.array([0, 1]), np.array([3, 3]), 10 / 3).tolist() == [1, 0]


@pytest.mark.parametrize("form", ["eq10", "align"])
def test_the_shaped_env_says_which_steps_met_nothing(
    inputs: tuple[SourceBank, PVED], form: str
) -> None:
    bank, model = inputs
    target = make_batched(TARGET_PUSH, 2)
    shaping = LatentShaping(model, bank, 0.5, target.robot_state_indices, form=form)
    env = ShapedBatchedEnv(target, shaping, MATCH_KEYS)
    env.reset(seed=1)
    env._episode[:] = [0, 1]  # the short episode and a whole one
    act = np.zeros((2, env.single_action_space.shape[0]))
    ended = []
    for _ in range(5):
        env.set_mean_actions(act)
        _, _, _, _, info = env.step(act)
        ended.append(info[SOURCE_ENDED].tolist())
        if form == "align":  # PPO leaves the guide's rows past the source's end out
            assert info[GUIDE_CONTEXT].shape[0] == 2
            np.testing.assert_array_equal(info[GUIDE_MASK], ~info[SOURCE_ENDED])
        else:
            assert GUIDE_MASK not in info
            np.testing.assert_array_equal(info["reward_shaping"] == 0.0, info[SOURCE_ENDED])
    assert ended == [[False, False]] * 3 + [[True, False]] * 2
