"""The robot-arm pair environments (Jaco -> Fetch4): both forms, rewards, success, contacts,
workspace and task options."""

from __future__ import annotations

import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import pved  # noqa: F401  (registers the ids)
from pved.envs import AGENTS, ENV_IDS, TASKS, env_id, make, make_batched
from pved.envs.arms import (
    FETCH_LOCKED_JOINTS,
    HOLE_CENTER_XY,
    HOLE_DEPTH,
    HOLE_HALF_WIDTH,
    HOLE_RANGE,
    REST_TIP,
    ROOT_POS,
    SUCCESS_DEPTH_TOL,
    TABLE_TOP_Z,
    TARGET_HIGH,
    TARGET_LOW,
    ArmPegBatched,
    default_config,
    fetch_asset_path,
    peg_inserted,
)
from pved.envs.batched import ASSETS_DIR
from pved.errors import PvedError

ARM_IDS = ["pved/JacoReach-v0", "pved/Fetch4Reach-v0", "pved/JacoPeg-v0", "pved/Fetch4Peg-v0"]
PEG_IDS = ARM_IDS[2:]
N_JOINTS = {"Jaco": 7, "Fetch4": 4}


def _agent(eid: str) -> str:
    return "Jaco" if "Jaco" in eid else "Fetch4"


def _act_dim(eid: str) -> int:
    return N_JOINTS[_agent(eid)]


# ---------------------------------------------------------------- registry and checker
def test_registry_lists_the_four_ids() -> None:
    assert set(ARM_IDS) <= set(ENV_IDS)
    assert {"Jaco", "Fetch4"} <= set(AGENTS)
    assert {"Reach", "Peg"} <= set(TASKS)
    assert env_id("Fetch4", "Peg") == "pved/Fetch4Peg-v0"
    for eid in ARM_IDS:
        assert eid in gym.registry


@pytest.mark.parametrize("eid", ARM_IDS)
def test_env_checker_and_render(eid: str) -> None:
    env = make(eid, render_mode="rgb_array", width=96, height=96)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")
        check_env(env.unwrapped)
    env.reset(seed=3)
    img = env.render()
    assert isinstance(img, np.ndarray)
    assert img.shape == (96, 96, 3) and img.dtype == np.uint8
    assert img.std() > 5.0 and len(np.unique(img.reshape(-1, 3), axis=0)) > 20
    env.close()


# ---------------------------------------------------------------- models
def test_fetch_is_loaded_from_the_installed_package_and_cut_to_four_joints() -> None:
    assert "gymnasium_robotics" in str(fetch_asset_path())
    # The repo holds no copy of the Fetch model.
    for path in ASSETS_DIR.glob("*.xml"):
        assert "robot0:" not in path.read_text()
    env = make_batched("pved/Fetch4Peg-v0", 1)
    model = env.model
    names = [model.joint(i).name for i in range(model.njnt)]
    assert len(names) == 4 and model.nu == 4 and model.nq == 4
    assert not any(lock in n for n in names for lock in FETCH_LOCKED_JOINTS)
    assert model.neq == 0  # FetchReach's mocap weld is gone
    assert model.nmesh > 0  # the package's meshes came along
    env.reset(seed=0)
    data = env.datas[0]
    np.testing.assert_allclose(data.body("fetch/robot0:shoulder_pan_link").xpos, ROOT_POS)
    jaco = make_batched("pved/JacoPeg-v0", 1)
    jaco.reset(seed=0)
    np.testing.assert_allclose(jaco.datas[0].body("link1").xpos, ROOT_POS)  # same root
    # Only the peg (and the table) collide.
    colliding = {model.geom(i).name for i in range(model.ngeom) if model.geom_contype[i]}
    assert "peg" in colliding and not any(n.startswith("fetch/") for n in colliding)


