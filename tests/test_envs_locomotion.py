"""The locomotion environments: terrain profiles and their MuJoCo surfaces, both env forms,
terrain-relative health, rewards and reward modes, rendering, errors."""

from __future__ import annotations

import dataclasses
import math
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import pved  # noqa: F401  (registers the ids)
from pved.envs import AGENTS, ENV_IDS, TASKS, env_id, make, make_batched
from pved.envs.locomotion import (
    LocomotionCurveBatched,
    LocomotionSlopeBatched,
    default_config,
    reward_terms,
)
from pved.envs.terrain import (
    CURVE_MAX_DEG,
    curve_angle,
    curve_height,
    draw_slope_deg,
    slope_angle,
    slope_height,
)
from pved.errors import PvedError
from pved.rl.evaluate import evaluate_policy

LOCO_AGENTS = ("Walker2d", "Hopper", "Humanoid", "Ant")
LOCO_IDS = [
    "pved/Walker2dSlope-v0",
    "pved/HopperSlope-v0",
    "pved/Walker2dCurve-v0",
    "pved/HopperCurve-v0",
    "pved/HumanoidSlope-v0",
    "pved/AntSlope-v0",
    "pved/HumanoidCurve-v0",
    "pved/AntCurve-v0",
]
OBS_DIMS = {"Walker2d": (18, 17), "Hopper": (12, 11), "Humanoid": (349, 45), "Ant": (28, 27)}


def _agent(eid: str) -> str:
    return next(a for a in LOCO_AGENTS if eid.startswith(f"pved/{a}"))


def _short(agent: str, steps: int) -> object:
    return dataclasses.replace(default_config(agent), episode_steps=steps)


def _ground(env: object, x: float, copy: int = 0) -> float:
    """Terrain height under x for one copy of a locomotion env."""
    return float(env._ground(np.array([x]), np.array([copy]))[0])  # type: ignore[attr-defined]


