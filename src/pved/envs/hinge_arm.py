"""Arms of hinge joints whose end point does the task: the robot part shared by the
Reacher pair (:mod:`pved.envs.reacher`, end point the fingertip) and the robot-arm pair
(:mod:`pved.envs.arms`, the peg tip), and their common training task, Reach.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from typing import Any, ClassVar, Protocol

import mujoco
import numpy as np

from pved.envs.base import Info
from pved.envs.batched import MujocoBatchedEnv, joint_addresses, split_reward_terms
from pved.errors import PvedError

_AXES = "xyz"


class HingeArmConfig(Protocol):
    """What :class:`HingeArmBatchedEnv` reads of its task's config (a frozen dataclass)."""

    @property
    def agent(self) -> str: ...
    @property
    def episode_steps(self) -> int: ...
    @property
    def timestep(self) -> float: ...
    @property
    def frame_skip(self) -> int: ...
    @property
    def init_qpos_noise(self) -> float: ...
    @property
    def init_qvel_noise(self) -> float: ...
    @property
    def ctrl_cost_weight(self) -> float: ...


class HingeArmReachConfig(HingeArmConfig, Protocol):
    """What :class:`HingeArmReachBatchedEnv` reads besides."""

    @property
    def success_dist(self) -> float: ...
    @property
    def dist_weight(self) -> float: ...


