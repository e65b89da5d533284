"""A batched replica of Gymnasium's ``Hopper-v5`` for fast PPO benchmarks.

It steps Gymnasium's own ``hopper.xml`` (read from the installed gymnasium package at run
time) with MuJoCo's C engine, one ``mj_step(model, data, nstep=4)`` per copy, and computes
Hopper-v5's observation, reward, health termination, 1000-step truncation and reset noise
in numpy over the batch. Copy ``i`` reset with seed ``s + i`` gives the same transitions
as ``gymnasium.make("Hopper-v5")`` reset with ``s + i`` and fed the same actions
(tested in ``tests/test_ppo.py``), including its later autoresets, which draw from the
copy's generator exactly as an unseeded ``env.reset()`` does.

The one omission: Gymnasium calls ``mj_rnePostConstraint`` after each step to fill
``cfrc_ext`` and friends; Hopper's observation and reward never read them, and
``mj_step`` recomputes them from the state, so skipping it changes nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from pved.envs.base import BatchedEnv, Info
from pved.errors import PvedError

FRAME_SKIP = 4
FORWARD_REWARD_WEIGHT = 1.0
CTRL_COST_WEIGHT = 1e-3
HEALTHY_REWARD = 1.0
HEALTHY_STATE_RANGE = (-100.0, 100.0)
HEALTHY_Z_RANGE = (0.7, float("inf"))
HEALTHY_ANGLE_RANGE = (-0.2, 0.2)
RESET_NOISE_SCALE = 5e-3
MAX_EPISODE_STEPS = 1000


def gymnasium_hopper_xml() -> Path:
    """Path of ``hopper.xml`` inside the installed gymnasium package."""
    import gymnasium.envs.mujoco as gym_mujoco

    path = Path(gym_mujoco.__file__).resolve().parent / "assets" / "hopper.xml"
    if not path.exists():
        raise PvedError(f"gymnasium's hopper.xml not found at {path}")
    return path


class HopperV5Batch(BatchedEnv):
    """N copies of Hopper-v5 (default arguments) stepped in one process.

    ``info`` holds, per copy, Hopper-v5's ``x_position``, ``z_distance_from_origin``,
    ``x_velocity``, ``reward_forward``, ``reward_ctrl``, ``reward_survive`` of the step,
    and ``final_obs``.
    """

    env_id = "Hopper-v5"

    def __init__(self, num_envs: int) -> None:
        if num_envs <= 0:
            raise PvedError(f"HopperV5Batch needs num_envs > 0, got {num_envs}")
        self.num_envs = int(num_envs)
        self.model = mujoco.MjModel.from_xml_path(str(gymnasium_hopper_xml()))
        self.datas = [mujoco.MjData(self.model) for _ in range(self.num_envs)]
        self.init_qpos = self.datas[0].qpos.copy()
        self.init_qvel = self.datas[0].qvel.copy()
        self.dt = float(self.model.opt.timestep) * FRAME_SKIP
        nq, nv = self.model.nq, self.model.nv
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (nq - 1 + nv,), np.float64)
        low, high = self.model.actuator_ctrlrange.copy().astype(np.float32).T
        self.single_action_space = gym.spaces.Box(low, high, dtype=np.float32)
        self.robot_state_indices = np.arange(nq - 1 + nv)
        self.max_episode_steps = MAX_EPISODE_STEPS
        self.qpos = np.zeros((self.num_envs, nq))
        self.qvel = np.zeros((self.num_envs, nv))
        self._t = np.zeros(self.num_envs, dtype=np.int64)
        self._rngs = [np.random.default_rng() for _ in range(self.num_envs)]
        self._state_spec = mujoco.mjtState.mjSTATE_INTEGRATION

    # -- helpers ---------------------------------------------------------------------
    def _gather(self) -> None:
        for i, d in enumerate(self.datas):
            self.qpos[i] = d.qpos
            self.qvel[i] = d.qvel

    def _obs(self) -> np.ndarray:
        return np.concatenate([self.qpos[:, 1:], np.clip(self.qvel, -10.0, 10.0)], axis=1)

    def _healthy(self) -> np.ndarray:
        z, angle = self.qpos[:, 1], self.qpos[:, 2]
        state = np.concatenate([self.qpos[:, 2:], self.qvel], axis=1)
        lo, hi = HEALTHY_STATE_RANGE
        healthy_state = np.all((lo < state) & (state < hi), axis=1)
        healthy_z = (HEALTHY_Z_RANGE[0] < z) & (z < HEALTHY_Z_RANGE[1])
        healthy_angle = (HEALTHY_ANGLE_RANGE[0] < angle) & (angle < HEALTHY_ANGLE_RANGE[1])
        return np.asarray(healthy_state & healthy_z & healthy_angle)

    def _reset_copy(self, i: int) -> None:
        d, rng = self.datas[i], self._rngs[i]
        mujoco.mj_resetData(self.model, d)
        # same draws, in the same order, as HopperEnv.reset_model
        d.qpos[:] = self.init_qpos + rng.uniform(
            -RESET_NOISE_SCALE, RESET_NOISE_SCALE, self.model.nq
        )
        d.qvel[:] = self.init_qvel + rng.uniform(
            -RESET_NOISE_SCALE, RESET_NOISE_SCALE, self.model.nv
        )
        mujoco.mj_forward(self.model, d)
        self.qpos[i] = d.qpos
        self.qvel[i] = d.qvel
        self._t[i] = 0

    # -- BatchedEnv --------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, Info]:
        if seed is not None:
            self._rngs = [np.random.default_rng(seed + i) for i in range(self.num_envs)]
        for i in range(self.num_envs):
            self._reset_copy(i)
        info: Info = {
            "x_position": self.qpos[:, 0].copy(),
            "z_distance_from_origin": self.qpos[:, 1] - self.init_qpos[1],
        }
        return self._obs(), info

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Info]:
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs, self.model.nu):
            raise PvedError(
                f"HopperV5Batch.step expects actions of shape {(self.num_envs, self.model.nu)}, "
                f"got {actions.shape}"
            )
        x_before = self.qpos[:, 0].copy()
        for d, a in zip(self.datas, actions, strict=True):
            d.ctrl[:] = a
            mujoco.mj_step(self.model, d, nstep=FRAME_SKIP)
        self._gather()
        self._t += 1
        x_after = self.qpos[:, 0].copy()
        x_velocity = (x_after - x_before) / self.dt
        healthy = self._healthy()
        forward = FORWARD_REWARD_WEIGHT * x_velocity
        survive = healthy * HEALTHY_REWARD
        ctrl_cost = CTRL_COST_WEIGHT * np.sum(np.square(actions), axis=1)
        reward = forward + survive - ctrl_cost
        terminated = ~healthy
        truncated = self._t >= self.max_episode_steps
        obs = self._obs()
        info: Info = {
            "x_position": x_after,
            "z_distance_from_origin": self.qpos[:, 1] - self.init_qpos[1],
            "x_velocity": x_velocity,
            "reward_forward": forward,
            "reward_ctrl": -ctrl_cost,
            "reward_survive": survive,
            "final_obs": obs.copy(),
        }
        done = terminated | truncated
        if done.any():
            for i in np.flatnonzero(done):
                self._reset_copy(int(i))
            obs = self._obs()
        return obs, reward, terminated, truncated, info

    # -- exact save/restore ------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """The full integration state of every copy, step counters and generators."""
        size = mujoco.mj_stateSize(self.model, self._state_spec)
        states = np.zeros((self.num_envs, size))
        for i, d in enumerate(self.datas):
            mujoco.mj_getState(self.model, d, states[i], self._state_spec)
        return {
            "mj_state": states,
            "t": self._t.copy(),
            "rng": [r.bit_generator.state for r in self._rngs],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        states = np.asarray(state["mj_state"], dtype=np.float64)
        if states.shape != (self.num_envs, mujoco.mj_stateSize(self.model, self._state_spec)):
            raise PvedError(
                f"HopperV5Batch state has shape {states.shape}, wrong for {self.num_envs} copies"
            )
        for i, d in enumerate(self.datas):
            # no mj_forward here: it would overwrite the solver warm start that the
            # restored state carries, and mj_step recomputes everything else
            mujoco.mj_setState(self.model, d, states[i], self._state_spec)
        self._gather()
        self._t = np.asarray(state["t"], dtype=np.int64).copy()
        for r, s in zip(self._rngs, state["rng"], strict=True):
            r.bit_generator.state = s