def _ray_height(model: mujoco.MjModel, data: mujoco.MjData, x: float, y: float = 0.0) -> float:
    """Height of the first contact surface straight below (x, y, 100 m)."""
    geom = np.zeros(1, dtype=np.int32)
    dist = mujoco.mj_ray(
        model, data, np.array([x, y, 100.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom
    )
    assert dist >= 0, f"no ground below x={x}, y={y}"
    return 100.0 - dist


# ---------------------------------------------------------------- registry and checker
def test_registry_lists_the_eight_ids() -> None:
    assert set(LOCO_IDS) <= set(ENV_IDS)
    assert set(LOCO_AGENTS) <= set(AGENTS)
    assert {"Slope", "Curve"} <= set(TASKS)
    assert env_id("Hopper", "Curve") == "pved/HopperCurve-v0"
    for eid in LOCO_IDS:
        assert eid in gym.registry
    with pytest.raises(PvedError, match="Push"):
        env_id("Hopper", "Push")


@pytest.mark.parametrize("eid", LOCO_IDS)
def test_env_checker_and_render(eid: str) -> None:
    """Gymnasium's checker passes; the image shows the agent in the middle of the frame,
    and still does once the agent is 20 m further up (the camera follows it)."""
    env = make(eid, render_mode="rgb_array", width=96, height=96)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")
        check_env(env.unwrapped, skip_render_check=_agent(eid) == "Humanoid")
    if _agent(eid) == "Humanoid":  # slow to draw; the other 3D agent (Ant) is drawn
        env.close()
        return
    env.reset(seed=3)
    batched = env.unwrapped.batched
    columns = []
    for x in (0.0, 20.0):
        qpos = batched.qpos[0].copy()
        qpos[0] = x
        qpos[batched._z_index] = _ground(batched, x) + batched.torso_height[0]
        env.unwrapped.set_joint_state(qpos, np.zeros_like(batched.qvel[0]))
        img = env.render()
        assert isinstance(img, np.ndarray) and img.shape == (96, 96, 3) and img.dtype == np.uint8
        assert img.std() > 5.0
        r, g, b = (img[..., k].astype(int) for k in range(3))
        body = (r > g + 15) & (g > b + 15)  # the bodies' tan; the ground is grey-green
        assert body.sum() > 20, f"the agent is not in the image at x = {x}"
        columns.append(np.nonzero(body)[1].mean())
    assert all(abs(c - 48) < 20 for c in columns), columns
    env.close()


# ---------------------------------------------------------------- batched == single
@pytest.mark.parametrize(
    "eid",
    [
        "pved/Walker2dSlope-v0",
        "pved/HopperSlope-v0",
        "pved/AntSlope-v0",
        "pved/Walker2dCurve-v0",
        "pved/HopperCurve-v0",
        "pved/AntCurve-v0",
    ],
)
def test_batched_matches_single_envs_across_autoreset(eid: str) -> None:
    n, seed, horizon = 3, 11, 20
    cfg = _short(_agent(eid), horizon)
    batched = make_batched(eid, n, config=cfg)
    singles = [make(eid, config=cfg) for _ in range(n)]
    steps = horizon + 6  # every copy crosses at least one episode boundary
    act_dim = batched.single_action_space.shape[0]
    actions = np.random.default_rng(0).uniform(-1.2, 1.2, size=(steps, n, act_dim))

    obs_b, info_b = batched.reset(seed=seed)
    for i, env in enumerate(singles):
        obs_s, info_s = env.reset(seed=seed + i)
        np.testing.assert_array_equal(obs_b[i], obs_s)
        for key, value in info_s.items():
            np.testing.assert_array_equal(info_b[key][i], value)
    params = batched.task_param_keys  # type: ignore[attr-defined]
    assert params == (("slope_deg",) if "Slope" in eid else ())
    ended = 0
    for t in range(steps):
        obs_b, rew_b, term_b, trunc_b, info_b = batched.step(actions[t])
        for i, env in enumerate(singles):
            obs_s, rew_s, term_s, trunc_s, info_s = env.step(actions[t, i])
            assert rew_b[i] == rew_s
            assert term_b[i] == term_s and trunc_b[i] == trunc_s
            assert set(info_s) == set(info_b) - {"final_obs"}
            np.testing.assert_array_equal(info_b["final_obs"][i], obs_s)
            if term_s or trunc_s:
                ended += 1
                old = {k: info_s[k] for k in params}
                obs_s, reset_info = env.reset()  # continues the copy's own random stream
                info_s.update({k: reset_info[k] for k in params})
                for k in params:  # a new slope is drawn for the new episode
                    assert old[k] != info_s[k]
            for key, value in info_s.items():
                np.testing.assert_array_equal(info_b[key][i], value, err_msg=key)
            np.testing.assert_array_equal(obs_b[i], obs_s)
    assert ended >= n


def test_get_state_set_state_continue_exactly() -> None:
    """Ant on Slope: per-copy slopes (mocap), contact forces in the observation."""
    env = make_batched("pved/AntSlope-v0", 2, config=_short("Ant", 15))
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    for a in rng.uniform(-1, 1, size=(8, 2, 8)):
        env.step(a)
    saved = env.state_dict()
    later = rng.uniform(-1, 1, size=(20, 2, 8))
    first = [env.step(a) for a in later]
    other = make_batched("pved/AntSlope-v0", 2, config=_short("Ant", 15))
    other.load_state_dict(saved)
    for a, (obs, rew, term, trunc, info) in zip(later, first, strict=True):
        obs2, rew2, term2, trunc2, info2 = other.step(a)
        np.testing.assert_array_equal(obs, obs2)
        np.testing.assert_array_equal(rew, rew2)
        np.testing.assert_array_equal(term | trunc, term2 | trunc2)
        for key in info:
            np.testing.assert_array_equal(info[key], info2[key], err_msg=key)


# ---------------------------------------------------------------- rewards
_MODES = [
    (agent, task, mode)
    for agent in LOCO_AGENTS
    for task in ("Slope", "Curve")
    for mode in (("default", "full") if task == "Slope" else ("default", "restricted", "full"))
]


@pytest.mark.parametrize(("agent", "task", "mode"), _MODES)
def test_reward_is_sum_of_its_terms(agent: str, task: str, mode: str) -> None:
    env = make_batched(env_id(agent, task), 2, reward=mode)
    cfg = env.config  # type: ignore[attr-defined]
    terms = set(reward_terms(agent, task, mode))
    all_terms = {"forward", "healthy", "ctrl"} | (
        {"contact"} if agent in ("Ant", "Humanoid") else set()
    )
    env.reset(seed=2)
    rng = np.random.default_rng(1)
    x_before = env.x.copy()  # type: ignore[attr-defined]
    for _ in range(4):
        low, high = env.single_action_space.low, env.single_action_space.high
        act = rng.uniform(low, high, size=(2, len(low)))
        _, rew, term, _, info = env.step(act)
        keys = [k for k in info if k.startswith("reward_")]
        assert {k.removeprefix("reward_") for k in keys} == terms
        assert {
            k.removeprefix("metric_") for k in info if k.startswith("metric_")
        } == all_terms - terms
        np.testing.assert_allclose(rew, sum(info[k] for k in keys), rtol=0, atol=1e-12)
        value = {t: info.get(f"reward_{t}", info.get(f"metric_{t}")) for t in all_terms}
        np.testing.assert_allclose(value["ctrl"], -cfg.ctrl_cost_weight * (act**2).sum(axis=1))
        speed = (info["x_position"] - x_before) / env.dt  # type: ignore[attr-defined]
        np.testing.assert_allclose(value["forward"], cfg.forward_reward_weight * speed)
        np.testing.assert_allclose(value["healthy"], cfg.healthy_reward * ~term)
        if "contact" in value:
            assert np.all(value["contact"] <= 0)
        x_before = np.where(term, 0.0, info["x_position"])  # a terminated copy restarts at 0


def test_target_agents_default_rewards_on_curve() -> None:
    """Hopper on Curve is paid for staying up, not for moving forward; Ant keeps the
    forward term; the source agents keep their full reward."""
    assert reward_terms("Hopper", "Curve") == ("healthy", "ctrl")
    assert "forward" in reward_terms("Ant", "Curve")
    assert "forward" in reward_terms("Walker2d", "Curve")
    assert "forward" in reward_terms("Humanoid", "Curve")
    assert "forward" in reward_terms("Hopper", "Curve", "full")
    assert "forward" in reward_terms("Hopper", "Slope")

    hopper = make("pved/HopperCurve-v0")
    hopper.reset(seed=0)
    batched = hopper.unwrapped.batched
    qvel = batched.qvel[0].copy()
    qvel[0] = 3.0  # sliding forward fast
    hopper.unwrapped.set_joint_state(batched.qpos[0].copy(), qvel)
    _, reward, _, _, info = hopper.step(np.zeros(3))
    assert "reward_forward" not in info and info["metric_forward"] > 1.0
    assert reward == info["reward_healthy"] + info["reward_ctrl"] == 1.0

    ant = make_batched("pved/AntCurve-v0", 1)
    ant.reset(seed=0)
    _, reward_a, _, _, info_a = ant.step(np.zeros((1, 8)))
    assert "reward_forward" in info_a and "metric_forward" not in info_a
    np.testing.assert_allclose(
        reward_a,
        info_a["reward_forward"]
        + info_a["reward_healthy"]
        + info_a["reward_ctrl"]
        + info_a["reward_contact"],
    )


# ---------------------------------------------------------------- terrain profiles
def test_curve_profile() -> None:
    xs = np.array([-3.0, 0.0, 6.0, 12.0, 20.0])
    np.testing.assert_allclose(np.degrees(curve_angle(xs)), [0.0, 0.0, 5.0, 10.0, 10.0], atol=1e-12)
    z = curve_height(xs)
    assert z[0] == 0.0 and z[1] == 0.0
    np.testing.assert_allclose(
        z[3], -(12.0 / math.radians(10.0)) * math.log(math.cos(math.radians(10.0)))
    )
    np.testing.assert_allclose(z[4], z[3] + 8.0 * math.tan(math.radians(10.0)))
    # z is the integral of tan(phi): continuous, with slope tan(phi) everywhere.
    fine = np.linspace(-2.0, 30.0, 64001)
    zf = curve_height(fine)
    assert np.abs(np.diff(zf)).max() < 1e-3 * math.tan(math.radians(10.0)) * 1.01
    mid = 0.5 * (fine[1:] + fine[:-1])
    np.testing.assert_allclose(np.diff(zf) / np.diff(fine), np.tan(curve_angle(mid)), atol=2e-6)
    # Convex: every tangent line lies below the curve (what the MuJoCo terrain relies on).
    for x0 in (0.0, 4.0, 12.0):
        tangent = curve_height(x0) + (fine - x0) * np.tan(curve_angle(x0))
        assert np.all(tangent <= zf + 1e-12)
    # Slope: a plane at the given angle.
    np.testing.assert_allclose(
        slope_height(np.array([0.0, 10.0]), 5.0), [0.0, 10 * math.tan(math.radians(5))]
    )
    np.testing.assert_allclose(slope_angle(np.zeros(3), 5.0), math.radians(5.0))
    np.testing.assert_allclose(draw_slope_deg(np.array([0.0, 0.5, 1.0])), [2.0, 6.0, 10.0])


@pytest.mark.parametrize("agent", ["Hopper", "Ant"])
def test_curve_matches_the_mujoco_surface(agent: str) -> None:
    env = make_batched(env_id(agent, "Curve"), 1)
    env.reset(seed=0)
    model, data = env.model, env.datas[0]
    for y in (3.0, 37.0):  # beside the agent, which stands at y = 0
        for x in (-20.0, -0.3, 0.0, 0.1, 3.0, 6.0, 9.1, 11.9, 12.0, 12.1, 20.0, 150.0):
            assert abs(_ray_height(model, data, x, y) - float(curve_height(x))) < 1e-4, (x, y)
    # Local slope from the surface: 0, 5, 10 and 10 degrees at x = 0, 6, 12, 20.
    for x, deg in ((0.0, 0.0), (6.0, 5.0), (12.0, 10.0), (20.0, 10.0)):
        h = 0.01
        dz = _ray_height(model, data, x + h, 3.0) - _ray_height(model, data, x - h, 3.0)
        assert abs(math.degrees(math.atan(dz / (2 * h))) - deg) < 0.3, x


def test_contacts_lie_on_the_curve() -> None:
    """A Hopper dropped upright at x = 6 m touches the terrain where z(x) says, tilted by
    the curve's 5 deg there. Contacts on the heightfield's internal edges take the foot's
    own tilt or an edge's normal (docs/decisions.md), hence a median with 2 deg slack."""
    env = make_batched("pved/HopperCurve-v0", 1)
    env.reset(seed=0)
    qpos = env.qpos[0].copy()
    qpos[0], qpos[1] = 6.0, float(curve_height(6.0)) + 1.3
    env.set_joint_state(qpos[None], np.zeros((1, env.model.nv)))
    errors = []
    for _ in range(40):
        env.step(np.zeros((1, 3)))
        data = env.datas[0]
        for c in data.contact[: data.ncon]:
            # The contact point sits midway between the surfaces: within the penetration.
            assert abs(c.pos[2] - float(curve_height(c.pos[0]))) < 5e-3
            normal = c.frame[:3] * (1 if c.frame[2] > 0 else -1)
            slope = math.degrees(math.atan2(-normal[0], normal[2]))
            errors.append(slope - math.degrees(float(curve_angle(c.pos[0]))))
    assert len(errors) > 20
    assert np.median(np.abs(errors)) < 2.0


def test_slope_option_is_the_slope_under_the_agent() -> None:
    slopes = np.array([2.5, 7.0, 10.0])
    env = make_batched("pved/HopperSlope-v0", 3)
    assert isinstance(env, LocomotionSlopeBatched)
    obs, info = env.reset(seed=0, options={"slope_deg": slopes})
    np.testing.assert_array_equal(info["slope_deg"], slopes)
    np.testing.assert_allclose(info["local_slope_deg"], slopes)
    np.testing.assert_allclose(obs[:, -1], np.radians(slopes))  # the terrain part
    for i, deg in enumerate(slopes):  # each copy stands on its own slope
        z1 = _ray_height(env.model, env.datas[i], 1.0)
        z3 = _ray_height(env.model, env.datas[i], 3.0)
        assert abs(math.degrees(math.atan((z3 - z1) / 2.0)) - deg) < 1e-9
        assert abs(_ray_height(env.model, env.datas[i], 0.0, 2.0)) < 1e-9
        # ... and starts just above it: no contact yet, the foot's front end within 10 cm.
        foot = env.datas[i].geom("foot_geom")
        front = foot.xpos[0] + 0.195  # capsule half-length (the foot is horizontal)
        clearance = foot.xpos[2] - 0.06 - float(slope_height(front, deg))
        assert env.datas[i].ncon == 0 and -0.005 < clearance < 0.1, clearance
    _, _, _, _, info = env.step(np.zeros((3, 3)))
    np.testing.assert_array_equal(info["slope_deg"], slopes)  # kept for the episode
    single = make("pved/AntSlope-v0")
    _, info_s = single.reset(seed=1, options={"slope_deg": 4.0})
    assert info_s["slope_deg"] == 4.0
    data = single.unwrapped.batched.datas[0]
    z = _ray_height(single.unwrapped.batched.model, data, 5.0, 2.0)
    assert abs(z - 5.0 * math.tan(math.radians(4.0))) < 1e-9


def test_slopes_are_drawn_in_range() -> None:
    env = make_batched("pved/Walker2dSlope-v0", 64)
    _, info = env.reset(seed=0)
    deg = info["slope_deg"]
    assert deg.min() >= 2.0 and deg.max() <= 10.0
    assert deg.std() > 1.5 and len(np.unique(deg)) == 64
    # The same seed gives the same slopes to the other agent of the pair.
    _, info_h = make_batched("pved/HopperSlope-v0", 64).reset(seed=0)
    np.testing.assert_array_equal(info_h["slope_deg"], deg)


# ---------------------------------------------------------------- health
def _place(env: LocomotionSlopeBatched | LocomotionCurveBatched, x: float, height: float) -> None:
    """Every copy upright at x with its torso ``height`` above the terrain there."""
    qpos = np.tile(env.model.qpos0, (env.num_envs, 1))
    qpos[:, 0] = x
    qpos[:, env._z_index] = env._ground(np.full(env.num_envs, x), np.arange(env.num_envs)) + height
    env.set_joint_state(qpos, np.zeros((env.num_envs, env.model.nv)))


@pytest.mark.parametrize(
    ("agent", "upright"), [("Hopper", 1.25), ("Walker2d", 1.25), ("Ant", 0.55), ("Humanoid", 1.4)]
)
def test_health_is_relative_to_the_terrain(agent: str, upright: float) -> None:
    env = make_batched(env_id(agent, "Curve"), 1)
    assert isinstance(env, LocomotionCurveBatched)
    env.reset(seed=0)
    z20 = float(curve_height(20.0))
    _place(env, 20.0, upright)  # standing far up the curve, 2.5 m above z = 0
    assert env.healthy()[0] and abs(env.torso_height[0] - upright) < 1e-12
    _place(env, 20.0, 0.15)  # lying on the terrain
    assert not env.healthy()[0]
    _place(env, 20.0, upright - z20)  # at the standing height above the *world* floor
    assert not env.healthy()[0]
    _place(env, 20.0, upright)  # and it stays so through a step, paid the alive bonus
    _, _, term, _, info = env.step(np.zeros((1, env.single_action_space.shape[0])))
    assert not term[0] and info["reward_healthy"][0] == env.config.healthy_reward
    # On a 10 deg slope far up, upright is healthy too.
    slope = make_batched(env_id(agent, "Slope"), 1)
    assert isinstance(slope, LocomotionSlopeBatched)
    slope.reset(seed=0, options={"slope_deg": 10.0})
    _place(slope, 20.0, upright)
    assert slope.healthy()[0]


def test_hopper_pitch_is_judged_from_gravity_by_default() -> None:
    """Upright (vertical) on a 10 deg slope is healthy; the "terrain" reference measures
    the pitch from the slope normal and rejects the same pose."""
    env = make_batched("pved/HopperSlope-v0", 1)
    assert isinstance(env, LocomotionSlopeBatched)
    env.reset(seed=0, options={"slope_deg": 10.0})
    _place(env, 5.0, 1.25)
    assert env.healthy()[0]
    qpos = env.qpos.copy()
    qpos[0, 2] = 0.15  # leaning 0.15 rad forward, into the slope
    env.set_joint_state(qpos, env.qvel.copy())
    assert env.healthy()[0]
    cfg = dataclasses.replace(default_config("Hopper"), healthy_angle_reference="terrain")
    rel = make_batched("pved/HopperSlope-v0", 1, config=cfg)
    assert isinstance(rel, LocomotionSlopeBatched)
    rel.reset(seed=0, options={"slope_deg": 10.0})
    rel.set_joint_state(qpos, env.qvel.copy())
    assert not rel.healthy()[0]
    # Leaning past the limit ends the episode at the next step.
    qpos[0, 2] = 0.5
    env.set_joint_state(qpos, env.qvel.copy())
    _, _, term, _, info = env.step(np.zeros((1, 3)))
    assert term[0] and info["reward_healthy"][0] == 0.0


# ---------------------------------------------------------------- observation and metric
def test_observation_layout_is_the_same_on_both_tasks() -> None:
    for agent in LOCO_AGENTS:
        slope = make_batched(env_id(agent, "Slope"), 1)
        curve = make_batched(env_id(agent, "Curve"), 1)
        dim, robot = OBS_DIMS[agent]
        for env in (slope, curve):
            assert env.single_observation_space.shape == (dim,)
            np.testing.assert_array_equal(env.robot_state_indices, np.arange(robot))
        assert slope.observation_names == curve.observation_names  # type: ignore[attr-defined]
        names = slope.observation_names  # type: ignore[attr-defined]
        assert names[0] == "torso_height" and names[-1] == "local_slope"
        obs, _ = curve.reset(seed=0)
        assert abs(obs[0, 0] - curve.torso_height[0]) < 1e-12  # type: ignore[attr-defined]


def test_ant_observes_contact_forces_only_when_asked() -> None:
    # off by default (PPO did not learn with them); the contact cost is paid either way
    cfg = dataclasses.replace(default_config("Ant"), extra_observations=True)
    with_forces = make_batched("pved/AntSlope-v0", 1, config=cfg)
    without = make_batched("pved/AntSlope-v0", 1)
    assert with_forces.single_observation_space.shape == (106,)
    names = with_forces.observation_names  # type: ignore[attr-defined]
    assert sum(n.startswith("cfrc_ext_") for n in names) == 78
    assert not any(n.startswith("cfrc_ext_") for n in without.observation_names)  # type: ignore[attr-defined]
    for env in (with_forces, without):
        env.reset(seed=0)
    action = np.full((1, 8), 0.5)
    for _ in range(3):
        infos = [env.step(action)[4] for env in (with_forces, without)]
    assert infos[0]["reward_contact"][0] == infos[1]["reward_contact"][0] < 0.0


def test_every_episode_starts_at_x_zero_and_x_position_is_the_distance() -> None:
    class Still:
        """Holds every joint still; the Hoppers fall and end their episodes."""

        def act(self, obs: np.ndarray, deterministic: bool, rng: np.random.Generator) -> np.ndarray:
            return np.zeros((len(obs), 3))

    env = make_batched("pved/HopperCurve-v0", 2, config=_short("Hopper", 30))
    result = evaluate_policy(Still(), env, episodes=2, seed=0, info_keys=("x_position",))
    # The same episodes by hand: each copy's first episode, x at its last step.
    _, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["x_position"], 0.0)
    final = np.full(2, np.nan)
    for _ in range(30):
        _, _, term, trunc, info = env.step(np.zeros((2, 3)))
        first = (term | trunc) & np.isnan(final)
        final[first] = info["x_position"][first]
    assert np.isfinite(final).all() and np.any(final != 0.0)
    assert result["x_position_mean"] == pytest.approx(final.mean(), abs=1e-12)


# ---------------------------------------------------------------- errors
def test_bad_names_options_and_configs_raise_pved_error() -> None:
    with pytest.raises(PvedError, match="restricted"):
        make_batched("pved/HopperSlope-v0", 1, reward="restricted")
    with pytest.raises(PvedError, match="bogus"):
        make("pved/AntCurve-v0", reward="bogus")
    env = make_batched("pved/HopperSlope-v0", 2)
    with pytest.raises(PvedError, match="slope_deg"):
        env.reset(options={"slope_deg": 45.0})
    with pytest.raises(PvedError, match="target"):
        env.reset(options={"target": 1.0})
    with pytest.raises(PvedError, match="shape"):
        env.reset(options={"slope_deg": np.ones(3)})
    with pytest.raises(PvedError, match="none"):
        make_batched("pved/HopperCurve-v0", 1).reset(options={"slope_deg": 5.0})
    with pytest.raises(PvedError, match="Ant"):
        make_batched("pved/HopperCurve-v0", 1, config=default_config("Ant"))
    with pytest.raises(PvedError, match="Dog"):
        default_config("Dog")
    with pytest.raises(PvedError, match="healthy_angle_reference"):
        cfg = dataclasses.replace(default_config("Hopper"), healthy_angle_reference="up")
        make_batched("pved/HopperCurve-v0", 1, config=cfg)
    assert CURVE_MAX_DEG == 10.0
