"""The locomotion pairs (paper IV.A): Walker2d -> Hopper and Humanoid -> Ant, on Slope and Curve.

Bodies: Gymnasium's v5 models, read at run time from the installed gymnasium package
(``walker2d_v5.xml``, ``hopper.xml``, ``humanoid.xml``, ``ant.xml``) and given a terrain
with ``mujoco.MjSpec``; nothing of their XML is copied into this repository. Each keeps its
own physics step and v5's frame skip, so the control periods are Walker2d and Hopper
0.008 s (0.002 s x 4), Humanoid 0.015 s (0.003 s x 5) and Ant 0.05 s (0.01 s x 5).

Terrain (profiles in :mod:`pved.envs.terrain`), with the contact parameters, material
and colour of the model's own floor:

* ``Slope``: the floor plane moved onto a mocap body and tilted about y by the episode's
  angle theta, drawn uniformly in [2, 10] deg (``slope_deg``). The tilt lives in
  ``MjData.mocap_quat``, so each copy of the one shared ``MjModel`` has its own slope, set
  once per reset at no per-step cost, and contacts, rays and rendering all see it.
  ``reset(options={"slope_deg": ...})`` fixes the angle (so both agents of a pair climb the
  same slope); accepted range [-``MAX_SLOPE_OPTION_DEG``, ``MAX_SLOPE_OPTION_DEG``].
* ``Curve``: phi(x) = 10 deg * clip(x / 12 m, 0, 1), z(x) its integral of tan(phi). The
  curve is convex, so the solid below it is the union of two pieces, each exact on its
  part: a heightfield over -``CURVE_FLAT_BEHIND`` = -50 m <= x <= 12 m (flat behind the
  start; 2 rows across ``CURVE_HFIELD_HALF_WIDTH`` = 1 km of y, one column every
  ``CURVE_HFIELD_DX`` = 0.2 m along x; between columns it is linear, so above the curve by
  at most dx^2 max(z'')/8 = 0.08 mm) and the tangent plane at x = 12 m (10 deg), which lies
  below the curve for x < 12 m and *is* the curve beyond, so the terrain continues
  indefinitely along +x. The v5 floor is removed (under the heightfield's flat part it would
  double every contact near the start); behind x = -50 m the ground ends.

Episodes: ``EPISODE_STEPS`` = 1000 control steps (truncation); terminated when unhealthy.
Every episode starts at torso x = 0 (v5's reset noise is applied to every other
coordinate), so ``info["x_position"]`` at the end is the distance travelled along x, the
paper's metric for Curve ("mean distance traveled along the x-axis in 1000 timesteps").
The start pose is v5's default pose raised above the local terrain: its root height is
v5's plus z(0) plus the smallest lift that keeps every collidable geom's bounding box at
least ``INIT_CLEARANCE`` = 1 cm above the terrain under it (no lift where v5's pose already
clears the ground, e.g. on the flat start of Curve). A reset draws one uniform for the task
first (Slope's angle; unused on Curve), then v5's qpos and qvel noise (Ant: normal qvel
noise, by Box-Muller), so one seed gives both agents of a pair the same slope and one
agent the same start noise on Slope and Curve; the free joints' quaternion is renormalised
after v5's entrywise noise.

Health (v5's ranges, judged against the terrain under the torso): the torso height above
the terrain, ``h = z_torso - z(x_torso)``, must lie in ``healthy_height_range`` (Walker2d
(0.8, 2.0) m, Hopper (0.7, inf), Humanoid (1.0, 2.0), Ant (0.2, 1.0)). Walker2d and Hopper
also check the torso pitch (Walker2d (-1, 1) rad, Hopper (-0.2, 0.2)) and Hopper v5's
state range (|qpos[2:]|, |qvel| < 100). The pitch is measured from the vertical of gravity
by default: balance is about gravity, and measuring it from the slope normal would shift
the allowed range by phi towards falling downhill (a vertical Hopper on a 10 deg slope
would already be at 0.17 of its 0.2 rad limit). ``healthy_angle_reference="terrain"`` in
the config measures it from the local slope normal instead (pitch + phi). Every agent is
also unhealthy when its state is not finite.

Observation (float64), robot part first:

* robot part (``robot_state_indices`` = ``arange(robot_dim)``, the same on Slope and
  Curve): torso height above the terrain h (1), v5's positions without x (Walker2d/Hopper:
  pitch and joint angles, ``qpos[2:]``; Humanoid/Ant: root quaternion and joint angles,
  ``qpos[3:]``; the world z that v5 keeps is replaced by h, which means the same anywhere on
  any terrain), joint velocities ``qvel`` (clipped to +-10 for Walker2d/Hopper as in v5).
  Dimensions: Walker2d 17, Hopper 11, Humanoid 45, Ant 27.
* v5's extra observations (``extra_observations``): Humanoid ``cinert`` (130), ``cvel``
  (78), ``qfrc_actuator`` of the joints (17) and ``cfrc_ext`` (78) of its 13 bodies (on by
  default, as in v5); Ant the external contact forces ``cfrc_ext`` of its 13 bodies clipped
  to [-1, 1] (78; off by default, as in v4 and in effect in the paper's Gym, where they
  read zero: PPO on Ant did not learn with them, docs/decisions.md). They are derived
  quantities (masses, contact forces) rather than the robot's state, so they are not in
  ``robot_state_indices``.
* terrain part: the local slope angle phi(x_torso) (rad) (1).

Observation sizes: Walker2d 18, Hopper 12, Humanoid 349, Ant 28 (106 with its extras).

Reward terms (v5's weights), reported in ``info`` as ``reward_<term>``:
``forward`` = w_f * (x_torso after - before) / dt (Walker2d/Hopper/Ant w_f = 1, Humanoid
1.25; torso x for every agent, so its sum over an episode is the distance metric times
w_f / dt); ``healthy`` = alive bonus while healthy (1; Humanoid 5); ``ctrl`` = -w_c ||a||^2
(Walker2d/Hopper 1e-3, Ant 0.5, Humanoid 0.1); ``contact`` (Ant, Humanoid only) = -5e-4 *
sum(clip(cfrc_ext, -1, 1)^2) (Ant) or -min(5e-7 * sum(cfrc_ext^2), 10) (Humanoid). The
reward is the sum of the terms of the reward mode; the others are reported as
``metric_<term>`` and not summed:

* ``"full"``: every term of the agent (the source agents' composition);
* ``"restricted"`` (Curve only): the paper's target-task reward of the pair: Walker2d and
  Hopper get the alive bonus and control cost but no forward term ("the reward only
  includes a bonus for not falling"); Humanoid and Ant keep every term ("for the target
  agent on the target task, we still include the velocity along positive x");
* ``"default"``: restricted for the target agents (Hopper, Ant) on Curve, full otherwise.

``info`` also holds ``x_position`` (torso x, m), ``x_velocity`` (m/s, steps only),
``torso_height`` (h, m) and ``local_slope_deg`` (phi(x_torso), deg), and on Slope the task
parameter ``slope_deg`` (``task_param_keys``; Curve has none).

One module past 600 lines on purpose: both locomotion pairs share one model builder, one
way of laying terrain and one batched env, differing only in their tables of agents and
terrains; much of the length is this docstring's physics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import mujoco
import numpy as np

from pved.envs.base import Info
from pved.envs.batched import REWARD_MODES as REWARD_MODES
from pved.envs.batched import (
    BatchOfOneEnv,
    MujocoBatchedEnv,
    select_reward_terms,
    split_reward_terms,
)
from pved.envs.terrain import (
    CURVE_MAX_DEG,
    CURVE_RAMP_LENGTH,
    SLOPE_DEG_RANGE,
    curve_angle,
    curve_height,
    draw_slope_deg,
    plane_quat,
    slope_angle,
    slope_height,
)
from pved.errors import PvedError

# ---------------------------------------------------------------- agents and tasks
AGENTS = ("Walker2d", "Hopper", "Humanoid", "Ant")
#: The target agent of each pair and its source (paper IV.A).
SOURCE_OF_TARGET: dict[str, str] = {"Hopper": "Walker2d", "Ant": "Humanoid"}
TARGET_AGENTS = tuple(SOURCE_OF_TARGET)
TASKS = ("Slope", "Curve")
#: Gymnasium v5's model file of each agent (in gymnasium/envs/mujoco/assets).
AGENT_XML: dict[str, str] = {
    "Walker2d": "walker2d_v5.xml",
    "Hopper": "hopper.xml",
    "Humanoid": "humanoid.xml",
    "Ant": "ant.xml",
}
#: Agents whose root is planar (slide x, slide z, hinge pitch) rather than a free joint.
PLANAR_AGENTS = ("Walker2d", "Hopper")

# ---------------------------------------------------------------- shared constants
EPISODE_STEPS = 1000  # control steps (paper: distance "in 1000 timesteps")
CAMERA = "track"  # the v5 models' own camera that follows the agent's centre of mass
FLOOR_GEOM = "floor"  # the v5 models' ground plane
TORSO_BODY = "torso"
#: Column spacing (m) of the Curve heightfield along x; chord error dx^2 z''/8 = 0.08 mm.
CURVE_HFIELD_DX = 0.2
#: Length (m) of the Curve heightfield's flat part behind the start (x < 0): farther than an
#: agent walks backwards in an episode; beyond it the ground ends.
CURVE_FLAT_BEHIND = 50.0
#: Half-width (m) of the Curve heightfield along y: far beyond where an agent can wander.
CURVE_HFIELD_HALF_WIDTH = 1000.0
#: Thickness (m) of the heightfield's solid base below z = 0.
CURVE_HFIELD_BASE = 0.5
#: Clearance (m) kept between the start pose's geom bounding boxes and the terrain.
INIT_CLEARANCE = 0.01
#: Checker texture repetitions per metre on the terrain (each shows 2 x 2 squares).
TERRAIN_CHECKER_REPEAT = 1.0
#: Largest |slope_deg| (deg) accepted as a reset option.
MAX_SLOPE_OPTION_DEG = 30.0
#: Planar agents' velocity clip in the observation (v5).
PLANAR_QVEL_CLIP = 10.0

_PLANAR_TERMS = ("forward", "healthy", "ctrl")
_SPATIAL_TERMS = ("forward", "healthy", "ctrl", "contact")
#: The paper's target-task reward of each pair, applied to both of its agents.
_RESTRICTED_TERMS: dict[str, tuple[str, ...]] = {
    "Walker2d": ("healthy", "ctrl"),
    "Hopper": ("healthy", "ctrl"),
    "Humanoid": _SPATIAL_TERMS,
    "Ant": _SPATIAL_TERMS,
}
_ANGLE_REFERENCES = ("gravity", "terrain")
_QVEL_NOISES = ("uniform", "normal")


# ---------------------------------------------------------------- config
@dataclass(frozen=True, kw_only=True)
class LocomotionConfig:
    """Parameters of one agent on the locomotion tasks; the defaults are Gymnasium v5's
    (``default_config``). Change fields with ``dataclasses.replace``.

    Attributes:
        agent: "Walker2d", "Hopper", "Humanoid" or "Ant".
        frame_skip: physics steps per control step (v5: 4, 4, 5, 5).
        forward_reward_weight: w_f of ``reward_forward`` (per m/s).
        ctrl_cost_weight: w_c of ``reward_ctrl`` = -w_c ||a||^2.
        healthy_reward: alive bonus per healthy step.
        healthy_height_range: open interval (m) of the torso height above the terrain.
        reset_noise_scale: half-width of v5's uniform qpos noise (and of uniform qvel
            noise, or the std of normal qvel noise).
        healthy_angle_range: open interval (rad) of the torso pitch, or None.
        healthy_state_range: open interval of every qpos[2:] and qvel entry, or None.
        healthy_angle_reference: "gravity" (pitch from the vertical) or "terrain" (pitch
            from the local slope normal, i.e. pitch + phi).
        contact_cost_weight: weight of ``reward_contact``, or None (planar agents).
        contact_force_clip: clip of each ``cfrc_ext`` entry in the contact cost and the
            observation (Ant: 1.0), or None.
        contact_cost_max: upper clip of the contact cost (Humanoid: 10), or None.
        qvel_noise: "uniform" or "normal" (Ant) initial joint-velocity noise.
        obs_qvel_clip: clip of the velocities in the observation (planar: 10), or None.
        extra_observations: include v5's extra observations (Humanoid by default; Ant
            off by default).
        terminate_when_unhealthy: end the episode when unhealthy.
        episode_steps: truncation horizon in control steps.
        slope_deg_range: Slope angle range (deg), drawn uniformly per episode.
        curve_max_deg: Curve's final tangential angle (deg).
        curve_ramp_length: x length (m) over which the Curve's angle rises.
        init_clearance: minimum clearance (m) of the start pose above the terrain.
    """

    agent: str
    frame_skip: int
    forward_reward_weight: float
    ctrl_cost_weight: float
    healthy_reward: float
    healthy_height_range: tuple[float, float]
    reset_noise_scale: float
    healthy_angle_range: tuple[float, float] | None = None
    healthy_state_range: tuple[float, float] | None = None
    healthy_angle_reference: str = "gravity"
    contact_cost_weight: float | None = None
    contact_force_clip: float | None = None
    contact_cost_max: float | None = None
    qvel_noise: str = "uniform"
    obs_qvel_clip: float | None = None
    extra_observations: bool = True
    terminate_when_unhealthy: bool = True
    episode_steps: int = EPISODE_STEPS
    slope_deg_range: tuple[float, float] = SLOPE_DEG_RANGE
    curve_max_deg: float = CURVE_MAX_DEG
    curve_ramp_length: float = CURVE_RAMP_LENGTH
    init_clearance: float = INIT_CLEARANCE


_DEFAULT_CONFIGS: dict[str, LocomotionConfig] = {
    "Walker2d": LocomotionConfig(
        agent="Walker2d",
        frame_skip=4,
        forward_reward_weight=1.0,
        ctrl_cost_weight=1e-3,
        healthy_reward=1.0,
        healthy_height_range=(0.8, 2.0),
        healthy_angle_range=(-1.0, 1.0),
        reset_noise_scale=5e-3,
        obs_qvel_clip=PLANAR_QVEL_CLIP,
    ),
    "Hopper": LocomotionConfig(
        agent="Hopper",
        frame_skip=4,
        forward_reward_weight=1.0,
        ctrl_cost_weight=1e-3,
        healthy_reward=1.0,
        healthy_height_range=(0.7, math.inf),
        healthy_angle_range=(-0.2, 0.2),
        healthy_state_range=(-100.0, 100.0),
        reset_noise_scale=5e-3,
        obs_qvel_clip=PLANAR_QVEL_CLIP,
    ),
    "Humanoid": LocomotionConfig(
        agent="Humanoid",
        frame_skip=5,
        forward_reward_weight=1.25,
        ctrl_cost_weight=0.1,
        healthy_reward=5.0,
        healthy_height_range=(1.0, 2.0),
        reset_noise_scale=1e-2,
        contact_cost_weight=5e-7,
        contact_cost_max=10.0,
    ),
    "Ant": LocomotionConfig(
        agent="Ant",
        frame_skip=5,
        forward_reward_weight=1.0,
        ctrl_cost_weight=0.5,
        healthy_reward=1.0,
        healthy_height_range=(0.2, 1.0),
        reset_noise_scale=0.1,
        contact_cost_weight=5e-4,
        contact_force_clip=1.0,
        qvel_noise="normal",
        # v5 observes cfrc_ext; with them PPO's updates on Ant ran away (docs/decisions.md)
        extra_observations=False,
    ),
}


def _check_agent(agent: str) -> None:
    if agent not in AGENTS:
        raise PvedError(f"unknown locomotion agent {agent!r}; known agents: {', '.join(AGENTS)}")


def _check_task(task: str) -> None:
    if task not in TASKS:
        raise PvedError(f"unknown locomotion task {task!r}; known tasks: {', '.join(TASKS)}")


def default_config(agent: str = "Walker2d") -> LocomotionConfig:
    """Gymnasium v5's parameters for ``agent`` (the same on Slope and Curve)."""
    _check_agent(agent)
    return _DEFAULT_CONFIGS[agent]