@pytest.mark.parametrize("agent", ["Jaco", "Fetch4"])
def test_rest_pose_puts_the_peg_tip_at_rest_tip_pointing_down(agent: str) -> None:
    env = make_batched(env_id(agent, "Reach"), 1)
    env.set_joint_state(env.rest_qpos[None], np.zeros((1, env.model.nv)))
    np.testing.assert_allclose(env.peg_tip[0], REST_TIP, atol=1e-3)
    data = env.datas[0]
    axis = data.site("peg_tip").xpos - data.site("peg_base").xpos
    np.testing.assert_allclose(axis / np.linalg.norm(axis), [0, 0, -1], atol=1e-3)


# ---------------------------------------------------------------- batched == single
@pytest.mark.parametrize("eid", ["pved/Fetch4Reach-v0", "pved/JacoPeg-v0"])
def test_batched_matches_single_envs_across_autoreset(eid: str) -> None:
    n, seed = 3, 11
    batched = make_batched(eid, n)
    singles = [make(eid) for _ in range(n)]
    horizon = batched.max_episode_steps
    steps = horizon + 5
    actions = np.random.default_rng(0).uniform(-1.2, 1.2, size=(steps, n, _act_dim(eid)))

    obs_b, info_b = batched.reset(seed=seed)
    for i, env in enumerate(singles):
        obs_s, info_s = env.reset(seed=seed + i)
        np.testing.assert_array_equal(obs_b[i], obs_s)
        for key, value in info_s.items():
            np.testing.assert_array_equal(info_b[key][i], value)
    params = batched.task_param_keys  # type: ignore[attr-defined]
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
                obs_s, reset_info = env.reset()
                info_s.update({k: reset_info[k] for k in params})
                assert not np.array_equal(old[params[0]], info_s[params[0]])
            for key, value in info_s.items():
                np.testing.assert_array_equal(info_b[key][i], value, err_msg=key)
            np.testing.assert_array_equal(obs_b[i], obs_s)
        assert trunc_b.all() == (t == horizon - 1)
    assert ended == n


def test_get_state_set_state_continue_exactly_through_contacts() -> None:
    env = make_batched("pved/Fetch4Peg-v0", 2, reward="full")
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    down = np.array([0.0, 1.0, 1.0, 1.0])  # presses the peg onto the table
    for _ in range(30):
        env.step(np.tile(down, (2, 1)))
    saved = env.state_dict()
    later = rng.uniform(-1, 1, size=(20, 2, 4))
    first = [env.step(a) for a in later]
    other = make_batched("pved/Fetch4Peg-v0", 2, reward="full")
    other.load_state_dict(saved)
    for a, (obs, rew, *_rest) in zip(later, first, strict=True):
        obs2, rew2, *_rest2 = other.step(a)
        np.testing.assert_array_equal(obs, obs2)
        np.testing.assert_array_equal(rew, rew2)


# ---------------------------------------------------------------- rewards
@pytest.mark.parametrize(
    ("eid", "reward", "terms"),
    [
        ("pved/JacoReach-v0", "default", {"dist", "ctrl"}),
        ("pved/Fetch4Reach-v0", "full", {"dist", "ctrl"}),
        ("pved/JacoPeg-v0", "default", {"dist", "ctrl"}),
        ("pved/JacoPeg-v0", "restricted", {"in_hole"}),
        ("pved/Fetch4Peg-v0", "default", {"in_hole"}),
        ("pved/Fetch4Peg-v0", "restricted", {"in_hole"}),
        ("pved/Fetch4Peg-v0", "full", {"dist", "ctrl"}),
    ],
)
def test_reward_is_sum_of_its_terms(eid: str, reward: str, terms: set[str]) -> None:
    env = make_batched(eid, 4, reward=reward)
    env.reset(seed=2)
    rng = np.random.default_rng(1)
    for _ in range(15):
        act = rng.uniform(-1, 1, size=(4, _act_dim(eid)))
        _, rew, _, _, info = env.step(act)
        keys = [k for k in info if k.startswith("reward_")]
        assert {k.removeprefix("reward_") for k in keys} == terms
        np.testing.assert_allclose(rew, sum(info[k] for k in keys), rtol=0, atol=1e-12)
        every = {
            k.split("_", 1)[1]: v for k, v in info.items() if k.startswith(("reward_", "metric_"))
        }
        np.testing.assert_allclose(every["ctrl"], -0.01 * (act**2).sum(axis=1))
        goal = info["target"] if "target" in info else info["hole_mid"]
        np.testing.assert_allclose(every["dist"], -np.linalg.norm(info["peg_tip"] - goal, axis=1))
    if eid.endswith("Peg-v0"):
        assert set(every) == {"dist", "ctrl", "in_hole"}
        np.testing.assert_array_equal(every["in_hole"], 0.0)  # the peg starts above the table


