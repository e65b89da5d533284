"""The robot-arm pair (paper IV.A, second agent pair): a 7-DoF Jaco and a 4-DoF Fetch arm.

Agents (both hold a peg rigidly in the gripper; only the peg and the table collide):

* ``Jaco`` (source): the Kinova Jaco 2 j2s7s300, seven revolute joints, written in
  ``assets/jaco7_arm.xml`` with robosuite's kinematics and link masses, capsule geoms.
* ``Fetch4`` (target): the arm of the Fetch robot as gymnasium-robotics 1.4.2 models it,
  loaded from the installed package at run time (``fetch/reach.xml``). The mobile base's
  slide joints, the torso lift, the head, the gripper fingers and FetchReach's mocap weld
  are removed (those bodies are fixed), and of the arm's seven joints the three rolls
  (``upperarm_roll``, ``forearm_roll``, ``wrist_roll``) are locked at 0, leaving
  ``shoulder_pan``, ``shoulder_lift``, ``elbow_flex`` and ``wrist_flex``: a yaw joint and
  three pitch joints, the fewest that still place the peg tip anywhere in the workspace
  and point the peg straight down (the paper: "we disable 3 of its joints").

Both arms' roots (the origin of the first joint: Jaco's joint 1, Fetch's shoulder pan) are
at ``ROOT_POS`` = (0, 0, 0.726) m, the Fetch's shoulder height with its torso lowered
("the same root location"); the table top is at z = ``TABLE_TOP_Z`` = 0.40 m from
x = 0.30 m on. Every joint of both arms has a torque motor ``JOINT_GEAR`` = 20 N m times the
action in [-1, 1], damping ``JOINT_DAMPING`` = 10 N m s/rad and armature ``JOINT_ARMATURE`` =
0.1 kg m^2 (a joint saturates near 2 rad/s); every moving body has ``gravcomp`` = 1 (the
arms' gravity-compensating joint controllers). Physics step 2 ms, 20 per control step:
control period ``DT`` = 0.04 s. Initial state ("similar random initial states"): the
agent's rest pose (peg tip at ``REST_TIP`` = (0.55, 0, 0.52) m, peg pointing down) plus
U(-0.05, 0.05) rad per joint, joint velocities U(-0.01, 0.01) rad/s.

Tasks:

* ``Reach`` (training task), 100 steps (4 s). The target is drawn uniformly in the box
  ``TARGET_LOW``..``TARGET_HIGH`` = [0.40, 0.70] x [-0.20, 0.20] x [0.50, 0.75] m, above the
  table and reachable by both arms. Reward = ``reward_dist`` + ``reward_ctrl``,
  ``reward_dist`` = -||tip - target|| (m), ``reward_ctrl`` = -0.01 ||a||^2. ``is_success``:
  ||tip - target|| < ``REACH_SUCCESS_DIST`` = 0.03 m. Never terminates.
* ``Peg`` (target task), 150 steps (6 s). A square hole (half-width ``HOLE_HALF_WIDTH`` =
  0.025 m, depth ``HOLE_DEPTH`` = 0.06 m) is cut in the table top, built from box geoms so
  the peg (radius 0.012 m) collides with its walls and can jam. The hole's xy is drawn
  uniformly in ``HOLE_CENTER_XY`` +- ``HOLE_RANGE`` = (0.55, 0) +- 0.05 m (the table moves
  with it). Terms: ``dist`` = -||tip - hole_mid|| with ``hole_mid`` the point on the hole's
  axis in the middle of its success zone (``HOLE_DEPTH - SUCCESS_DEPTH_TOL / 2`` = 0.05 m
  below the top surface: with the point at half the depth, the reward's optimum lay above
  the success zone and PPO learned to hover there), ``ctrl`` = -0.01 ||a||^2, and
  ``in_hole`` = +1 per step while the tip is inside the hole (xy within the opening, z
  below the table top).
  ``reward="full"`` sums ``dist`` + ``ctrl`` (the source's reward, default for Jaco),
  ``reward="restricted"`` only ``in_hole`` (the paper's sparse reward for the target
  agent, default for Fetch4); unused terms are reported as ``metric_<term>``.
  ``is_success``: the tip is within the opening in xy and at most ``SUCCESS_DEPTH_TOL`` =
  0.02 m above the hole's bottom (the bottom third of the hole). Never terminates unless
  ``terminate_on_success=True`` in the config.

Observation (float64), robot part first; ``robot_state_indices`` = ``arange(3n + 3)``, the
same for Reach and Peg of one agent (n joints):

* robot: cos q (n), sin q (n), qvel (n), peg tip xyz (3);
* Reach task part: target xyz (3), target - tip (3);
* Peg task part: hole_mid xyz (3), hole_mid - tip (3).

``info`` (batched: leading axis N) holds the reward terms, ``is_success``, the readout
``peg_tip`` (3,) of the step just taken (and ``hole_mid`` (3,) for Peg), and the task
parameters (``task_param_keys``): ``target`` (3,) (Reach) or ``hole`` (2,) (Peg).

Reset options: ``target`` (Reach, xyz) / ``hole`` (Peg, xy within ``HOLE_OPTION_RANGE`` =
0.15 m of ``HOLE_CENTER_XY`` per axis), of shape (3,)/(2,) for the Gymnasium form and
(N, 3)/(N, 2) or a single value for the batched form. Both agents of a pair given the same
option get the same target / hole.

One module past 600 lines on purpose: both arms share one scene (table, hole, peg), one
batched env and one reward; much of the length is this docstring's physical constants
and their reasons.
"""