def reward_terms(agent: str, task: str, reward: str = "default") -> tuple[str, ...]:
    """The reward terms summed for ``agent`` on ``task`` under ``reward`` mode.

    ``"full"``: all of the agent's terms; ``"restricted"`` (Curve only): the paper's
    target-task reward of the agent's pair (no forward term for Walker2d/Hopper, all terms
    for Humanoid/Ant); ``"default"``: restricted for the target agents on Curve, else full.
    """
    _check_agent(agent)
    _check_task(task)
    full = _PLANAR_TERMS if agent in PLANAR_AGENTS else _SPATIAL_TERMS
    target_agent = agent in TARGET_AGENTS
    return select_reward_terms(
        reward, task, TASKS, "locomotion", target_agent, full, _RESTRICTED_TERMS[agent]
    )


def _validate_config(cfg: LocomotionConfig) -> None:
    _check_agent(cfg.agent)
    if cfg.frame_skip < 1 or cfg.episode_steps < 1:
        raise PvedError("frame_skip and episode_steps must be >= 1")
    if not cfg.healthy_height_range[0] < cfg.healthy_height_range[1]:
        raise PvedError(f"empty healthy_height_range {cfg.healthy_height_range}")
    if cfg.healthy_angle_reference not in _ANGLE_REFERENCES:
        raise PvedError(
            f"unknown healthy_angle_reference {cfg.healthy_angle_reference!r}; "
            f"known: {', '.join(_ANGLE_REFERENCES)}"
        )
    if cfg.qvel_noise not in _QVEL_NOISES:
        raise PvedError(f"unknown qvel_noise {cfg.qvel_noise!r}; known: {', '.join(_QVEL_NOISES)}")
    if cfg.healthy_angle_range is not None and cfg.agent not in PLANAR_AGENTS:
        raise PvedError(f"{cfg.agent} has no pitch joint; healthy_angle_range must be None")
    if cfg.agent in PLANAR_AGENTS and cfg.contact_cost_weight is not None:
        raise PvedError(f"{cfg.agent} has no contact term; contact_cost_weight must be None")
    if cfg.agent not in PLANAR_AGENTS and cfg.contact_cost_weight is None:
        raise PvedError(f"{cfg.agent} needs a contact_cost_weight (v5: Ant 5e-4, Humanoid 5e-7)")
    lo, hi = cfg.slope_deg_range
    if not -MAX_SLOPE_OPTION_DEG <= lo <= hi <= MAX_SLOPE_OPTION_DEG:
        raise PvedError(
            f"slope_deg_range must satisfy -{MAX_SLOPE_OPTION_DEG} <= low <= high <= "
            f"{MAX_SLOPE_OPTION_DEG}, got {cfg.slope_deg_range}"
        )
    if cfg.init_clearance < 0 or cfg.reset_noise_scale < 0:
        raise PvedError("init_clearance and reset_noise_scale must be >= 0")