# ---------------------------------------------------------------- success on scripted states
def _set_tip(env: ArmPegBatched, tip: np.ndarray) -> None:
    q, residual = env.ik(tip[None], point_down=True)
    assert residual[0] < 1e-6
    env.set_joint_state(q, np.zeros((1, env.model.nv)))
    np.testing.assert_allclose(env.peg_tip[0], tip, atol=1e-6)


@pytest.mark.parametrize("eid", PEG_IDS)
def test_success_judged_on_scripted_states(eid: str) -> None:
    env = make_batched(eid, 1, reward="full")
    assert isinstance(env, ArmPegBatched)
    hole = np.array([0.53, 0.03])
    env.reset(seed=0, options={"hole": hole})
    bottom = TABLE_TOP_Z - HOLE_DEPTH
    zero = np.zeros((1, _act_dim(eid)))
    cases = [  # tip position, in_hole, success
        ((*hole, bottom + 0.005), True, True),
        ((*hole, bottom + 0.8 * SUCCESS_DEPTH_TOL), True, True),
        ((*hole, bottom + 1.3 * SUCCESS_DEPTH_TOL), True, False),  # half-way down
        ((*hole, TABLE_TOP_Z + 0.03), False, False),  # above the opening
        ((hole[0] + 0.06, hole[1], TABLE_TOP_Z + 0.002), False, False),  # on the table
    ]
    for tip, in_hole, success in cases:
        _set_tip(env, np.array(tip))
        info = env.step(zero)[4]  # gravity compensation holds the arm still
        assert abs(info["peg_tip"][0, 2] - tip[2]) < 2e-3
        assert info["is_success"][0] == success, tip
        in_hole_term = info.get("reward_in_hole", info.get("metric_in_hole"))
        assert in_hole_term is not None and in_hole_term[0] == float(in_hole), tip


def test_peg_inserted_thresholds() -> None:
    bottom, hw, tol = 0.34, HOLE_HALF_WIDTH, SUCCESS_DEPTH_TOL
    tips = np.array(
        [
            [0.55, 0.0, bottom + 0.5 * tol],
            [0.55 + 0.9 * hw, 0.0, bottom],
            [0.55 + 1.1 * hw, 0.0, bottom],
            [0.55, 0.0, bottom + 1.1 * tol],
        ]
    )
    got = peg_inserted(tips, np.tile([0.55, 0.0], (4, 1)), hw, bottom, tol)
    np.testing.assert_array_equal(got, [True, True, False, False])