from __future__ import annotations

import importlib.util
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from pved.envs.base import Info
from pved.envs.batched import (
    ASSETS_DIR,
    BatchOfOneEnv,
    joint_addresses,
    resolve_config,
    select_reward_terms,
    split_reward_terms,
)
from pved.envs.batched import REWARD_MODES as REWARD_MODES
from pved.envs.hinge_arm import HingeArmBatchedEnv, HingeArmReachBatchedEnv
from pved.errors import PvedError

# ---------------------------------------------------------------- agents
SOURCE_AGENT = "Jaco"
TARGET_AGENT = "Fetch4"
AGENTS = (SOURCE_AGENT, TARGET_AGENT)
TASKS = ("Reach", "Peg")

#: Joint names of each agent's controlled joints, root to gripper.
JACO_JOINTS = tuple(f"joint{k}" for k in range(1, 8))
FETCH_PREFIX = "fetch/"
FETCH_KEPT_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex")
#: Locked at 0: with the rolls gone the flex axes stay parallel, a yaw + 3-pitch arm.
FETCH_LOCKED_JOINTS = ("upperarm_roll", "forearm_roll", "wrist_roll")
#: Fetch joints of the rest of the robot, removed so their bodies are fixed.
FETCH_FIXED_JOINTS = (
    "slide0",
    "slide1",
    "slide2",
    "torso_lift",
    "head_pan",
    "head_tilt",
    "r_gripper_finger",
    "l_gripper_finger",
)
#: Fetch's shoulder-pan origin in its base_link frame with the torso lift at 0 (robot.xml:
#: torso_lift_link at (-0.0869, 0, 0.3774), shoulder_pan_link at (0.1195, 0, 0.3486)).
FETCH_PAN_IN_BASE = (0.0326, 0.0, 0.726)
GYMNASIUM_ROBOTICS_VERSION = "1.4.2"

# ---------------------------------------------------------------- shared constants
TIMESTEP = 0.002  # s, MuJoCo physics step
FRAME_SKIP = 20  # physics steps per control step
DT = TIMESTEP * FRAME_SKIP  # s, control period
ROOT_POS = (0.0, 0.0, 0.726)  # m, both arms' first-joint origin
TABLE_TOP_Z = 0.40  # m
JOINT_GEAR = 20.0  # N m of torque at action 1
JOINT_DAMPING = 10.0  # N m s/rad
JOINT_ARMATURE = 0.1  # kg m^2
PEG_RADIUS = 0.012  # m
PEG_LENGTH = 0.152  # m, from the gripper's peg_base site to the tip
REST_TIP = (0.55, 0.0, 0.52)  # m, peg tip at the rest pose (peg pointing down)
#: Rest poses (rad): peg tip at REST_TIP, peg pointing down (found by ``peg_tip_ik``).
REST_QPOS: dict[str, tuple[float, ...]] = {
    "Jaco": (3.1568, 4.0637, 0.0046, 1.7224, -0.0051, 3.9418, 0.0),
    "Fetch4": (0.0, -1.15, 1.602, 1.1189),
}
INIT_QPOS_NOISE = 0.05  # rad, half-width of the uniform joint-angle perturbation
INIT_QVEL_NOISE = 0.01  # rad/s, half-width of the uniform joint-velocity perturbation
CTRL_COST_WEIGHT = 0.01