# ---------------------------------------------------------------- MuJoCo models
def gymnasium_asset(filename: str) -> Path:
    """Path of ``filename`` in the installed gymnasium package's MuJoCo assets."""
    import gymnasium.envs.mujoco as gym_mujoco

    path = Path(gym_mujoco.__file__).resolve().parent / "assets" / filename
    if not path.is_file():
        raise PvedError(f"gymnasium's {filename} not found at {path}")
    return path


# Contact and look of the ground: copied from the model's floor onto every terrain geom.
_GROUND_ATTRS = (
    "contype",
    "conaffinity",
    "condim",
    "friction",
    "margin",
    "gap",
    "solref",
    "solimp",
    "solmix",
    "priority",
    "material",
    "rgba",
    "group",
)


def _ground_geom(body: Any, floor: Any, **kwargs: Any) -> Any:
    geom = body.add_geom(**kwargs)
    for attr in _GROUND_ATTRS:
        setattr(geom, attr, getattr(floor, attr))
    return geom


def build_model(agent: str, task: str, config: LocomotionConfig | None = None) -> mujoco.MjModel:
    """Compile ``agent``'s Gymnasium v5 model with the terrain of ``task`` (module docstring).

    Slope: the floor becomes the plane ``slope`` on the mocap body ``terrain`` (tilt per
    copy through ``MjData.mocap_quat``). Curve: the floor becomes the heightfield ``curve``
    and the tangent plane ``curve_tangent``. Every ground plane is rendered infinite.
    """
    _check_agent(agent)
    _check_task(task)
    cfg = default_config(agent) if config is None else config
    spec = mujoco.MjSpec.from_file(str(gymnasium_asset(AGENT_XML[agent])))
    # Rendering scales its clip planes and fog with the model's extent, which the 2 km
    # wide heightfield would inflate (hiding the agent): keep v5's.
    v5_stat = spec.compile().stat
    spec.stat.extent = float(v5_stat.extent)
    spec.stat.center = np.asarray(v5_stat.center).tolist()
    floor = spec.geom(FLOOR_GEOM)
    if floor is None:
        raise PvedError(f"{AGENT_XML[agent]} has no geom {FLOOR_GEOM!r}")
    # v5's checker, TERRAIN_CHECKER_REPEAT times per metre whatever the geom's size, so
    # the ground shows how far the agent went on planes drawn infinite.
    look = spec.material(str(floor.material))
    material = spec.add_material(
        name="terrain",
        texrepeat=[TERRAIN_CHECKER_REPEAT, TERRAIN_CHECKER_REPEAT],
        texuniform=True,
        reflectance=float(look.reflectance) if look is not None else 0.0,
    )
    if look is not None:
        material.textures = list(look.textures)
    floor.material = "terrain"
    plane = mujoco.mjtGeom.mjGEOM_PLANE
    # Size 0 renders a plane as infinite: agents travel far beyond v5's 20-40 m floors.
    infinite = [0.0, 0.0, 0.125]
    if task == "Slope":
        body = spec.worldbody.add_body(name="terrain", mocap=True)
        _ground_geom(body, floor, name="slope", type=plane, size=infinite)
        spec.delete(floor)
    else:
        length, behind = cfg.curve_ramp_length, CURVE_FLAT_BEHIND
        ncol = round((length + behind) / CURVE_HFIELD_DX) + 1
        xs = np.linspace(-behind, length, ncol)
        zs = curve_height(xs, cfg.curve_max_deg, length)
        top = float(zs[-1])
        spec.add_hfield(
            name="curve",
            # x half-length, y half-width, elevation scale, base thickness.
            size=[(length + behind) / 2, CURVE_HFIELD_HALF_WIDTH, top, CURVE_HFIELD_BASE],
            nrow=2,
            ncol=ncol,
            # Rows run along y; both equal, since the curve is constant along y.
            userdata=np.tile(zs / top, 2).tolist(),
        )
        world = spec.worldbody
        centre = [(length - behind) / 2, 0.0, 0.0]
        hfield = mujoco.mjtGeom.mjGEOM_HFIELD
        _ground_geom(world, floor, name="curve", type=hfield, hfieldname="curve", pos=centre)
        _ground_geom(
            world,
            floor,
            name="curve_tangent",
            type=plane,
            size=infinite,
            pos=[length, 0.0, top],
            quat=plane_quat(math.radians(cfg.curve_max_deg)).tolist(),
        )
        # The heightfield's flat part replaces the floor: a floor under it would double
        # every contact near the start (both surfaces at z = 0).
        spec.delete(floor)
    return spec.compile()