@pytest.mark.parametrize("eid", PEG_IDS)
def test_scripted_insertion_succeeds(eid: str) -> None:
    """A joint-space PD controller following IK waypoints down the hole's axis inserts
    the peg through the real walls: the hole is wide enough and the success reachable."""
    env = make_batched(eid, 1, reward="full")
    assert isinstance(env, ArmPegBatched)
    _, info = env.reset(seed=3, options={"hole": np.array([0.58, -0.04])})
    hole = info["hole"][0]
    waypoints, prev = [], None
    for z in (0.47, 0.43, 0.40, 0.37, 0.345):
        q, res = env.ik(np.array([[hole[0], hole[1], z]]), point_down=True, q0=prev)
        assert res[0] < 1e-6
        prev = q[0]
        waypoints.append(q[0])
    flags, returns = [], 0.0
    for step in range(env.max_episode_steps - 1):
        q_des = waypoints[min(step // 20, len(waypoints) - 1)]
        q, qd = env.qpos[0, env._arm_qpos], env.qvel[0, env._arm_dof]
        act = np.clip(3.0 * (q_des - q) - 0.3 * qd, -1, 1)
        _, reward, _, _, info = env.step(act[None])
        returns += float(reward[0])
        flags.append(bool(info["is_success"][0]))
    assert flags[-1] and sum(flags) > 30
    assert info["metric_in_hole"][0] == 1.0
    idle = make_batched(eid, 1, reward="full")
    idle.reset(seed=3, options={"hole": np.array([0.58, -0.04])})
    idle_return = sum(float(idle.step(np.zeros((1, _act_dim(eid))))[1][0]) for _ in flags)
    assert returns > idle_return


# ---------------------------------------------------------------- contacts
@pytest.mark.parametrize("eid", ["pved/JacoPeg-v0", "pved/Fetch4Peg-v0", "pved/Fetch4Reach-v0"])
def test_peg_cannot_pass_through_the_table(eid: str) -> None:
    """Drive the tip straight down at full torque, away from the hole, for 80 steps."""
    env = make_batched(eid, 1)
    options = {"hole": np.array([0.60, 0.10])} if "Peg" in eid else None
    env.reset(seed=0, options=options)
    model, data = env.model, env.datas[0]
    jacp = np.zeros((3, model.nv))
    lowest = np.inf
    for _ in range(80):
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, jacp, None, model.site("peg_tip").id)
        push = jacp[:, env._arm_dof].T @ np.array([0.0, 0.0, -1.0])
        env.step(np.clip(50.0 * push, -1, 1)[None])
        lowest = min(lowest, env.peg_tip[0, 2])
    assert lowest < TABLE_TOP_Z + 0.02  # it did get down to the table...
    assert lowest > TABLE_TOP_Z - 0.005  # ... and stayed on it
    if "Peg" in eid:
        assert np.linalg.norm(env.peg_tip[0, :2] - [0.60, 0.10]) > 2 * HOLE_HALF_WIDTH


# ---------------------------------------------------------------- workspace and options
def test_reach_target_from_options_is_the_one_used_by_both_robots() -> None:
    targets = np.array([[0.45, 0.1, 0.6], [0.62, -0.15, 0.55]])
    for agent in ("Jaco", "Fetch4"):
        env = make_batched(env_id(agent, "Reach"), 2)
        obs, info = env.reset(seed=1, options={"target": targets})
        np.testing.assert_array_equal(info["target"], targets)
        k = len(env.robot_state_indices)
        np.testing.assert_array_equal(obs[:, k : k + 3], targets)
        np.testing.assert_array_equal(env.datas[1].mocap_pos[0], targets[1])
        _, _, _, _, info = env.step(np.zeros((2, N_JOINTS[agent])))
        np.testing.assert_array_equal(info["target"], targets)
        dist = np.linalg.norm(info["peg_tip"] - targets, axis=1)
        np.testing.assert_allclose(info["reward_dist"], -dist)
    single = make("pved/Fetch4Reach-v0")
    _, info = single.reset(seed=0, options={"target": targets[0]})
    np.testing.assert_array_equal(info["target"], targets[0])


def test_hole_from_options_is_the_one_used() -> None:
    hole = np.array([0.5, -0.05])
    for agent in ("Jaco", "Fetch4"):
        env = make_batched(env_id(agent, "Peg"), 2)
        _, info = env.reset(seed=1, options={"hole": hole})
        np.testing.assert_array_equal(info["hole"], np.tile(hole, (2, 1)))
        np.testing.assert_allclose(
            info["hole_mid"][0], [*hole, TABLE_TOP_Z - HOLE_DEPTH + SUCCESS_DEPTH_TOL / 2]
        )
        np.testing.assert_array_equal(env.datas[0].mocap_pos[0], [*hole, TABLE_TOP_Z])


def test_random_targets_and_holes_are_reachable_by_both_robots() -> None:
    env = make_batched("pved/JacoReach-v0", 200)
    _, info = env.reset(seed=0)
    targets = info["target"]
    assert np.all(targets >= TARGET_LOW) and np.all(targets <= TARGET_HIGH)
    assert np.all(targets.std(axis=0) > 0.05)  # spread over the box
    peg = make_batched("pved/Fetch4Peg-v0", 200)
    _, pinfo = peg.reset(seed=0)
    assert np.all(np.abs(pinfo["hole"] - HOLE_CENTER_XY) <= HOLE_RANGE)
    # Corners of the hole distribution, tip at the hole's bottom, peg vertical.
    corners = np.array(
        [
            [HOLE_CENTER_XY[0] + sx * HOLE_RANGE, HOLE_CENTER_XY[1] + sy * HOLE_RANGE, 0.345]
            for sx in (-1, 1)
            for sy in (-1, 1)
        ]
    )
    for agent in ("Jaco", "Fetch4"):
        reach = make_batched(env_id(agent, "Reach"), 1)
        _, residual = reach.ik(targets[:8])
        assert residual.max() < 2e-3, (agent, residual)
        _, residual = reach.ik(corners, point_down=True)
        assert residual.max() < 1e-4, (agent, residual)


def test_same_seed_same_initial_arm_on_reach_and_peg() -> None:
    for agent in ("Jaco", "Fetch4"):
        reach = make_batched(env_id(agent, "Reach"), 3)
        peg = make_batched(env_id(agent, "Peg"), 3)
        np.testing.assert_array_equal(reach.robot_state_indices, peg.robot_state_indices)
        assert len(reach.robot_state_indices) == 3 * N_JOINTS[agent] + 3
        obs_r, _ = reach.reset(seed=9)
        obs_p, _ = peg.reset(seed=9)
        idx = reach.robot_state_indices
        np.testing.assert_array_equal(obs_r[:, idx], obs_p[:, idx])


def test_peg_tip_readout_is_the_current_state() -> None:
    env = make_batched("pved/Fetch4Reach-v0", 2)
    env.reset(seed=4)
    obs = env.step(np.ones((2, 4)))[0]
    for i in range(2):
        scratch = mujoco.MjData(env.model)
        scratch.qpos[:] = env.qpos[i]
        mujoco.mj_forward(env.model, scratch)
        np.testing.assert_allclose(env.peg_tip[i], scratch.site("peg_tip").xpos, atol=1e-12)
    np.testing.assert_array_equal(obs[:, env.robot_state_indices[-3:]], env.peg_tip)


# ---------------------------------------------------------------- errors
def test_bad_inputs_raise_pved_error() -> None:
    with pytest.raises(PvedError, match="restricted"):
        make_batched("pved/JacoReach-v0", 1, reward="restricted")
    with pytest.raises(PvedError, match="bogus"):
        make("pved/Fetch4Peg-v0", reward="bogus")
    with pytest.raises(PvedError, match="Jaco9"):
        default_config("Jaco9", "Reach")
    with pytest.raises(PvedError, match="Push"):
        default_config("Jaco", "Push")
    env = make_batched("pved/Fetch4Peg-v0", 1)
    with pytest.raises(PvedError, match="hole"):
        env.reset(options={"hole": np.array([1.5, 0.0])})
    with pytest.raises(PvedError, match="target"):
        env.reset(options={"target": np.zeros(3)})
    with pytest.raises(PvedError, match="Fetch4"):
        make_batched("pved/JacoReach-v0", 1, config=default_config("Fetch4", "Reach"))