# ---------------------------------------------------------------- Reach
REACH_EPISODE_STEPS = 100
TARGET_LOW = (0.40, -0.20, 0.50)  # m
TARGET_HIGH = (0.70, 0.20, 0.75)  # m
REACH_SUCCESS_DIST = 0.03  # m

# ---------------------------------------------------------------- Peg
PEG_EPISODE_STEPS = 150
HOLE_CENTER_XY = (0.55, 0.0)  # m, centre of the hole distribution
HOLE_RANGE = 0.05  # m, half-width of the uniform hole xy distribution, per axis
HOLE_OPTION_RANGE = 0.15  # m, how far a hole set through reset options may lie, per axis
HOLE_HALF_WIDTH = 0.025  # m, the opening is a 0.05 m square
HOLE_DEPTH = 0.06  # m
SUCCESS_DEPTH_TOL = 0.02  # m, tip at most this far above the hole's bottom
IN_HOLE_REWARD = 1.0  # per control step with the tip inside the hole

_REACH_TERMS = ("dist", "ctrl")
_PEG_FULL_TERMS = ("dist", "ctrl")
_PEG_RESTRICTED_TERMS = ("in_hole",)


# ---------------------------------------------------------------- configs
@dataclass(frozen=True, kw_only=True)
class ArmConfig:
    """Parameters shared by both arm tasks (change them with ``dataclasses.replace``)."""

    agent: str
    episode_steps: int
    timestep: float = TIMESTEP
    frame_skip: int = FRAME_SKIP
    init_qpos_noise: float = INIT_QPOS_NOISE
    init_qvel_noise: float = INIT_QVEL_NOISE
    ctrl_cost_weight: float = CTRL_COST_WEIGHT
    joint_gear: float = JOINT_GEAR
    joint_damping: float = JOINT_DAMPING
    joint_armature: float = JOINT_ARMATURE


@dataclass(frozen=True, kw_only=True)
class ArmReachConfig(ArmConfig):
    """Reach task: a target box reachable by both arms."""

    episode_steps: int = REACH_EPISODE_STEPS
    target_low: tuple[float, float, float] = TARGET_LOW
    target_high: tuple[float, float, float] = TARGET_HIGH
    success_dist: float = REACH_SUCCESS_DIST
    dist_weight: float = 1.0


@dataclass(frozen=True, kw_only=True)
class ArmPegConfig(ArmConfig):
    """Peg task: hole distribution, success tolerance and reward weights (the hole's
    size is fixed by ``assets/arm_peg_task.xml``)."""

    episode_steps: int = PEG_EPISODE_STEPS
    hole_center_xy: tuple[float, float] = HOLE_CENTER_XY
    hole_range: float = HOLE_RANGE
    success_depth_tol: float = SUCCESS_DEPTH_TOL
    dist_weight: float = 1.0
    in_hole_reward: float = IN_HOLE_REWARD
    terminate_on_success: bool = False


ArmTaskConfig = ArmReachConfig | ArmPegConfig


def _check_agent(agent: str) -> None:
    if agent not in AGENTS:
        raise PvedError(f"unknown arm agent {agent!r}; known agents: {', '.join(AGENTS)}")


def default_config(agent: str = SOURCE_AGENT, task: str = "Reach") -> ArmTaskConfig:
    """The default parameters of ``agent`` ("Jaco"/"Fetch4") on ``task`` ("Reach"/"Peg")."""
    _check_agent(agent)
    if task == "Reach":
        return ArmReachConfig(agent=agent)
    if task == "Peg":
        return ArmPegConfig(agent=agent)
    raise PvedError(f"unknown arm task {task!r}; known tasks: {', '.join(TASKS)}")