class HingeArmBatchedEnv(MujocoBatchedEnv):
    """An arm of n hinge joints whose end point does the task: the robot part shared by
    the Reacher pair (``reacher.py``, end point the fingertip ``ee``) and the robot-arm
    pair (``arms.py``, the peg ``tip``).

    Robot observation (``robot_state_indices`` = ``arange(3n + d)``): cos q (n), sin q (n),
    qvel (n), end point (d). Initial arm state (:meth:`_initial_arm`): ``rest_qpos`` plus
    U(-init_qpos_noise, init_qpos_noise) per joint, joint velocities U(-init_qvel_noise,
    init_qvel_noise). Reward term ``ctrl`` = -ctrl_cost_weight ||a||^2 (:meth:`_ctrl_term`).

    The subclass builds and checks the model (calling :meth:`_check_timing` first), keeps
    ``end_pos`` up to date in ``_derive``, and names the end point: ``end_name`` in the
    observation names, ``end_key`` as its ``info`` readout.

    Attributes (besides :class:`MujocoBatchedEnv`'s):
        agent: the agent; task: the task; config: the task's config.
        reward_mode: the ``reward`` argument; reward_terms: the terms summed.
        joint_names: the arm's joints, root to end point; n_joints: n.
        rest_qpos: (n,) the rest pose (rad).
        end_pos: (N, d) end-point position of each copy.
        robot_observation_names: names of the robot part of the observation.
    """

    end_name: ClassVar[str]
    end_key: ClassVar[str]
    config: HingeArmConfig

    def __init__(
        self,
        model: mujoco.MjModel,
        config: HingeArmConfig,
        task: str,
        reward: str,
        reward_terms: tuple[str, ...],
        joint_names: tuple[str, ...],
        rest_qpos: Sequence[float] | np.ndarray,
        end_dim: int,
        num_envs: int,
        autoreset: bool,
    ) -> None:
        self.agent = config.agent
        self.task = task
        self.reward_mode = reward
        self.reward_terms = reward_terms
        model.opt.timestep = config.timestep
        super().__init__(model, num_envs, config.frame_skip, config.episode_steps, autoreset)
        self.config = config
        self.joint_names = joint_names
        self._arm_qpos, self._arm_dof = joint_addresses(model, joint_names)
        n = len(joint_names)
        self.n_joints = n
        self.rest_qpos = np.asarray(rest_qpos, dtype=np.float64)
        self.end_pos = np.zeros((self.num_envs, end_dim))
        self.robot_state_indices = np.arange(3 * n + end_dim)
        self.robot_observation_names: tuple[str, ...] = (
            *(f"cos_q{k}" for k in range(n)),
            *(f"sin_q{k}" for k in range(n)),
            *(f"qvel{k}" for k in range(n)),
            *(f"{self.end_name}_{a}" for a in _AXES[:end_dim]),
        )

    @staticmethod
    def _check_timing(config: HingeArmConfig) -> None:
        """Reject a config whose timestep, frame skip or episode length is not positive."""
        if config.timestep <= 0 or config.frame_skip < 1 or config.episode_steps < 1:
            raise PvedError("timestep must be > 0, frame_skip and episode_steps >= 1")

    def _robot_obs(self) -> np.ndarray:
        """(N, 3n + d): cos q, sin q, qvel, end point."""
        q = self.qpos[:, self._arm_qpos]
        return np.concatenate(
            [np.cos(q), np.sin(q), self.qvel[:, self._arm_dof], self.end_pos], axis=1
        )

    def _initial_arm(self, uniforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """qpos (k, nq) and qvel (k, nv): the rest pose plus uniform noise from the first
        2n columns of ``uniforms`` on the arm's joints, zero elsewhere. The arm's draws
        come first in every task, so one seed gives one agent the same initial arm state
        on both of its tasks."""
        n, cfg = self.n_joints, self.config
        q = self.rest_qpos + cfg.init_qpos_noise * (2.0 * uniforms[:, :n] - 1.0)
        qd = cfg.init_qvel_noise * (2.0 * uniforms[:, n : 2 * n] - 1.0)
        qpos = np.zeros((len(uniforms), self.model.nq))
        qvel = np.zeros((len(uniforms), self.model.nv))
        qpos[:, self._arm_qpos] = q
        qvel[:, self._arm_dof] = qd
        return qpos, qvel

    def _ctrl_term(self, actions: np.ndarray) -> np.ndarray:
        return -self.config.ctrl_cost_weight * np.sum(actions * actions, axis=1)


class HingeArmReachBatchedEnv(HingeArmBatchedEnv):
    """The Reach task of a hinge arm (the training task of both arm pairs): bring the end
    point to a target drawn per episode.

    Reward terms ``dist`` = -dist_weight ||end - target|| and ``ctrl``; ``is_success``:
    ||end - target|| < ``success_dist``; never terminates. Observation task part: target
    (d), target - end point (d). Task parameter and reset option: ``target`` (d,).
    ``info`` readouts: ``is_success`` and the end point (``end_key``).

    A task class derives from this and from its pair's arm class, calls
    :meth:`_init_reach` once constructed, draws targets in :meth:`_draw_target` and
    places the target's marker in ``_write_extra``.
    """

    config: HingeArmReachConfig

    def _init_reach(self) -> None:
        d = self.end_pos.shape[1]
        self.target = np.zeros((self.num_envs, d))
        self.task_param_keys = ("target",)
        self._set_observation_names(
            (
                *self.robot_observation_names,
                *(f"target_{a}" for a in _AXES[:d]),
                *(f"target_minus_{self.end_name}_{a}" for a in _AXES[:d]),
            )
        )

    @abstractmethod
    def _draw_target(self, task_u: np.ndarray) -> np.ndarray:
        """Targets (k, d) from the task's U[0, 1) draws (k, m) of a reset, the columns
        after the arm's 2n."""

    def _validate_options(self, options: dict[str, Any]) -> dict[str, np.ndarray]:
        unknown = set(options) - {"target"}
        if unknown:
            raise PvedError(f"unknown reset option(s) {sorted(unknown)}; Reach takes 'target'")
        shape = (self.target.shape[1],)
        return {"target": self._batched_option("target", options["target"], shape)}

    def _initial_state(
        self, idx: np.ndarray, uniforms: np.ndarray, options: dict[str, np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        qpos, qvel = self._initial_arm(uniforms)
        target = self._draw_target(uniforms[:, 2 * self.n_joints :])
        if options is not None and "target" in options:
            target = options["target"][idx]
        self.target[idx] = target
        return qpos, qvel

    def _get_task_state(self) -> dict[str, np.ndarray]:
        return {"target": self.target.copy()}

    def _set_task_state(self, state: dict[str, np.ndarray]) -> None:
        self.target = np.asarray(state["target"], dtype=np.float64).copy()

    def _observe(self) -> np.ndarray:
        return np.concatenate([self._robot_obs(), self.target, self.target - self.end_pos], axis=1)

    def _evaluate(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, Info]:
        dist = np.linalg.norm(self.end_pos - self.target, axis=1)
        terms = {"dist": -self.config.dist_weight * dist, "ctrl": self._ctrl_term(actions)}
        reward, info = split_reward_terms(terms, self.reward_terms, self.num_envs)
        info["is_success"] = dist < self.config.success_dist
        info[self.end_key] = self.end_pos.copy()
        return reward, np.zeros(self.num_envs, dtype=bool), info

    def _reset_info(self) -> Info:
        dist = np.linalg.norm(self.end_pos - self.target, axis=1)
        return {"is_success": dist < self.config.success_dist, self.end_key: self.end_pos.copy()}

    def _task_params(self) -> Info:
        return {"target": self.target.copy()}


__all__ = [
    "HingeArmBatchedEnv",
    "HingeArmConfig",
    "HingeArmReachBatchedEnv",
    "HingeArmReachConfig",
]