def _joint_coordinate_names(model: mujoco.MjModel) -> tuple[list[str], list[str]]:
    """Names of every qpos and qvel entry, from the joint names."""
    qpos_names = [""] * model.nq
    qvel_names = [""] * model.nv
    for j in range(model.njnt):
        name = model.joint(j).name or f"joint{j}"
        qa, va = int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            for k, s in enumerate(("x", "y", "z", "qw", "qx", "qy", "qz")):
                qpos_names[qa + k] = f"{name}_{s}"
            for k, s in enumerate(("vx", "vy", "vz", "wx", "wy", "wz")):
                qvel_names[va + k] = f"{name}_{s}"
        else:
            qpos_names[qa] = name
            qvel_names[va] = f"{name}_vel"
    return qpos_names, qvel_names


# ---------------------------------------------------------------- batched envs
class _LocomotionBatched(MujocoBatchedEnv):
    """Body, health, rewards and observation of one agent; the task supplies the terrain
    through ``_ground`` and ``_local_angle``."""

    task: str

    def __init__(
        self,
        agent: str,
        num_envs: int,
        reward: str,
        config: LocomotionConfig | None,
        autoreset: bool,
    ) -> None:
        _check_agent(agent)
        cfg = default_config(agent) if config is None else config
        if not isinstance(cfg, LocomotionConfig):
            raise PvedError("config must be a LocomotionConfig")
        if cfg.agent != agent:
            raise PvedError(f"config is for agent {cfg.agent!r}, not {agent!r}")
        _validate_config(cfg)
        self.agent = agent
        self.config = cfg
        self.reward_mode = reward
        self.reward_terms = reward_terms(agent, self.task, reward)
        model = build_model(agent, self.task, cfg)
        super().__init__(model, num_envs, cfg.frame_skip, cfg.episode_steps, autoreset)
        self.planar = agent in PLANAR_AGENTS
        # Root coordinates: planar bodies slide in x and z and pitch about y.
        self._z_index = 1 if self.planar else 2
        self._obs_qpos_start = 2 if self.planar else 3
        torso = model.body(TORSO_BODY).id
        self._agent_bodies = np.flatnonzero(model.body_rootid == torso)
        # The agent's bodies are 1..nb (the terrain body, if any, comes after them).
        nb = len(self._agent_bodies)
        if not np.array_equal(self._agent_bodies, np.arange(1, nb + 1)):
            raise PvedError(f"{agent}'s bodies are not numbered 1..{nb}")
        self._nb = nb
        self._extent_lo, self._extent_hi, self._gap = self._start_pose_extents()
        n = self.num_envs
        self.x = np.zeros(n)
        self._x_prev = np.zeros(n)
        self.torso_height = np.zeros(n)
        self.local_angle = np.zeros(n)
        self.spatial = not self.planar
        self._cfrc = np.zeros((n, nb * 6))
        self._humanoid_extras = agent == "Humanoid"
        nu_dofs = model.nv - 6
        self._cinert = np.zeros((n, nb * 10)) if self._humanoid_extras else np.zeros((n, 0))
        self._cvel = np.zeros((n, nb * 6)) if self._humanoid_extras else np.zeros((n, 0))
        self._qfrc = np.zeros((n, nu_dofs)) if self._humanoid_extras else np.zeros((n, 0))
        self._set_observation_layout()

    # ------------------------------------------------------------ layout
    def _set_observation_layout(self) -> None:
        model = self.model
        qpos_names, qvel_names = _joint_coordinate_names(model)
        robot = ("torso_height", *qpos_names[self._obs_qpos_start :], *qvel_names)
        body_names = [model.body(int(b)).name or f"body{b}" for b in self._agent_bodies]
        extras: list[str] = []
        if self.config.extra_observations and self.spatial:
            if self._humanoid_extras:
                extras += [f"cinert_{b}_{k}" for b in body_names for k in range(10)]
                extras += [f"cvel_{b}_{k}" for b in body_names for k in range(6)]
                extras += [f"qfrc_actuator_{name}" for name in qvel_names[6:]]
            extras += [f"cfrc_ext_{b}_{k}" for b in body_names for k in range(6)]
        self.robot_observation_names: tuple[str, ...] = robot
        self._set_observation_names((*robot, *extras, "local_slope"))
        self.robot_state_indices = np.arange(len(robot))

    def _start_pose_extents(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World bounding boxes of the collidable geoms in v5's default pose on flat
        ground: x extents (G,) relative to the torso and bottom heights (G,) above z = 0."""
        model = self.model
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        ground = model.geom("curve" if self.task == "Curve" else "slope")
        g_type, g_aff = int(ground.contype[0]), int(ground.conaffinity[0])
        in_agent = np.isin(model.geom_bodyid, self._agent_bodies)
        touches = ((model.geom_contype & g_aff) | (model.geom_conaffinity & g_type)) != 0
        ids = np.flatnonzero(in_agent & touches)
        if ids.size == 0:
            raise PvedError(f"{self.agent} has no geom that collides with the ground")
        centre_local = model.geom_aabb[ids, :3]
        half_local = model.geom_aabb[ids, 3:]
        rot = data.geom_xmat[ids].reshape(-1, 3, 3)
        centre = data.geom_xpos[ids] + np.einsum("gij,gj->gi", rot, centre_local)
        half = np.einsum("gij,gj->gi", np.abs(rot), half_local)
        torso_x = float(data.xpos[model.body(TORSO_BODY).id, 0])
        lo = centre[:, 0] - half[:, 0] - torso_x
        hi = centre[:, 0] + half[:, 0] - torso_x
        gap = centre[:, 2] - half[:, 2]
        return lo, hi, gap

    # ------------------------------------------------------------ terrain (task hooks)
    def _ground(self, x: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Terrain height (m) at x (k, ...) for the copies ids (k,)."""
        raise NotImplementedError

    def _local_angle(self, x: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Terrain slope angle (rad) at x (k,) for the copies ids (k,)."""
        raise NotImplementedError

    # ------------------------------------------------------------ MujocoBatchedEnv hooks
    @property
    def _num_reset_uniforms(self) -> int:
        qvel_draws = 2 * self.model.nv if self.config.qvel_noise == "normal" else self.model.nv
        # One task draw first (the slope; unused on Curve), then the robot's: a seed gives
        # every agent the same slope and one agent the same start noise on both tasks.
        return 1 + self.model.nq + qvel_draws

    def _draw_task(
        self, idx: np.ndarray, u: np.ndarray, options: dict[str, np.ndarray] | None
    ) -> None:
        """Store the task parameters of copies idx from their first uniform u (k,)."""

    def _initial_state(
        self, idx: np.ndarray, uniforms: np.ndarray, options: dict[str, np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        cfg, model = self.config, self.model
        nq, nv = model.nq, model.nv
        self._draw_task(idx, uniforms[:, 0], options)
        uniforms = uniforms[:, 1:]
        scale = cfg.reset_noise_scale
        qpos = model.qpos0 + scale * (2.0 * uniforms[:, :nq] - 1.0)
        if cfg.qvel_noise == "normal":
            # Box-Muller from two uniforms per entry; 1 - u lies in (0, 1], so log is finite.
            u1, u2 = uniforms[:, nq : nq + nv], uniforms[:, nq + nv : nq + 2 * nv]
            normal = np.sqrt(-2.0 * np.log(1.0 - u1)) * np.cos(2.0 * np.pi * u2)
            qvel = scale * normal
        else:
            qvel = scale * (2.0 * uniforms[:, nq : nq + nv] - 1.0)
        # Start at x = 0 exactly, so x_position is the distance travelled.
        qpos[:, 0] = 0.0
        if not self.planar:
            # v5 perturbs the root quaternion entrywise; keep it a rotation.
            quat = qpos[:, 3:7]
            qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        x0 = qpos[:, 0]
        base = self._ground(x0, idx)
        # Highest terrain under each geom's x extent (the profiles are convex, so the
        # maximum over an interval is at one of its ends) minus its height above z = 0.
        ends = x0[:, None, None] + np.stack([self._extent_lo, self._extent_hi], axis=1)[None]
        under = self._ground(ends, idx).max(axis=2) - base[:, None]
        lift = np.maximum(0.0, (under - self._gap[None] + cfg.init_clearance).max(axis=1))
        qpos[:, self._z_index] += base + lift
        return qpos, qvel

    def _derive(self, idx: np.ndarray | slice) -> None:
        ids = np.arange(self.num_envs)[idx]
        # x before the state change, for the forward velocity of the next step.
        self._x_prev[ids] = self.x[ids]
        x = self.qpos[ids, 0]
        self.x[ids] = x
        self.torso_height[ids] = self.qpos[ids, self._z_index] - self._ground(x, ids)
        self.local_angle[ids] = self._local_angle(x, ids)
        if self.spatial:
            model, nb = self.model, self._nb
            for i in ids:
                data = self.datas[i]
                # mj_step leaves cfrc_ext etc. unset; v5 fills them the same way.
                mujoco.mj_rnePostConstraint(model, data)
                self._cfrc[i] = data.cfrc_ext[1 : nb + 1].ravel()
                if self._humanoid_extras:
                    self._cinert[i] = data.cinert[1 : nb + 1].ravel()
                    self._cvel[i] = data.cvel[1 : nb + 1].ravel()
                    self._qfrc[i] = data.qfrc_actuator[6:]

    def _contact_forces(self) -> np.ndarray:
        clip = self.config.contact_force_clip
        return self._cfrc if clip is None else np.clip(self._cfrc, -clip, clip)

    def _observe(self) -> np.ndarray:
        cfg = self.config
        qvel = self.qvel
        if cfg.obs_qvel_clip is not None:
            qvel = np.clip(qvel, -cfg.obs_qvel_clip, cfg.obs_qvel_clip)
        parts = [self.torso_height[:, None], self.qpos[:, self._obs_qpos_start :], qvel]
        if cfg.extra_observations and self.spatial:
            if self._humanoid_extras:
                parts += [self._cinert, self._cvel, self._qfrc]
            parts.append(self._contact_forces())
        parts.append(self.local_angle[:, None])
        return np.concatenate(parts, axis=1)

    def healthy(self) -> np.ndarray:
        """(N,) bool: the current state of each copy is healthy (module docstring)."""
        cfg = self.config
        ok = np.isfinite(self.qpos).all(axis=1) & np.isfinite(self.qvel).all(axis=1)
        lo, hi = cfg.healthy_height_range
        ok &= (lo < self.torso_height) & (self.torso_height < hi)
        if cfg.healthy_angle_range is not None:
            pitch = self.qpos[:, 2]
            if cfg.healthy_angle_reference == "terrain":
                # The slope normal is pitched by -phi, so the pitch from it is pitch + phi.
                pitch = pitch + self.local_angle
            lo, hi = cfg.healthy_angle_range
            ok &= (lo < pitch) & (pitch < hi)
        if cfg.healthy_state_range is not None:
            state = np.concatenate([self.qpos[:, 2:], self.qvel], axis=1)
            lo, hi = cfg.healthy_state_range
            ok &= np.all((lo < state) & (state < hi), axis=1)
        return np.asarray(ok)

    def _evaluate(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, Info]:
        cfg = self.config
        x_velocity = (self.x - self._x_prev) / self.dt
        healthy = self.healthy()
        terms = {
            "forward": cfg.forward_reward_weight * x_velocity,
            "healthy": cfg.healthy_reward * healthy.astype(np.float64),
            "ctrl": -cfg.ctrl_cost_weight * np.sum(actions * actions, axis=1),
        }
        if cfg.contact_cost_weight is not None:
            cost = cfg.contact_cost_weight * np.sum(self._contact_forces() ** 2, axis=1)
            if cfg.contact_cost_max is not None:
                cost = np.minimum(cost, cfg.contact_cost_max)
            terms["contact"] = -cost
        reward, info = split_reward_terms(terms, self.reward_terms, self.num_envs)
        info.update(self._readouts())
        info["x_velocity"] = x_velocity
        if cfg.terminate_when_unhealthy:
            terminated = ~healthy
        else:
            terminated = np.zeros(self.num_envs, dtype=bool)
        return reward, terminated, info

    def _readouts(self) -> Info:
        return {
            "x_position": self.x.copy(),
            "torso_height": self.torso_height.copy(),
            "local_slope_deg": np.degrees(self.local_angle),
        }

    def _reset_info(self) -> Info:
        return self._readouts()


class LocomotionSlopeBatched(_LocomotionBatched):
    """N copies of ``pved/<agent>Slope-v0`` (see the module docstring).

    Args:
        agent: "Walker2d", "Hopper", "Humanoid" or "Ant".
        num_envs: N.
        reward: "default" or "full" (the same on Slope).
        config: a :class:`LocomotionConfig` for ``agent`` (default: ``default_config``).
        autoreset: reset finished copies inside ``step``.

    Reset option ``slope_deg``: the angle (deg), a scalar or (N,) for the batch, a scalar
    for the Gymnasium form; drawn uniformly in ``config.slope_deg_range`` otherwise.
    """

    task = "Slope"

    def __init__(
        self,
        agent: str = "Walker2d",
        num_envs: int = 1,
        reward: str = "default",
        config: LocomotionConfig | None = None,
        autoreset: bool = True,
    ) -> None:
        super().__init__(agent, num_envs, reward, config, autoreset)
        self.slope_deg = np.zeros(self.num_envs)
        self.task_param_keys = ("slope_deg",)

    def _ground(self, x: np.ndarray, ids: np.ndarray) -> np.ndarray:
        slope = self.slope_deg[ids].reshape((-1,) + (1,) * (np.ndim(x) - 1))
        return slope_height(x, slope)

    def _local_angle(self, x: np.ndarray, ids: np.ndarray) -> np.ndarray:
        return slope_angle(x, self.slope_deg[ids])

    def _validate_options(self, options: dict[str, Any]) -> dict[str, np.ndarray]:
        unknown = set(options) - {"slope_deg"}
        if unknown:
            raise PvedError(f"unknown reset option(s) {sorted(unknown)}; Slope takes 'slope_deg'")
        slope = self._batched_option("slope_deg", options["slope_deg"], ())
        limit = MAX_SLOPE_OPTION_DEG
        if np.any(np.abs(slope) > limit):
            raise PvedError(f"slope_deg must lie in [-{limit}, {limit}] deg")
        return {"slope_deg": slope}

    def _draw_task(
        self, idx: np.ndarray, u: np.ndarray, options: dict[str, np.ndarray] | None
    ) -> None:
        lo, hi = self.config.slope_deg_range
        slope = draw_slope_deg(u, lo, hi)
        if options is not None and "slope_deg" in options:
            slope = options["slope_deg"][idx]
        self.slope_deg[idx] = slope

    def _write_extra(self, i: int, data: mujoco.MjData) -> None:
        # The copy's own tilt of the shared plane (the mocap body "terrain").
        data.mocap_quat[0] = plane_quat(math.radians(self.slope_deg[i]))

    def _get_task_state(self) -> dict[str, np.ndarray]:
        return {"slope_deg": self.slope_deg.copy()}

    def _set_task_state(self, state: dict[str, np.ndarray]) -> None:
        self.slope_deg = np.asarray(state["slope_deg"], dtype=np.float64).copy()

    def _task_params(self) -> Info:
        return {"slope_deg": self.slope_deg.copy()}


class LocomotionCurveBatched(_LocomotionBatched):
    """N copies of ``pved/<agent>Curve-v0`` (see the module docstring).

    Args:
        agent: "Walker2d", "Hopper", "Humanoid" or "Ant".
        num_envs: N.
        reward: "default" (restricted for Hopper and Ant, full for the source agents),
            "restricted" (the pair's target-task reward) or "full".
        config: a :class:`LocomotionConfig` for ``agent`` (default: ``default_config``).
        autoreset: reset finished copies inside ``step``.

    The Curve is the same in every episode: no task parameters, no reset options.
    """

    task = "Curve"

    def __init__(
        self,
        agent: str = "Walker2d",
        num_envs: int = 1,
        reward: str = "default",
        config: LocomotionConfig | None = None,
        autoreset: bool = True,
    ) -> None:
        super().__init__(agent, num_envs, reward, config, autoreset)
        self.task_param_keys = ()

    def _ground(self, x: np.ndarray, ids: np.ndarray) -> np.ndarray:
        cfg = self.config
        return curve_height(x, cfg.curve_max_deg, cfg.curve_ramp_length)

    def _local_angle(self, x: np.ndarray, ids: np.ndarray) -> np.ndarray:
        cfg = self.config
        return curve_angle(x, cfg.curve_max_deg, cfg.curve_ramp_length)

    def _task_params(self) -> Info:
        return {}


# ---------------------------------------------------------------- Gymnasium form
class _LocomotionEnv(BatchOfOneEnv):
    """The Gymnasium form of a locomotion task, whose batched form is ``batched_class``."""

    batched_class: ClassVar[type[_LocomotionBatched]]

    def __init__(
        self,
        agent: str = "Walker2d",
        reward: str = "default",
        config: LocomotionConfig | None = None,
        render_mode: str | None = None,
        width: int = 240,
        height: int = 240,
    ) -> None:
        batched = self.batched_class(agent, 1, reward=reward, config=config, autoreset=False)
        super().__init__(
            batched, render_mode=render_mode, width=width, height=height, camera=CAMERA
        )


class LocomotionSlopeEnv(_LocomotionEnv):
    """``gymnasium.Env`` of ``pved/<agent>Slope-v0`` (a batch of one, no autoreset).

    Args: as :class:`LocomotionSlopeBatched`, plus ``render_mode`` (None or "rgb_array")
    and the image ``width``/``height`` in pixels; the camera follows the agent.
    """

    batched_class = LocomotionSlopeBatched


class LocomotionCurveEnv(_LocomotionEnv):
    """``gymnasium.Env`` of ``pved/<agent>Curve-v0`` (a batch of one, no autoreset).

    Args: as :class:`LocomotionCurveBatched`, plus ``render_mode`` (None or "rgb_array")
    and the image ``width``/``height`` in pixels; the camera follows the agent.
    """

    batched_class = LocomotionCurveBatched


__all__ = [
    "AGENTS",
    "AGENT_XML",
    "CURVE_HFIELD_DX",
    "EPISODE_STEPS",
    "INIT_CLEARANCE",
    "REWARD_MODES",
    "SOURCE_OF_TARGET",
    "TARGET_AGENTS",
    "TASKS",
    "LocomotionConfig",
    "LocomotionCurveBatched",
    "LocomotionCurveEnv",
    "LocomotionSlopeBatched",
    "LocomotionSlopeEnv",
    "build_model",
    "default_config",
    "gymnasium_asset",
    "reward_terms",
]