def reward_terms(agent: str, task: str, reward: str = "default") -> tuple[str, ...]:
    """The reward terms summed for ``agent`` on ``task`` under ``reward`` mode.

    ``"default"`` is the paper's choice: the full reward (``dist`` + ``ctrl``) for Jaco,
    the restricted one (``in_hole`` only, sparse) for Fetch4 on Peg. Reach has a single
    reward, which ``"default"`` and ``"full"`` name.
    """
    _check_agent(agent)
    full = _REACH_TERMS if task == "Reach" else _PEG_FULL_TERMS
    target_agent = agent == TARGET_AGENT
    return select_reward_terms(
        reward, task, TASKS, "arm", target_agent, full, _PEG_RESTRICTED_TERMS
    )


# ---------------------------------------------------------------- models
def fetch_asset_path() -> Path:
    """Path of gymnasium-robotics' ``fetch/reach.xml`` in the installed package.

    Found without importing ``gymnasium_robotics`` (its import registers many envs and
    prints notices); raises :class:`PvedError` if the package is missing.
    """
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or not spec.submodule_search_locations:
        raise PvedError(
            f"the Fetch4 envs need gymnasium-robotics=={GYMNASIUM_ROBOTICS_VERSION} "
            f"(pip install gymnasium-robotics=={GYMNASIUM_ROBOTICS_VERSION})"
        )
    path = Path(next(iter(spec.submodule_search_locations))) / "envs/assets/fetch/reach.xml"
    if not path.is_file():
        raise PvedError(f"gymnasium-robotics has no Fetch model at {path}")
    return path


def _fetch_arm_spec() -> mujoco.MjSpec:
    """The Fetch robot of gymnasium-robotics, cut down to the 4-DoF arm."""
    spec = mujoco.MjSpec.from_file(str(fetch_asset_path()))
    for name in (*FETCH_FIXED_JOINTS, *FETCH_LOCKED_JOINTS):
        spec.delete(spec.joint(f"robot0:{name}_joint" if "slide" not in name else f"robot0:{name}"))
    for eq in list(spec.equalities):  # FetchReach's mocap weld on the gripper
        spec.delete(eq)
    for geom in spec.geoms:  # visual only: the peg is the arm's one colliding geom
        geom.contype = 0
        geom.conaffinity = 0
    for body in spec.bodies:
        body.gravcomp = 1.0
    for texture in list(spec.textures):  # one look for both scenes: no green sky
        if texture.type == mujoco.mjtTexture.mjTEXTURE_SKYBOX:
            spec.delete(texture)
    return spec


