"""A tiny batched env for tests: a 1-D point that must reach a random target.

Numpy only (no MuJoCo), so PPO's tests can learn it in seconds. It exercises both ways
an episode ends: reaching the target *terminates* (with a bonus and ``is_success``),
running out of time *truncates* (bootstrapped from ``final_obs``).

Dynamics per step: ``x ← clip(x + speed·a, −1.5, 1.5)`` with ``a ∈ [−1, 1]``;
reward ``−|g − x|`` plus 1 on success (``|g − x| < tolerance``). Observation
``(x, g − x)``. A random policy scores about −25 per episode, a good one about −1.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from pved.envs.base import BatchedEnv, Info
from pved.errors import PvedError


class PointTarget1D(BatchedEnv):
    """N copies of the 1-D point-to-target task.

    Args:
        num_envs: N.
        max_episode_steps: truncation horizon.
        speed: distance moved by a full action.
        tolerance: success radius.
    """

    env_id = "pved-toy/PointTarget1D"

    def __init__(
        self,
        num_envs: int = 8,
        max_episode_steps: int = 50,
        speed: float = 0.1,
        tolerance: float = 0.05,
    ) -> None:
        if num_envs <= 0 or max_episode_steps <= 0:
            raise PvedError("PointTarget1D needs num_envs > 0 and max_episode_steps > 0")
        self.num_envs = int(num_envs)
        self.max_episode_steps = int(max_episode_steps)
        self.speed = float(speed)
        self.tolerance = float(tolerance)
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.robot_state_indices = np.array([0])
        self._x = np.zeros(self.num_envs)
        self._goal = np.zeros(self.num_envs)
        self._t = np.zeros(self.num_envs, dtype=np.int64)
        self._rngs = [np.random.default_rng(i) for i in range(self.num_envs)]

    def _obs(self) -> np.ndarray:
        return np.stack([self._x, self._goal - self._x], axis=1)

    def _reset_copies(self, idx: np.ndarray) -> None:
        for i in idx:
            self._x[i] = self._rngs[i].uniform(-1.0, 1.0)
            self._goal[i] = self._rngs[i].uniform(-1.0, 1.0)
        self._t[idx] = 0

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, Info]:
        if seed is not None:
            self._rngs = [np.random.default_rng(seed + i) for i in range(self.num_envs)]
        self._reset_copies(np.arange(self.num_envs))
        return self._obs(), {}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Info]:
        a = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, 1)[:, 0]
        self._x = np.clip(self._x + self.speed * np.clip(a, -1.0, 1.0), -1.5, 1.5)
        self._t += 1
        distance = np.abs(self._goal - self._x)
        success = distance < self.tolerance
        reward = -distance + success.astype(np.float64)
        terminated = success
        truncated = self._t >= self.max_episode_steps
        obs = self._obs()
        info: Info = {
            "is_success": success.astype(np.float64),
            "distance": distance,
            "final_obs": obs.copy(),
        }
        done = terminated | truncated
        if done.any():
            self._reset_copies(np.flatnonzero(done))
            obs = self._obs()
        return obs, reward, terminated, truncated, info

    # -- exact save/restore (lets PPO resume bit-exactly) --------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {
            "x": self._x.copy(),
            "goal": self._goal.copy(),
            "t": self._t.copy(),
            "rng": [r.bit_generator.state for r in self._rngs],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._x = np.asarray(state["x"], dtype=np.float64).copy()
        self._goal = np.asarray(state["goal"], dtype=np.float64).copy()
        self._t = np.asarray(state["t"], dtype=np.int64).copy()
        for r, s in zip(self._rngs, state["rng"], strict=True):
            r.bit_generator.state = s
