"""The batched environment contract shared by every pved environment.

Every task is written once, over a batch of N copies of one MuJoCo model: physics is
stepped by MuJoCo's C engine (one ``mj_step(model, data, nstep)`` call per copy), and
everything else (observations, rewards, terminations, resets) is numpy over the batch.
The plain ``gymnasium.Env`` of each task is a thin adapter over a batch of one, so the
two forms give identical transitions for the same seed and actions by construction.

Autoreset: when copy ``i`` ends (terminated or truncated) inside ``step``, it is reset in
the same call; the returned observation is the first one of its new episode and the
last observation of the old one is in ``info["final_obs"][i]`` (Stable-Baselines3's
convention). ``info`` maps names to arrays whose first axis is the batch. Step
quantities in ``info`` (``reward_<term>``, ``is_success``) describe the step just taken,
so for a finished copy they are its episode's last step; task parameters (``target``,
``button_start``, ...) describe the episode the returned observation belongs to, so
after an autoreset they are the new episode's.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import gymnasium as gym
import numpy as np

Info = dict[str, np.ndarray]


class BatchedEnv(ABC):
    """N copies of one task stepped together.

    Attributes:
        num_envs: N.
        single_observation_space: Box of one copy's observation, shape (obs_dim,).
        single_action_space: Box of one copy's action, shape (act_dim,).
        robot_state_indices: indices into the observation of the robot's own state
            (joint angles and velocities, end effector or torso), the part PVED sees
            (paper IV.A: "we only consider robot-related states").
        max_episode_steps: truncation horizon.
    """

    num_envs: int
    single_observation_space: gym.spaces.Box
    single_action_space: gym.spaces.Box
    robot_state_indices: np.ndarray
    max_episode_steps: int

    @abstractmethod
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, Info]:
        """Reset all copies. Copy ``i`` is seeded with ``seed + i`` (Gymnasium's vector
        convention), so it matches a single env reset with that seed.

        Returns:
            obs: (N, obs_dim) float64; info: arrays with leading axis N.
        """

    @abstractmethod
    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Info]:
        """Step all copies with ``actions`` (N, act_dim), autoresetting finished ones.

        Returns:
            obs (N, obs_dim), reward (N,), terminated (N,) bool, truncated (N,) bool, info.
        """

    def close(self) -> None:  # noqa: B027  (optional hook, not abstract)
        """Release resources (renderers); the default holds none."""