def build_model(agent: str, task: str) -> mujoco.MjModel:
    """Compile ``agent``'s scene for ``task``: the scene asset ``<agent>_<task>.xml`` plus,
    for Fetch4, the arm from gymnasium-robotics attached at the frame ``robot_mount``."""
    _check_agent(agent)
    if task not in TASKS:
        raise PvedError(f"unknown arm task {task!r}; known tasks: {', '.join(TASKS)}")
    name = "jaco7" if agent == "Jaco" else "fetch4"
    path = ASSETS_DIR / f"{name}_{task.lower()}.xml"
    if not path.is_file():
        raise PvedError(f"missing MJCF asset {path}")
    if agent == "Jaco":
        return mujoco.MjModel.from_xml_path(str(path))
    scene = mujoco.MjSpec.from_file(str(path))
    arm = _fetch_arm_spec()
    base = arm.body("robot0:base_link")
    # Place the base so the shoulder-pan origin lands on the mount frame (= ROOT_POS).
    base.pos = [-c for c in FETCH_PAN_IN_BASE]
    base.quat = [1.0, 0.0, 0.0, 0.0]
    scene.frame("robot_mount").attach_body(base, FETCH_PREFIX, "")
    # The peg is added after attaching so that its geom and sites are named as Jaco's.
    gripper = scene.body(f"{FETCH_PREFIX}robot0:gripper_link")
    # The peg lies along the gripper's x (its pointing direction), between the fingers.
    gripper.add_geom(
        name="peg",
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        fromto=[-0.01, 0, 0, 0.13, 0, 0],
        size=[PEG_RADIUS, 0, 0],
        contype=2,
        conaffinity=2,
        condim=3,
        friction=[0.5, 0.005, 0.0001],
        solref=[0.01, 1.0],
        solimp=[0.95, 0.99, 0.001, 0.5, 2.0],
        mass=0.0,
        rgba=[0.95, 0.55, 0.1, 1.0],
        material="",  # not the gripper class's material (renamed by the attach prefix)
        margin=0.0,
    )
    gripper.add_site(name="peg_base", pos=[-0.01, 0, 0], size=[0.004, 0, 0])
    gripper.add_site(name="peg_tip", pos=[0.13 + PEG_RADIUS, 0, 0], size=[0.004, 0, 0])
    for name in FETCH_KEPT_JOINTS:
        scene.add_actuator(
            name=f"motor_{name}",
            target=f"{FETCH_PREFIX}robot0:{name}_joint",
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            ctrllimited=True,
            ctrlrange=[-1.0, 1.0],
            gear=[JOINT_GEAR, 0, 0, 0, 0, 0],
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return scene.compile()


def agent_joint_names(agent: str) -> tuple[str, ...]:
    """Full MuJoCo names of ``agent``'s controlled joints, root to gripper."""
    _check_agent(agent)
    if agent == "Jaco":
        return JACO_JOINTS
    return tuple(f"{FETCH_PREFIX}robot0:{n}_joint" for n in FETCH_KEPT_JOINTS)


# ---------------------------------------------------------------- kinematics
def peg_tip_ik(
    model: mujoco.MjModel,
    targets: np.ndarray,
    q0: np.ndarray,
    qpos_adr: np.ndarray,
    dof_adr: np.ndarray,
    point_down: bool = False,
    iterations: int = 100,
    damping: float = 1e-3,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles putting the peg tip at ``targets`` (and the peg vertical, tip down, if
    ``point_down``), by damped least squares from ``q0``, clipped to the joint limits.

    For tests, rest poses and scripted demonstrations, not for the simulation.

    Args:
        model: a compiled arm model (sites ``peg_tip`` and ``peg_base``).
        targets: (M, 3) tip positions (m); q0: (M, n) initial joint angles (rad).
        qpos_adr, dof_adr: (n,) qpos / dof addresses of the arm's joints.
        point_down: also align the peg with -z.
        iterations: DLS steps; damping: the DLS regulariser (m^2).

    Returns:
        q (M, n) and the residual tip error (M,) in m.
    """
    data = mujoco.MjData(model)
    tip_id, base_id = model.site("peg_tip").id, model.site("peg_base").id
    jnt_range = model.jnt_range[model.dof_jntid[dof_adr]]
    limited = model.jnt_limited[model.dof_jntid[dof_adr]].astype(bool)
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    out = np.array(q0, dtype=np.float64, copy=True)
    residual = np.zeros(len(out))
    down = np.array([0.0, 0.0, -1.0])
    for m, target in enumerate(np.asarray(targets, dtype=np.float64)):
        q = out[m]
        for it in range(iterations + 1):
            data.qpos[qpos_adr] = q
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            err = target - data.site_xpos[tip_id]
            mujoco.mj_jacSite(model, data, jacp, jacr, tip_id)
            rows, errs = [jacp[:, dof_adr]], [err]
            if point_down:
                axis = data.site_xpos[tip_id] - data.site_xpos[base_id]
                axis /= np.linalg.norm(axis)
                # Rotations about the peg axis do not matter: project them out.
                proj = np.eye(3) - np.outer(axis, axis)
                rows.append(0.3 * proj @ jacr[:, dof_adr])
                errs.append(0.3 * np.cross(axis, down))
            jac, e = np.concatenate(rows), np.concatenate(errs)
            if it == iterations:  # last pass only measures the residual
                break
            step = jac.T @ np.linalg.solve(jac @ jac.T + damping * np.eye(len(e)), e)
            q = q + step
            q[limited] = np.clip(q[limited], jnt_range[limited, 0], jnt_range[limited, 1])
        out[m] = q
        residual[m] = float(np.linalg.norm(err))
    return out, residual


def peg_in_hole(
    tip: np.ndarray, hole_xy: np.ndarray, half_width: float, top_z: float
) -> np.ndarray:
    """(N,) bool: the tip (N, 3) is inside the hole, i.e. within the square opening of
    half-width ``half_width`` (m) around ``hole_xy`` (N, 2) and below the top ``top_z``."""
    inside_xy = np.all(np.abs(tip[:, :2] - hole_xy) < half_width, axis=1)
    return inside_xy & (tip[:, 2] < top_z)


def peg_inserted(
    tip: np.ndarray, hole_xy: np.ndarray, half_width: float, bottom_z: float, tol: float
) -> np.ndarray:
    """(N,) bool: success, the tip is within the opening and at most ``tol`` (m) above the
    hole's bottom ``bottom_z``."""
    inside_xy = np.all(np.abs(tip[:, :2] - hole_xy) < half_width, axis=1)
    return inside_xy & (tip[:, 2] < bottom_z + tol)


# ---------------------------------------------------------------- batched envs
class _ArmBatched(HingeArmBatchedEnv):
    """State and observation of the robot part, common to both tasks; the arm's end
    point is the peg tip."""

    config: ArmTaskConfig
    end_name = "tip"
    end_key = "peg_tip"

    def __init__(
        self, config: ArmTaskConfig, task: str, num_envs: int, reward: str, autoreset: bool
    ) -> None:
        terms = reward_terms(config.agent, task, reward)
        self._check_timing(config)
        model = build_model(config.agent, task)
        names = agent_joint_names(config.agent)
        _, arm_dof = joint_addresses(model, names)
        if model.nu != len(names) or model.nq != len(names):
            raise PvedError(f"{config.agent} model has nq={model.nq}, nu={model.nu}")
        # One set of joint dynamics for both arms (module docstring).
        model.dof_damping[arm_dof] = config.joint_damping
        model.dof_armature[arm_dof] = config.joint_armature
        model.actuator_gear[:, 0] = config.joint_gear
        rest = REST_QPOS[config.agent]
        super().__init__(model, config, task, reward, terms, names, rest, 3, num_envs, autoreset)
        self._tip_site = model.site("peg_tip").id

    @property
    def peg_tip(self) -> np.ndarray:
        """(N, 3) peg tip position of each copy (the arm's ``end_pos``)."""
        return self.end_pos

    def _derive(self, idx: np.ndarray | slice) -> None:
        # After mj_step the site positions describe the state before the last physics
        # step; forward kinematics (cheap) brings them to the current qpos.
        tip_id = self._tip_site
        for i in np.arange(self.num_envs)[idx]:
            data = self.datas[i]
            mujoco.mj_kinematics(self.model, data)
            self.end_pos[i] = data.site_xpos[tip_id]

    def ik(
        self, targets: np.ndarray, point_down: bool = False, q0: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joint angles (M, n) putting the peg tip at ``targets`` (M, 3) (see
        :func:`peg_tip_ik`; starts from the rest pose) and the residuals (M,) in m."""
        targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
        start = np.broadcast_to(self.rest_qpos if q0 is None else q0, (len(targets), self.n_joints))
        return peg_tip_ik(
            self.model, targets, start, self._arm_qpos, self._arm_dof, point_down=point_down
        )


class ArmReachBatched(HingeArmReachBatchedEnv, _ArmBatched):
    """N copies of ``pved/<agent>Reach-v0`` (see the module docstring).

    Args:
        agent: "Jaco" or "Fetch4".
        num_envs: N.
        reward: "default" or "full" (the same single reward).
        config: an :class:`ArmReachConfig` for ``agent`` (default: ``default_config``).
        autoreset: reset finished copies inside ``step``.
    """

    config: ArmReachConfig

    def __init__(
        self,
        agent: str = SOURCE_AGENT,
        num_envs: int = 1,
        reward: str = "default",
        config: ArmReachConfig | None = None,
        autoreset: bool = True,
    ) -> None:
        cfg = resolve_config(agent, "Reach", config, ArmReachConfig, default_config)
        if not np.all(np.asarray(cfg.target_low) < np.asarray(cfg.target_high)):
            raise PvedError("need target_low < target_high on every axis")
        super().__init__(cfg, "Reach", num_envs, reward, autoreset)
        self._init_reach()

    @property
    def _num_reset_uniforms(self) -> int:
        return 2 * self.n_joints + 3  # arm, then target xyz

    def _draw_target(self, task_u: np.ndarray) -> np.ndarray:
        low, high = np.asarray(self.config.target_low), np.asarray(self.config.target_high)
        return low + (high - low) * task_u

    def _write_extra(self, i: int, data: mujoco.MjData) -> None:
        # The target is drawn only; its mocap body follows the task parameter.
        data.mocap_pos[0] = self.target[i]


class ArmPegBatched(_ArmBatched):
    """N copies of ``pved/<agent>Peg-v0`` (see the module docstring).

    Args:
        agent: "Jaco" or "Fetch4".
        num_envs: N.
        reward: "default" (full for Jaco, restricted for Fetch4), "restricted"
            (``in_hole`` only) or "full" (``dist`` + ``ctrl``).
        config: an :class:`ArmPegConfig` for ``agent`` (default: ``default_config``).
        autoreset: reset finished copies inside ``step``.
    """

    config: ArmPegConfig

    def __init__(
        self,
        agent: str = SOURCE_AGENT,
        num_envs: int = 1,
        reward: str = "default",
        config: ArmPegConfig | None = None,
        autoreset: bool = True,
    ) -> None:
        cfg = resolve_config(agent, "Peg", config, ArmPegConfig, default_config)
        if not 0 <= cfg.hole_range <= HOLE_OPTION_RANGE:
            raise PvedError(f"hole_range must lie in [0, {HOLE_OPTION_RANGE}] m")
        if not 0 < cfg.success_depth_tol < HOLE_DEPTH:
            raise PvedError(f"success_depth_tol must lie in (0, {HOLE_DEPTH}) m")
        super().__init__(cfg, "Peg", num_envs, reward, autoreset)
        self.hole = np.zeros((self.num_envs, 2))
        self.hole_top_z = TABLE_TOP_Z
        self.hole_bottom_z = TABLE_TOP_Z - HOLE_DEPTH
        self.task_param_keys = ("hole",)
        self._set_observation_names(
            (
                *self.robot_observation_names,
                "hole_mid_x",
                "hole_mid_y",
                "hole_mid_z",
                "hole_mid_minus_tip_x",
                "hole_mid_minus_tip_y",
                "hole_mid_minus_tip_z",
            )
        )

    @property
    def hole_mid(self) -> np.ndarray:
        """(N, 3) the reward's point in each copy's hole: on its axis, in the middle of
        the success zone (the bottom ``SUCCESS_DEPTH_TOL`` of the hole)."""
        z = np.full((self.num_envs, 1), TABLE_TOP_Z - HOLE_DEPTH + 0.5 * SUCCESS_DEPTH_TOL)
        return np.concatenate([self.hole, z], axis=1)

    @property
    def _num_reset_uniforms(self) -> int:
        return 2 * self.n_joints + 2  # arm, then hole xy

    def _validate_options(self, options: dict[str, Any]) -> dict[str, np.ndarray]:
        unknown = set(options) - {"hole"}
        if unknown:
            raise PvedError(f"unknown reset option(s) {sorted(unknown)}; Peg takes 'hole'")
        hole = self._batched_option("hole", options["hole"], (2,))
        if np.any(np.abs(hole - np.asarray(self.config.hole_center_xy)) > HOLE_OPTION_RANGE):
            raise PvedError(
                f"hole must lie within {HOLE_OPTION_RANGE} m of {self.config.hole_center_xy} "
                "on each axis"
            )
        return {"hole": hole}

    def _initial_state(
        self, idx: np.ndarray, uniforms: np.ndarray, options: dict[str, np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        qpos, qvel = self._initial_arm(uniforms)
        task_u = uniforms[:, 2 * self.n_joints :]
        hole = np.asarray(cfg.hole_center_xy) + cfg.hole_range * (2.0 * task_u - 1.0)
        if options is not None and "hole" in options:
            hole = options["hole"][idx]
        self.hole[idx] = hole
        return qpos, qvel

    def _get_task_state(self) -> dict[str, np.ndarray]:
        return {"hole": self.hole.copy()}

    def _set_task_state(self, state: dict[str, np.ndarray]) -> None:
        self.hole = np.asarray(state["hole"], dtype=np.float64).copy()

    def _write_extra(self, i: int, data: mujoco.MjData) -> None:
        # The table (with its hole) is one mocap body whose origin is the opening's centre.
        data.mocap_pos[0] = (self.hole[i, 0], self.hole[i, 1], TABLE_TOP_Z)

    def _observe(self) -> np.ndarray:
        mid = self.hole_mid
        return np.concatenate([self._robot_obs(), mid, mid - self.peg_tip], axis=1)

    def _evaluate(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, Info]:
        cfg = self.config
        tip = self.peg_tip
        inside = peg_in_hole(tip, self.hole, HOLE_HALF_WIDTH, self.hole_top_z)
        terms = {
            "dist": -cfg.dist_weight * np.linalg.norm(tip - self.hole_mid, axis=1),
            "ctrl": self._ctrl_term(actions),
            "in_hole": cfg.in_hole_reward * inside.astype(np.float64),
        }
        reward, info = split_reward_terms(terms, self.reward_terms, self.num_envs)
        success = self._success()
        info["is_success"] = success
        info["peg_tip"] = tip.copy()
        info["hole_mid"] = self.hole_mid
        terminated = success.copy() if cfg.terminate_on_success else np.zeros_like(success)
        return reward, terminated, info

    def _success(self) -> np.ndarray:
        return peg_inserted(
            self.peg_tip,
            self.hole,
            HOLE_HALF_WIDTH,
            self.hole_bottom_z,
            self.config.success_depth_tol,
        )

    def _reset_info(self) -> Info:
        return {
            "is_success": self._success(),
            "peg_tip": self.peg_tip.copy(),
            "hole_mid": self.hole_mid,
        }

    def _task_params(self) -> Info:
        return {"hole": self.hole.copy()}


# ---------------------------------------------------------------- Gymnasium form
class ArmReachEnv(BatchOfOneEnv):
    """``gymnasium.Env`` of the arm Reach task (a batch of one, no autoreset).

    Args: as :class:`ArmReachBatched`, plus ``render_mode`` (None or "rgb_array") and the
    image ``width``/``height`` in pixels (rendered from the camera "view").
    """

    def __init__(
        self,
        agent: str = SOURCE_AGENT,
        reward: str = "default",
        config: ArmReachConfig | None = None,
        render_mode: str | None = None,
        width: int = 240,
        height: int = 240,
    ) -> None:
        batched = ArmReachBatched(agent, 1, reward=reward, config=config, autoreset=False)
        super().__init__(
            batched, render_mode=render_mode, width=width, height=height, camera="view"
        )


class ArmPegEnv(BatchOfOneEnv):
    """``gymnasium.Env`` of the Peg task (a batch of one, no autoreset).

    Args: as :class:`ArmPegBatched`, plus ``render_mode`` (None or "rgb_array") and the
    image ``width``/``height`` in pixels (rendered from the camera "view").
    """

    def __init__(
        self,
        agent: str = SOURCE_AGENT,
        reward: str = "default",
        config: ArmPegConfig | None = None,
        render_mode: str | None = None,
        width: int = 240,
        height: int = 240,
    ) -> None:
        batched = ArmPegBatched(agent, 1, reward=reward, config=config, autoreset=False)
        super().__init__(
            batched, render_mode=render_mode, width=width, height=height, camera="view"
        )


__all__ = [
    "AGENTS",
    "DT",
    "FETCH_KEPT_JOINTS",
    "FETCH_LOCKED_JOINTS",
    "HOLE_CENTER_XY",
    "HOLE_DEPTH",
    "HOLE_HALF_WIDTH",
    "HOLE_RANGE",
    "REACH_SUCCESS_DIST",
    "REST_QPOS",
    "ROOT_POS",
    "SUCCESS_DEPTH_TOL",
    "TABLE_TOP_Z",
    "TARGET_HIGH",
    "TARGET_LOW",
    "ArmPegBatched",
    "ArmPegConfig",
    "ArmPegEnv",
    "ArmReachBatched",
    "ArmReachConfig",
    "ArmReachEnv",
    "agent_joint_names",
    "build_model",
    "default_config",
    "fetch_asset_path",
    "peg_in_hole",
    "peg_inserted",
    "peg_tip_ik",
    "reward_terms",
]
