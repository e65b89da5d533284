"""The Reacher pair (paper IV.A, first agent pair): planar 3- and 4-link arms.

Agents (top-down planar arms, hinge axes along z, root at the origin):

* ``Reacher3`` (source): links 0.12, 0.10, 0.08 m (reach 0.30 m).
* ``Reacher4`` (target): links 0.10, 0.08, 0.07, 0.05 m (reach 0.30 m).

The root joint is unlimited, the others limited to +-2.6 rad; with these limits both arms
reach every point of the disc of radius 0.30 m. Each joint has a motor (torque
``gear 1 x a``, ``a`` in [-1, 1]), damping 0.2 and armature 0.02, so a joint saturates
near 5 rad/s with a 0.1 s time constant. Physics step 5 ms, 4 per control step: control
period ``DT`` = 0.02 s. Initial state (both agents, both tasks, "similar random initial
states"): rest pose ``(pi, 0, ..., 0)`` (arm stretched along -x) plus U(-0.1, 0.1) rad per
joint, joint velocities U(-0.005, 0.005) rad/s.

Tasks:

* ``Reach`` (training task), 50 steps. The target is drawn uniformly (by area) in the
  annulus ``TARGET_RADIUS_MIN`` = 0.05 m <= r <= ``TARGET_RADIUS_MAX`` = 0.25 m, which lies
  inside the workspace of both arms. Reward = ``reward_dist`` + ``reward_ctrl`` with
  ``reward_dist`` = -||ee - target|| and ``reward_ctrl`` = -0.1 ||a||^2. ``is_success``:
  ||ee - target|| < ``REACH_SUCCESS_DIST`` = 0.02 m. Never terminates.
* ``Push`` (target task), 100 steps. A 3 cm square button slides along x in a channel at
  y = ``CHANNEL_Y`` = 0.15 m (slide joint over [-0.2, 0.2] m with damping 2 N s/m and dry
  friction 0.3 N, so it stops as soon as it is not pushed). Its start x is drawn uniformly
  in ``BUTTON_START_X`` +- ``BUTTON_START_HALFWIDTH`` = -0.08 +- 0.03 m; the goal bar is at
  x = ``GOAL_X`` = 0.06 m. Only the fingertip (a 1 cm sphere) and the button collide, so
  the arm must bring its fingertip to the left of the button and push it right.
  Reward terms: ``reward_ee_button`` = -||ee - button||, ``reward_button_goal`` =
  -||button - goal||, ``reward_ctrl`` = -0.1 ||a||^2. ``reward="full"`` uses all three (the
  source agent's reward, default for Reacher3), ``reward="restricted"`` only
  ``reward_button_goal`` (the paper's reward for the target agent, which does not
  encourage approaching the button; default for Reacher4). The unused terms are
  reported as ``metric_<term>`` and not summed.
  Success (paper: "the button reaches the goal and the end effector moves little
  after"): at a control step the button is *settled* when |button_x - goal_x| <
  ``GOAL_TOL`` = 0.01 m and the end-effector speed is below ``EE_SPEED_TOL`` = 0.05 m/s;
  ``is_success`` is true once this has held for ``SETTLE_STEPS`` = 10 consecutive
  control steps (0.2 s, i.e. the end effector moved less than 1 cm over that window).
  An episode counts as a success when ``is_success`` holds at its last step; it does not
  terminate on success unless ``terminate_on_success=True`` in the config.

Observation (float64), robot part first; ``robot_state_indices`` = ``arange(3n + 2)`` is
the same for Reach and Push of one agent (n links):

* robot: cos q (n), sin q (n), qvel (n), end-effector xy (2);
* Reach task part: target xy (2), target - ee (2);
* Push task part: button xy (2), button x-velocity (1), goal xy (2), button - ee (2).

``info`` (batched: leading axis N) holds the reward terms, ``is_success``, the readouts
``ee_pos`` (2,) (and ``button_pos`` (2,) for Push) of the step just taken, and the task
parameters (``task_param_keys``): ``target`` (2,) (Reach) or ``button_start`` (2,) and
``goal`` (2,) (Push); after an autoreset these are the new episode's (``base.py``).

Reset options: ``target`` (Reach) / ``button_start`` (Push), xy of shape (2,) for the
Gymnasium form and (N, 2) or (2,) for the batched form; the button start must lie on the
channel (y = ``CHANNEL_Y``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from pved.envs.base import Info
from pved.envs.batched import REWARD_MODES as REWARD_MODES
from pved.envs.batched import (
    BatchOfOneEnv,
    load_model,
    resolve_config,
    select_reward_terms,
    split_reward_terms,
)
from pved.envs.hinge_arm import HingeArmBatchedEnv, HingeArmReachBatchedEnv
from pved.errors import PvedError

# ---------------------------------------------------------------- agents
#: Link lengths (m) of each agent, root to fingertip; fixed by the MJCF assets.
AGENT_LINK_LENGTHS: dict[str, tuple[float, ...]] = {
    "Reacher3": (0.12, 0.10, 0.08),
    "Reacher4": (0.10, 0.08, 0.07, 0.05),
}
SOURCE_AGENT = "Reacher3"
TARGET_AGENT = "Reacher4"
TASKS = ("Reach", "Push")

# ---------------------------------------------------------------- shared constants
TIMESTEP = 0.005  # s, MuJoCo physics step
FRAME_SKIP = 4  # physics steps per control step
DT = TIMESTEP * FRAME_SKIP  # s, control period
REST_ROOT_ANGLE = math.pi  # rad: the rest pose stretches the arm along -x
INIT_QPOS_NOISE = 0.1  # rad, half-width of the uniform joint-angle perturbation
INIT_QVEL_NOISE = 0.005  # rad/s, half-width of the uniform joint-velocity perturbation
CTRL_COST_WEIGHT = 0.1
ARM_Z = 0.02  # m, height of the arm plane (and of the button and target centres)

# ---------------------------------------------------------------- Reach
REACH_EPISODE_STEPS = 50
TARGET_RADIUS_MIN = 0.05  # m
TARGET_RADIUS_MAX = 0.25  # m; both arms reach 0.30 m
REACH_SUCCESS_DIST = 0.02  # m

# ---------------------------------------------------------------- Push
PUSH_EPISODE_STEPS = 100
CHANNEL_Y = 0.15  # m, y of the channel the button slides in
CHANNEL_HALF_LENGTH = 0.2  # m, the button's slide range is [-0.2, 0.2] in x
BUTTON_HALF_SIZE = 0.015  # m
GOAL_X = 0.06  # m
BUTTON_START_X = -0.08  # m, centre of the button start distribution
BUTTON_START_HALFWIDTH = 0.03  # m
GOAL_TOL = 0.01  # m, |button_x - goal_x| below which the button is at the goal
EE_SPEED_TOL = 0.05  # m/s, end-effector speed below which the arm counts as still
SETTLE_STEPS = 10  # consecutive control steps both must hold for success

_PUSH_FULL_TERMS = ("ee_button", "button_goal", "ctrl")
_PUSH_RESTRICTED_TERMS = ("button_goal",)
_REACH_TERMS = ("dist", "ctrl")


# ---------------------------------------------------------------- configs
@dataclass(frozen=True, kw_only=True)
class ReacherArmConfig:
    """Parameters shared by both Reacher tasks.

    ``link_lengths`` must match the agent's MJCF asset (it documents the geometry and is
    checked on construction); the rest can be changed with ``dataclasses.replace``.
    """

    agent: str
    link_lengths: tuple[float, ...]
    episode_steps: int
    timestep: float = TIMESTEP
    frame_skip: int = FRAME_SKIP
    rest_root_angle: float = REST_ROOT_ANGLE
    init_qpos_noise: float = INIT_QPOS_NOISE
    init_qvel_noise: float = INIT_QVEL_NOISE
    ctrl_cost_weight: float = CTRL_COST_WEIGHT


@dataclass(frozen=True, kw_only=True)
class ReacherReachConfig(ReacherArmConfig):
    """Reach task: targets in an annulus reachable by both arms."""

    episode_steps: int = REACH_EPISODE_STEPS
    target_radius_min: float = TARGET_RADIUS_MIN
    target_radius_max: float = TARGET_RADIUS_MAX
    success_dist: float = REACH_SUCCESS_DIST
    dist_weight: float = 1.0


@dataclass(frozen=True, kw_only=True)
class ReacherPushConfig(ReacherArmConfig):
    """Push task: button channel, goal, success thresholds and reward weights."""

    episode_steps: int = PUSH_EPISODE_STEPS
    channel_y: float = CHANNEL_Y
    goal_x: float = GOAL_X
    button_start_x: float = BUTTON_START_X
    button_start_halfwidth: float = BUTTON_START_HALFWIDTH
    goal_tol: float = GOAL_TOL
    ee_speed_tol: float = EE_SPEED_TOL
    settle_steps: int = SETTLE_STEPS
    ee_button_weight: float = 1.0
    button_goal_weight: float = 1.0
    terminate_on_success: bool = False


ReacherConfig = ReacherReachConfig | ReacherPushConfig


def _check_agent(agent: str) -> tuple[float, ...]:
    if agent not in AGENT_LINK_LENGTHS:
        raise PvedError(
            f"unknown Reacher agent {agent!r}; known agents: {', '.join(AGENT_LINK_LENGTHS)}"
        )
    return AGENT_LINK_LENGTHS[agent]


def default_config(agent: str = SOURCE_AGENT, task: str = "Reach") -> ReacherConfig:
    """The default parameters of ``agent`` ("Reacher3"/"Reacher4") on ``task``
    ("Reach"/"Push")."""
    links = _check_agent(agent)
    if task == "Reach":
        return ReacherReachConfig(agent=agent, link_lengths=links)
    if task == "Push":
        return ReacherPushConfig(agent=agent, link_lengths=links)
    raise PvedError(f"unknown Reacher task {task!r}; known tasks: {', '.join(TASKS)}")


def reward_terms(agent: str, task: str, reward: str = "default") -> tuple[str, ...]:
    """The reward terms summed for ``agent`` on ``task`` under ``reward`` mode.

    ``"default"`` is the paper's choice: full reward for the source agent, restricted
    (``button_goal`` only) for the target agent on Push. Reach has a single reward, which
    ``"default"`` and ``"full"`` name.
    """
    _check_agent(agent)
    full = _REACH_TERMS if task == "Reach" else _PUSH_FULL_TERMS
    target_agent = agent == TARGET_AGENT
    return select_reward_terms(
        reward, task, TASKS, "Reacher", target_agent, full, _PUSH_RESTRICTED_TERMS
    )


# ---------------------------------------------------------------- kinematics
def forward_kinematics(
    q: np.ndarray, qvel: np.ndarray, link_lengths: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """End-effector position and velocity of planar arms, in closed form.

    Computed from the joint state rather than read from ``MjData.site_xpos``, which after
    ``mj_step`` still describes the state before the last physics step.

    Args:
        q: (N, n) joint angles; qvel: (N, n) joint velocities; link_lengths: (n,).

    Returns:
        ee_pos (N, 2) and ee_vel (N, 2), in the world frame (root at the origin).
    """
    phi = np.cumsum(q, axis=1)  # absolute link angles
    dphi = np.cumsum(qvel, axis=1)
    cos_l = np.cos(phi) * link_lengths
    sin_l = np.sin(phi) * link_lengths
    ee = np.stack([cos_l.sum(axis=1), sin_l.sum(axis=1)], axis=1)
    ee_vel = np.stack([-(sin_l * dphi).sum(axis=1), (cos_l * dphi).sum(axis=1)], axis=1)
    return ee, ee_vel


def ee_jacobian(q: np.ndarray, link_lengths: np.ndarray) -> np.ndarray:
    """(N, 2, n) Jacobian d ee / d q of planar arms with joint angles q (N, n)."""
    phi = np.cumsum(q, axis=1)
    # Column k sums the contributions of links k..n-1: reverse cumulative sums.
    jx = -np.cumsum((np.sin(phi) * link_lengths)[:, ::-1], axis=1)[:, ::-1]
    jy = np.cumsum((np.cos(phi) * link_lengths)[:, ::-1], axis=1)[:, ::-1]
    return np.stack([jx, jy], axis=1)


def push_settled(
    button_x: np.ndarray, ee_vel: np.ndarray, goal_x: float, goal_tol: float, ee_speed_tol: float
) -> np.ndarray:
    """(N,) bool: button within ``goal_tol`` of the goal and end effector slower than
    ``ee_speed_tol``; success needs this for ``settle_steps`` steps in a row.

    Args:
        button_x: (N,) button x; ee_vel: (N, 2) end-effector velocity.
    """
    at_goal = np.abs(button_x - goal_x) < goal_tol
    still = np.linalg.norm(ee_vel, axis=1) < ee_speed_tol
    return at_goal & still


# ---------------------------------------------------------------- batched envs
class _ReacherBatched(HingeArmBatchedEnv):
    """State and observation of the robot part, common to both tasks; the arm's end
    point is the fingertip ``ee`` (joints ``joint0``.. from the root)."""

    config: ReacherConfig
    end_name = "ee"
    end_key = "ee_pos"

    def __init__(
        self, config: ReacherConfig, task: str, num_envs: int, reward: str, autoreset: bool
    ) -> None:
        n = len(_check_agent(config.agent))
        terms = reward_terms(config.agent, task, reward)
        self._check_timing(config)
        model = load_model(f"{config.agent.lower()}_{task.lower()}.xml")
        self.n_links = n
        self.link_lengths = self._asset_link_lengths(model, n)
        if not np.allclose(self.link_lengths, config.link_lengths, rtol=0, atol=1e-9):
            raise PvedError(
                f"config.link_lengths {tuple(config.link_lengths)} do not match the "
                f"{config.agent} asset {tuple(self.link_lengths.tolist())}"
            )
        names = tuple(f"joint{k}" for k in range(n))
        rest = np.zeros(n)
        rest[0] = config.rest_root_angle
        super().__init__(model, config, task, reward, terms, names, rest, 2, num_envs, autoreset)
        self.ee_vel = np.zeros((self.num_envs, 2))

    @property
    def ee_pos(self) -> np.ndarray:
        """(N, 2) end-effector xy of each copy (the arm's ``end_pos``)."""
        return self.end_pos

    @staticmethod
    def _asset_link_lengths(model: mujoco.MjModel, n: int) -> np.ndarray:
        """Link lengths as compiled: offsets of successive link bodies and the ee site."""
        lengths = [float(model.body(f"link{k + 1}").pos[0]) for k in range(n - 1)]
        lengths.append(float(model.site("ee").pos[0]))
        return np.asarray(lengths)

    def _derive(self, idx: np.ndarray | slice) -> None:
        q = self.qpos[idx][:, self._arm_qpos]
        qd = self.qvel[idx][:, self._arm_dof]
        self.end_pos[idx], self.ee_vel[idx] = forward_kinematics(q, qd, self.link_lengths)


class ReacherReachBatched(HingeArmReachBatchedEnv, _ReacherBatched):
    """N copies of ``pved/<agent>Reach-v0`` (see the module docstring).

    Args:
        agent: "Reacher3" or "Reacher4".
        num_envs: N.
        reward: "default" or "full" (the same single reward).
        config: a :class:`ReacherReachConfig` for ``agent`` (default: ``default_config``).
        autoreset: reset finished copies inside ``step``.
    """

    config: ReacherReachConfig

    def __init__(
        self,
        agent: str = SOURCE_AGENT,
        num_envs: int = 1,
        reward: str = "default",
        config: ReacherReachConfig | None = None,
        autoreset: bool = True,
    ) -> None:
        cfg = resolve_config(agent, "Reach", config, ReacherReachConfig, default_config)
        if not 0 <= cfg.target_radius_min < cfg.target_radius_max <= sum(cfg.link_lengths):
            raise PvedError("need 0 <= target_radius_min < target_radius_max <= arm reach")
        super().__init__(cfg, "Reach", num_envs, reward, autoreset)
        self._init_reach()

    @property
    def _num_reset_uniforms(self) -> int:
        return 2 * self.n_links + 2  # arm, then target radius and angle

    def _draw_target(self, task_u: np.ndarray) -> np.ndarray:
        cfg = self.config
        # Uniform by area in the annulus: r^2 uniform between the squared radii.
        r2 = cfg.target_radius_min**2 + task_u[:, 0] * (
            cfg.target_radius_max**2 - cfg.target_radius_min**2
        )
        theta = 2.0 * np.pi * task_u[:, 1]
        return np.sqrt(r2)[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=1)

    def _write_extra(self, i: int, data: mujoco.MjData) -> None:
        # The target is drawn only; its mocap body follows the task parameter.
        data.mocap_pos[0] = (self.target[i, 0], self.target[i, 1], ARM_Z)


class ReacherPushBatched(_ReacherBatched):
    """N copies of ``pved/<agent>Push-v0`` (see the module docstring).

    Args:
        agent: "Reacher3" or "Reacher4".
        num_envs: N.
        reward: "default" (full for Reacher3, restricted for Reacher4), "restricted"
            (``button_goal`` only) or "full" (``ee_button`` + ``button_goal`` + ``ctrl``).
        config: a :class:`ReacherPushConfig` for ``agent`` (default: ``default_config``).
        autoreset: reset finished copies inside ``step``.
    """

    config: ReacherPushConfig

    def __init__(
        self,
        agent: str = SOURCE_AGENT,
        num_envs: int = 1,
        reward: str = "default",
        config: ReacherPushConfig | None = None,
        autoreset: bool = True,
    ) -> None:
        cfg = resolve_config(agent, "Push", config, ReacherPushConfig, default_config)
        lo, hi = -CHANNEL_HALF_LENGTH, CHANNEL_HALF_LENGTH
        start_lo = cfg.button_start_x - cfg.button_start_halfwidth
        start_hi = cfg.button_start_x + cfg.button_start_halfwidth
        if not (lo < start_lo <= start_hi < hi and lo < cfg.goal_x < hi):
            raise PvedError(
                f"button start range and goal_x must lie inside the channel ({lo}, {hi})"
            )
        if cfg.goal_tol <= 0 or cfg.ee_speed_tol <= 0 or cfg.settle_steps < 1:
            raise PvedError("goal_tol and ee_speed_tol must be > 0 and settle_steps >= 1")
        super().__init__(cfg, "Push", num_envs, reward, autoreset)
        self._place_channel(cfg)
        model = self.model
        slide = model.joint("button_slide")
        self._button_qpos = int(slide.qposadr[0])
        self._button_dof = int(slide.dofadr[0])
        self.goal = np.array([cfg.goal_x, cfg.channel_y])
        self.button_start = np.zeros((self.num_envs, 2))
        self.settle_count = np.zeros(self.num_envs, dtype=np.int64)
        self.task_param_keys = ("button_start", "goal")
        self._set_observation_names(
            (
                *self.robot_observation_names,
                "button_x",
                "button_y",
                "button_vx",
                "goal_x",
                "goal_y",
                "button_minus_ee_x",
                "button_minus_ee_y",
            )
        )

    def _place_channel(self, cfg: ReacherPushConfig) -> None:
        """Move the channel (button body, walls) to ``channel_y`` and the goal bar to
        ``goal_x``; the asset holds the defaults."""
        model = self.model
        shift = cfg.channel_y - float(model.body("button").pos[1])
        model.body("button").pos[1] += shift
        for name in ("channel_lower", "channel_upper"):
            model.geom(name).pos[1] += shift
        model.geom("goal_bar").pos[:2] = (cfg.goal_x, cfg.channel_y)

    @property
    def _num_reset_uniforms(self) -> int:
        return 2 * self.n_links + 1  # arm, then button start

    def _get_task_state(self) -> dict[str, np.ndarray]:
        return {"button_start": self.button_start.copy(), "settle_count": self.settle_count.copy()}

    def _set_task_state(self, state: dict[str, np.ndarray]) -> None:
        self.button_start = np.asarray(state["button_start"], dtype=np.float64).copy()
        self.settle_count = np.asarray(state["settle_count"], dtype=np.int64).copy()

    @property
    def button_pos(self) -> np.ndarray:
        """(N, 2) button centre xy."""
        bx = self.qpos[:, self._button_qpos]
        return np.stack([bx, np.full_like(bx, self.config.channel_y)], axis=1)

    def _validate_options(self, options: dict[str, Any]) -> dict[str, np.ndarray]:
        unknown = set(options) - {"button_start"}
        if unknown:
            raise PvedError(f"unknown reset option(s) {sorted(unknown)}; Push takes 'button_start'")
        start = self._batched_option("button_start", options["button_start"], (2,))
        if np.any(np.abs(start[:, 1] - self.config.channel_y) > 1e-9):
            raise PvedError(f"button_start must lie on the channel y = {self.config.channel_y}")
        limit = CHANNEL_HALF_LENGTH - BUTTON_HALF_SIZE
        if np.any(np.abs(start[:, 0]) > limit):
            raise PvedError(f"button_start x must lie in [-{limit}, {limit}]")
        return {"button_start": start}

    def _initial_state(
        self, idx: np.ndarray, uniforms: np.ndarray, options: dict[str, np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        qpos, qvel = self._initial_arm(uniforms)
        task_u = uniforms[:, 2 * self.n_links :]
        start_x = cfg.button_start_x + cfg.button_start_halfwidth * (2.0 * task_u[:, 0] - 1.0)
        start = np.stack([start_x, np.full_like(start_x, cfg.channel_y)], axis=1)
        if options is not None and "button_start" in options:
            start = options["button_start"][idx]
        self.button_start[idx] = start
        self.settle_count[idx] = 0
        qpos[:, self._button_qpos] = start[:, 0]
        return qpos, qvel

    def _observe(self) -> np.ndarray:
        button = self.button_pos
        return np.concatenate(
            [
                self._robot_obs(),
                button,
                self.qvel[:, self._button_dof : self._button_dof + 1],
                np.broadcast_to(self.goal, (self.num_envs, 2)),
                button - self.ee_pos,
            ],
            axis=1,
        )

    def _evaluate(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, Info]:
        cfg = self.config
        button = self.button_pos
        terms = {
            "ee_button": -cfg.ee_button_weight * np.linalg.norm(self.ee_pos - button, axis=1),
            "button_goal": -cfg.button_goal_weight * np.linalg.norm(button - self.goal, axis=1),
            "ctrl": self._ctrl_term(actions),
        }
        reward, info = split_reward_terms(terms, self.reward_terms, self.num_envs)
        settled = push_settled(
            button[:, 0], self.ee_vel, cfg.goal_x, cfg.goal_tol, cfg.ee_speed_tol
        )
        self.settle_count = np.where(settled, self.settle_count + 1, 0)
        success = self.settle_count >= cfg.settle_steps
        info["is_success"] = success
        info["button_pos"] = button
        info["ee_pos"] = self.ee_pos.copy()
        terminated = success.copy() if cfg.terminate_on_success else np.zeros_like(success)
        return reward, terminated, info

    def _reset_info(self) -> Info:
        return {
            "is_success": self.settle_count >= self.config.settle_steps,
            "button_pos": self.button_pos,
            "ee_pos": self.ee_pos.copy(),
        }

    def _task_params(self) -> Info:
        return {
            "button_start": self.button_start.copy(),
            "goal": np.broadcast_to(self.goal, (self.num_envs, 2)).copy(),
        }


# ---------------------------------------------------------------- Gymnasium form
class ReacherReachEnv(BatchOfOneEnv):
    """``gymnasium.Env`` of the Reach task (a batch of one, no autoreset).

    Args: as :class:`ReacherReachBatched`, plus ``render_mode`` (None or "rgb_array")
    and the image ``width``/``height`` in pixels.
    """

    def __init__(
        self,
        agent: str = SOURCE_AGENT,
        reward: str = "default",
        config: ReacherReachConfig | None = None,
        render_mode: str | None = None,
        width: int = 240,
        height: int = 240,
    ) -> None:
        batched = ReacherReachBatched(agent, 1, reward=reward, config=config, autoreset=False)
        super().__init__(batched, render_mode=render_mode, width=width, height=height)


class ReacherPushEnv(BatchOfOneEnv):
    """``gymnasium.Env`` of the Push task (a batch of one, no autoreset).

    Args: as :class:`ReacherPushBatched`, plus ``render_mode`` (None or "rgb_array")
    and the image ``width``/``height`` in pixels.
    """

    def __init__(
        self,
        agent: str = SOURCE_AGENT,
        reward: str = "default",
        config: ReacherPushConfig | None = None,
        render_mode: str | None = None,
        width: int = 240,
        height: int = 240,
    ) -> None:
        batched = ReacherPushBatched(agent, 1, reward=reward, config=config, autoreset=False)
        super().__init__(batched, render_mode=render_mode, width=width, height=height)


__all__ = [
    "AGENT_LINK_LENGTHS",
    "BUTTON_START_HALFWIDTH",
    "BUTTON_START_X",
    "CHANNEL_Y",
    "DT",
    "EE_SPEED_TOL",
    "GOAL_TOL",
    "GOAL_X",
    "REACH_SUCCESS_DIST",
    "SETTLE_STEPS",
    "TARGET_RADIUS_MAX",
    "TARGET_RADIUS_MIN",
    "ReacherPushBatched",
    "ReacherPushConfig",
    "ReacherPushEnv",
    "ReacherReachBatched",
    "ReacherReachConfig",
    "ReacherReachEnv",
    "default_config",
    "ee_jacobian",
    "forward_kinematics",
    "push_settled",
    "reward_terms",
]
