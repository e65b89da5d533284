"""The Reacher pair environments: both forms, rewards, success, task geometry, errors."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import pved  # noqa: F401  (registers the ids)
from pved.envs import AGENTS, ENV_IDS, TASKS, env_id, make, make_batched
from pved.envs.reacher import (
    AGENT_LINK_LENGTHS,
    ReacherPushBatched,
    default_config,
    ee_jacobian,
    forward_kinematics,
    push_settled,
)
from pved.errors import PvedError

REACHER_IDS = [
    "pved/Reacher3Reach-v0",
    "pved/Reacher4Reach-v0",
    "pved/Reacher3Push-v0",
    "pved/Reacher4Push-v0",
]
PUSH_IDS = REACHER_IDS[2:]


def _n_links(eid: str) -> int:
    return 3 if "Reacher3" in eid else 4


# ---------------------------------------------------------------- registry and checker
def test_registry_lists_the_four_ids() -> None:
    assert set(REACHER_IDS) <= set(ENV_IDS)
    assert {"Reacher3", "Reacher4"} <= set(AGENTS)
    assert {"Reach", "Push"} <= set(TASKS)
    assert env_id("Reacher4", "Push") == "pved/Reacher4Push-v0"
    for eid in REACHER_IDS:
        assert eid in gym.registry


@pytest.mark.parametrize("eid", REACHER_IDS)
def test_env_checker_and_render(eid: str) -> None:
    env = make(eid, render_mode="rgb_array", width=128, height=128)
    with warnings.catch_warnings():
        # Unbounded observation boxes are intended (as in Gymnasium's MuJoCo envs).
        warnings.filterwarnings("ignore", message=".*infinity.*")
        check_env(env.unwrapped)
    env.reset(seed=3)
    img = env.render()
    assert isinstance(img, np.ndarray)
    assert img.shape == (128, 128, 3) and img.dtype == np.uint8
    assert img.std() > 5.0 and len(np.unique(img.reshape(-1, 3), axis=0)) > 20
    # The red target / goal bar is drawn.
    r, g, b = (img[..., k].astype(int) for k in range(3))
    assert np.count_nonzero((r > 150) & (g < 90) & (b < 90)) > 0
    env.close()


def test_render_follows_the_target() -> None:
    env = make("pved/Reacher3Reach-v0", render_mode="rgb_array", width=64, height=64)
    env.reset(seed=0, options={"target": np.array([0.2, 0.0])})
    left = env.render()
    env.reset(seed=0, options={"target": np.array([-0.2, 0.15])})
    right = env.render()
    assert not np.array_equal(left, right)
    env.close()


def test_render_without_a_gl_context_names_the_fix() -> None:
    """MuJoCo's default (windowed) GL backend with no display gives one PvedError that
    says to set MUJOCO_GL, not a FatalError from deep inside the renderer."""
    code = (
        "import gymnasium as gym, pved\n"
        "from pved.errors import PvedError\n"
        "env = gym.make('pved/Reacher3Reach-v0', render_mode='rgb_array', width=32, height=32)\n"
        "env.reset(seed=0)\n"
        "try:\n"
        "    env.render()\n"
        "except PvedError as err:\n"
        "    print('PvedError:', err)\n"
    )
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")
    }
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("PvedError: cannot render") and "MUJOCO_GL=osmesa" in out.stdout


# ---------------------------------------------------------------- batched == single
@pytest.mark.parametrize("eid", ["pved/Reacher4Reach-v0", "pved/Reacher3Push-v0"])
def test_batched_matches_single_envs_across_autoreset(eid: str) -> None:
    n, seed = 4, 11
    batched = make_batched(eid, n)
    singles = [make(eid) for _ in range(n)]
    horizon = batched.max_episode_steps
    steps = horizon + 7  # crosses one episode boundary
    act_dim = batched.single_action_space.shape[0]
    actions = np.random.default_rng(0).uniform(-1.2, 1.2, size=(steps, n, act_dim))

    obs_b, info_b = batched.reset(seed=seed)
    for i, env in enumerate(singles):
        obs_s, info_s = env.reset(seed=seed + i)
        np.testing.assert_array_equal(obs_b[i], obs_s)
        for key, value in info_s.items():
            np.testing.assert_array_equal(info_b[key][i], value)

    params = batched.task_param_keys  # type: ignore[attr-defined]
    assert params and set(params) <= set(info_b)
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
                # Task parameters are the new episode's, and they did change.
                info_s.update({k: reset_info[k] for k in params})
                assert not np.array_equal(old[params[0]], info_s[params[0]])
            for key, value in info_s.items():
                np.testing.assert_array_equal(info_b[key][i], value, err_msg=key)
            np.testing.assert_array_equal(obs_b[i], obs_s)
        assert trunc_b.all() == (t == horizon - 1)
    assert ended == n


def test_unseeded_reset_and_seeded_reset_are_reproducible() -> None:
    env = make_batched("pved/Reacher3Reach-v0", 3)
    a, _ = env.reset(seed=5)
    b, _ = env.reset(seed=5)
    c, _ = env.reset()
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert not np.array_equal(a[0], a[1])  # copies differ


def test_episode_does_not_depend_on_history() -> None:
    """A reset wipes the simulator state (warm starts, contacts): the same seed and
    actions give the same episode whatever came before."""
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(40, 2, 3))
    fresh = make_batched("pved/Reacher3Push-v0", 2)
    used = make_batched("pved/Reacher3Push-v0", 2)
    used.reset(seed=100)
    for a in rng.uniform(-1, 1, size=(70, 2, 3)):
        used.step(a)
    first = [env.reset(seed=7)[0] for env in (fresh, used)]
    np.testing.assert_array_equal(first[0], first[1])
    # The whole simulator state is fresh, warm start and clock included.
    for d_used, d_fresh in zip(used.datas, fresh.datas, strict=True):
        assert d_used.time == 0.0
        np.testing.assert_array_equal(d_used.qacc_warmstart, d_fresh.qacc_warmstart)
    for a in actions:
        np.testing.assert_array_equal(fresh.step(a)[0], used.step(a)[0])


@pytest.mark.parametrize("eid", ["pved/Reacher4Reach-v0", "pved/Reacher4Push-v0"])
def test_get_state_set_state_continue_exactly(eid: str) -> None:
    """A saved state (as PPO checkpoints it) continues bit-exactly in a new env,
    through autoresets (generators restored) and contacts (warm start restored)."""
    env = make_batched(eid, 3, reward="full")
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    for a in rng.uniform(-1, 1, size=(30, 3, 4)):
        env.step(a)
    saved = env.state_dict()
    later = rng.uniform(-1, 1, size=(130, 3, 4))
    first = [env.step(a) for a in later]
    other = make_batched(eid, 3, reward="full")
    other.load_state_dict(saved)
    for a, (obs, rew, term, trunc, info) in zip(later, first, strict=True):
        obs2, rew2, term2, trunc2, info2 = other.step(a)
        np.testing.assert_array_equal(obs, obs2)
        np.testing.assert_array_equal(rew, rew2)
        np.testing.assert_array_equal(term, term2)
        np.testing.assert_array_equal(trunc, trunc2)
        for key in info:
            np.testing.assert_array_equal(info[key], info2[key], err_msg=key)
    with pytest.raises(PvedError, match="shape"):
        make_batched(eid, 2).load_state_dict(saved)


def test_gym_form_truncates_at_horizon_without_autoreset() -> None:
    env = make("pved/Reacher4Reach-v0")
    env.reset(seed=0)
    horizon = env.unwrapped.max_episode_steps
    assert horizon == 50
    for t in range(horizon):
        _, _, term, trunc, info = env.step(np.zeros(4))
        assert not term and trunc == (t == horizon - 1)
        assert "final_obs" not in info


# ---------------------------------------------------------------- rewards
def _reward_keys(info: dict) -> list[str]:
    return [k for k in info if k.startswith("reward_")]


@pytest.mark.parametrize(
    ("eid", "reward", "terms"),
    [
        ("pved/Reacher3Reach-v0", "default", {"dist", "ctrl"}),
        ("pved/Reacher4Reach-v0", "full", {"dist", "ctrl"}),
        ("pved/Reacher3Push-v0", "default", {"ee_button", "button_goal", "ctrl"}),
        ("pved/Reacher4Push-v0", "default", {"button_goal"}),
        ("pved/Reacher4Push-v0", "full", {"ee_button", "button_goal", "ctrl"}),
        ("pved/Reacher3Push-v0", "restricted", {"button_goal"}),
    ],
)
def test_reward_is_sum_of_its_terms(eid: str, reward: str, terms: set[str]) -> None:
    env = make_batched(eid, 5, reward=reward)
    env.reset(seed=2)
    rng = np.random.default_rng(1)
    for _ in range(20):
        act = rng.uniform(-1, 1, size=(5, env.single_action_space.shape[0]))
        _, rew, _, _, info = env.step(act)
        keys = _reward_keys(info)
        assert {k.removeprefix("reward_") for k in keys} == terms
        np.testing.assert_allclose(rew, sum(info[k] for k in keys), rtol=0, atol=1e-12)
        # Each term means what it says.
        if "reward_ctrl" in info:
            np.testing.assert_allclose(info["reward_ctrl"], -0.1 * (act**2).sum(axis=1))
        if "reward_dist" in info:
            dist = np.linalg.norm(info["ee_pos"] - info["target"], axis=1)
            np.testing.assert_allclose(info["reward_dist"], -dist)
        if "reward_button_goal" in info:
            gap = np.linalg.norm(info["button_pos"] - info["goal"], axis=1)
            np.testing.assert_allclose(info["reward_button_goal"], -gap)
    if eid.endswith("Push-v0") and terms == {"button_goal"}:
        # The unused terms are reported, but apart from the reward.
        assert {"metric_ee_button", "metric_ctrl"} <= set(info)
        assert np.all(info["metric_ee_button"] < 0)


def test_restricted_reward_ignores_the_end_effector() -> None:
    """Reacher4Push's default reward does not change when only the arm moves."""
    env = make("pved/Reacher4Push-v0")
    env.reset(seed=0)
    rewards = [env.step(np.ones(4) * s)[1] for s in (1.0, -1.0, 0.5, 0.0)]
    assert len(set(rewards)) == 1  # the button never moved, the arm did


# ---------------------------------------------------------------- success on scripted states
def _push_env(eid: str) -> gym.Env:
    return make(eid).unwrapped


def _set_push_state(env: gym.Env, button_x: float, arm_q: np.ndarray, arm_qd: np.ndarray) -> None:
    qpos = np.zeros(env.batched.model.nq)
    qvel = np.zeros(env.batched.model.nv)
    qpos[: len(arm_q)] = arm_q
    qvel[: len(arm_qd)] = arm_qd
    qpos[-1] = button_x
    env.set_joint_state(qpos, qvel)


@pytest.mark.parametrize("eid", PUSH_IDS)
def test_success_judged_on_scripted_states(eid: str) -> None:
    n = _n_links(eid)
    cfg = default_config("Reacher3" if n == 3 else "Reacher4", "Push")
    rest = np.zeros(n)
    rest[0] = np.pi  # the arm points away from the channel
    zero = np.zeros(n)

    # Button at the goal, arm still: success after exactly settle_steps steps.
    env = _push_env(eid)
    env.reset(seed=0)
    _set_push_state(env, cfg.goal_x + 0.6 * cfg.goal_tol, rest, zero)
    flags = [env.step(zero)[4]["is_success"] for _ in range(cfg.settle_steps + 3)]
    assert flags == [False] * (cfg.settle_steps - 1) + [True] * 4

    # Button at the goal, arm sweeping fast (away from the channel): never.
    env.reset(seed=0)
    spin = zero.copy()
    spin[0] = 3.0
    _set_push_state(env, cfg.goal_x, rest, spin)
    push = zero.copy()
    push[0] = 1.0
    for _ in range(cfg.settle_steps + 5):
        info = env.step(push)[4]
        assert np.linalg.norm(env.batched.ee_vel[0]) > cfg.ee_speed_tol
        assert not info["is_success"]
    assert abs(info["button_pos"][0] - cfg.goal_x) < 1e-12  # the button was at the goal

    # Button short of the goal (just outside the tolerance), arm still: never.
    env.reset(seed=0)
    _set_push_state(env, cfg.goal_x - 1.2 * cfg.goal_tol, rest, zero)
    assert not any(env.step(zero)[4]["is_success"] for _ in range(3 * cfg.settle_steps))


def test_push_settled_thresholds() -> None:
    bx = np.array([0.06, 0.06, 0.0505, 0.0695, 0.06])
    vel = np.array([[0.0, 0.0], [0.03, 0.045], [0.0, 0.0], [0.0, 0.0], [0.0, 0.049]])
    got = push_settled(bx, vel, goal_x=0.06, goal_tol=0.01, ee_speed_tol=0.05)
    np.testing.assert_array_equal(got, [True, False, True, True, True])
    assert not push_settled(np.array([0.0715]), np.zeros((1, 2)), 0.06, 0.01, 0.05)[0]


# ---------------------------------------------------------------- workspace and options
def _ik_residual(targets: np.ndarray, lengths: np.ndarray, limit: float = 2.6) -> np.ndarray:
    """Smallest |ee - target| found by damped least squares (joints 1.. limited), from
    several starting poses; (M,) residuals for targets (M, 2)."""
    rng = np.random.default_rng(0)
    n, best = len(lengths), np.full(len(targets), np.inf)
    for _ in range(6):
        q = rng.uniform(-limit, limit, size=(len(targets), n))
        for _ in range(200):
            ee, _ = forward_kinematics(q, np.zeros_like(q), lengths)
            jac = ee_jacobian(q, lengths)
            err = targets - ee
            jjt = jac @ jac.transpose(0, 2, 1) + 1e-4 * np.eye(2)
            q = q + np.einsum("mji,mj->mi", jac, np.linalg.solve(jjt, err[..., None])[..., 0])
            q[:, 1:] = np.clip(q[:, 1:], -limit, limit)
        ee, _ = forward_kinematics(q, np.zeros_like(q), lengths)
        best = np.minimum(best, np.linalg.norm(targets - ee, axis=1))
    return best


def test_targets_lie_in_both_workspaces() -> None:
    env = make_batched("pved/Reacher3Reach-v0", 400)
    _, info = env.reset(seed=0)
    targets = info["target"]
    radius = np.linalg.norm(targets, axis=1)
    cfg = default_config("Reacher3", "Reach")
    assert radius.min() >= cfg.target_radius_min and radius.max() <= cfg.target_radius_max
    # Spread over the annulus, not collapsed onto a line or a ring.
    angles = np.arctan2(targets[:, 1], targets[:, 0])
    assert np.histogram(angles, bins=4, range=(-np.pi, np.pi))[0].min() > 60
    assert radius.std() > 0.03
    for lengths in AGENT_LINK_LENGTHS.values():
        assert _ik_residual(targets[:60], np.asarray(lengths)).max() < 1e-4
    # ... and the button's whole path (start range to goal) is reachable by both.
    push_cfg = default_config("Reacher4", "Push")
    assert isinstance(push_cfg, type(default_config("Reacher3", "Push")))
    xs = np.linspace(
        push_cfg.button_start_x - push_cfg.button_start_halfwidth - 0.05, push_cfg.goal_x, 12
    )
    path = np.stack([xs, np.full_like(xs, push_cfg.channel_y)], axis=1)
    for lengths in AGENT_LINK_LENGTHS.values():
        assert _ik_residual(path, np.asarray(lengths)).max() < 1e-4


@pytest.mark.parametrize("eid", REACHER_IDS)
def test_forward_kinematics_matches_mujoco(eid: str) -> None:
    env = make_batched(eid, 6)
    env.reset(seed=4)
    rng = np.random.default_rng(0)
    qpos = env.qpos.copy()
    qpos[:, : _n_links(eid)] = rng.uniform(-2.5, 2.5, size=(6, _n_links(eid)))
    env.set_joint_state(qpos, np.zeros_like(env.qvel))
    for i, data in enumerate(env.datas):
        np.testing.assert_allclose(env.ee_pos[i], data.site("ee").xpos[:2], atol=1e-12)
    obs = env.step(np.zeros((6, _n_links(eid))))[0]
    np.testing.assert_array_equal(obs[:, env.robot_state_indices[-2:]], env.ee_pos)


def test_reset_options_set_task_parameters_exactly() -> None:
    targets = np.array([[0.1, 0.05], [-0.2, 0.1], [0.0, -0.15]])
    for agent in ("Reacher3", "Reacher4"):
        env = make_batched(env_id(agent, "Reach"), 3)
        obs, info = env.reset(seed=1, options={"target": targets})
        np.testing.assert_array_equal(info["target"], targets)
        k = len(env.robot_state_indices)
        np.testing.assert_array_equal(obs[:, k : k + 2], targets)
        _, _, _, _, info = env.step(np.zeros((3, _n_links(env_id(agent, "Reach")))))
        np.testing.assert_array_equal(info["target"], targets)  # kept for the episode

    starts = np.array([[-0.1, 0.15], [-0.05, 0.15]])
    env = make_batched("pved/Reacher4Push-v0", 2)
    obs, info = env.reset(seed=1, options={"button_start": starts})
    np.testing.assert_array_equal(info["button_start"], starts)
    np.testing.assert_array_equal(info["button_pos"], starts)
    np.testing.assert_array_equal(obs[:, 14:16], starts)

    single = make("pved/Reacher3Push-v0")
    _, info = single.reset(seed=0, options={"button_start": np.array([-0.09, 0.15])})
    np.testing.assert_array_equal(info["button_start"], [-0.09, 0.15])


def test_same_seed_same_initial_arm_on_reach_and_push() -> None:
    """Encoders trained on Reach see Push: the robot part means the same in both."""
    for agent in ("Reacher3", "Reacher4"):
        reach = make_batched(env_id(agent, "Reach"), 3)
        push = make_batched(env_id(agent, "Push"), 3)
        np.testing.assert_array_equal(reach.robot_state_indices, push.robot_state_indices)
        obs_r, _ = reach.reset(seed=9)
        obs_p, _ = push.reset(seed=9)
        idx = reach.robot_state_indices
        np.testing.assert_array_equal(obs_r[:, idx], obs_p[:, idx])
        assert len(idx) == 3 * len(AGENT_LINK_LENGTHS[agent]) + 2


# ---------------------------------------------------------------- the button
@pytest.mark.parametrize("eid", PUSH_IDS)
def test_button_stays_unless_pushed(eid: str) -> None:
    env = make_batched(eid, 4)
    _, info = env.reset(seed=3)
    start = info["button_start"].copy()
    for _ in range(60):
        _, _, _, _, info = env.step(np.zeros((4, _n_links(eid))))
    np.testing.assert_array_equal(info["button_pos"], start)
    # A flicked button stops within a few steps (damping and dry friction).
    qvel = env.qvel.copy()
    qvel[:, -1] = 0.3
    env.set_joint_state(env.qpos.copy(), qvel)
    for _ in range(10):
        env.step(np.zeros((4, _n_links(eid))))
    assert np.all(np.abs(env.qvel[:, -1]) < 1e-6)  # MuJoCo's dry friction is soft
    travelled = env.qpos[:, -1] - start[:, 0]
    assert np.all((travelled > 0) & (travelled < 0.02))
    rest = env.qpos[:, -1].copy()
    for _ in range(25):  # 95 steps in all: no autoreset yet
        env.step(np.zeros((4, _n_links(eid))))
    np.testing.assert_allclose(env.qpos[:, -1], rest, rtol=0, atol=1e-7)


def _scripted_push(env: ReacherPushBatched, phase: np.ndarray) -> np.ndarray:
    """Move the fingertip to the left of the button, then push it to the goal
    (resolved-rate control through the damped pseudo-inverse of the Jacobian)."""
    cfg = env.config
    q, qd = env.qpos[:, : env.n_links], env.qvel[:, : env.n_links]
    ee, button = env.ee_pos, env.button_pos
    approach = button + np.array([-0.045, 0.0])
    phase |= np.linalg.norm(ee - approach, axis=1) < 0.01
    contact_x = cfg.goal_x - 0.015 - 0.01  # button half size + fingertip radius
    goal_point = np.array([contact_x, cfg.channel_y])
    desired = np.where(phase[:, None], goal_point, approach)
    vel = 8.0 * (desired - ee)
    speed = np.linalg.norm(vel, axis=1, keepdims=True)
    vel *= np.minimum(1.0, 0.6 / np.maximum(speed, 1e-9))
    jac = ee_jacobian(q, env.link_lengths)
    jjt = jac @ jac.transpose(0, 2, 1) + 1e-4 * np.eye(2)
    qd_des = np.einsum("nji,nj->ni", jac, np.linalg.solve(jjt, vel[..., None])[..., 0])
    return np.clip(qd_des - qd, -1.0, 1.0)


@pytest.mark.parametrize("eid", PUSH_IDS)
def test_scripted_push_reaches_the_goal_and_succeeds(eid: str) -> None:
    env = make_batched(eid, 8, reward="full")
    assert isinstance(env, ReacherPushBatched)
    _, info = env.reset(seed=21)
    start = info["button_start"][:, 0].copy()
    phase = np.zeros(8, dtype=bool)
    returns = np.zeros(8)
    for _ in range(env.max_episode_steps):
        _, reward, _, trunc, info = env.step(_scripted_push(env, phase))
        returns += reward
    assert trunc.all()
    button_x = info["button_pos"][:, 0]
    assert np.all(button_x > start + 0.08)  # pushed all the way...
    assert np.all(np.abs(button_x - env.config.goal_x) < env.config.goal_tol)
    assert info["is_success"].all()  # ... and the arm settled
    # A do-nothing policy scores worse under the full reward.
    idle = make_batched(eid, 8, reward="full")
    idle.reset(seed=21)
    idle_returns = sum(idle.step(np.zeros((8, env.n_links)))[1] for _ in range(100))
    assert np.all(returns > idle_returns)


# ---------------------------------------------------------------- errors
def test_unknown_names_raise_pved_error() -> None:
    with pytest.raises(PvedError, match="Reacher5"):
        env_id("Reacher5", "Reach")
    with pytest.raises(PvedError, match="Fly"):
        env_id("Reacher3", "Fly")
    with pytest.raises(PvedError, match="pved/Nope-v0"):
        make_batched("pved/Nope-v0", 2)
    with pytest.raises(PvedError, match="pved/Nope-v0"):
        make("pved/Nope-v0")
    with pytest.raises(PvedError, match="bogus"):
        make("pved/Reacher4Push-v0", reward="bogus")
    with pytest.raises(PvedError, match="bogus"):
        make_batched("pved/Reacher3Push-v0", 2, reward="bogus")
    with pytest.raises(PvedError, match="restricted"):
        make_batched("pved/Reacher3Reach-v0", 2, reward="restricted")
    with pytest.raises(PvedError, match="Reacher9"):
        default_config("Reacher9", "Reach")
    with pytest.raises(PvedError, match="Peg"):
        default_config("Reacher3", "Peg")
    with pytest.raises(PvedError, match="num_envs"):
        make_batched("pved/Reacher3Reach-v0", 0)
    with pytest.raises(PvedError, match="agent"):
        make_batched("pved/Reacher3Reach-v0", 2, agent="Reacher4")


def test_bad_inputs_raise_pved_error() -> None:
    env = make_batched("pved/Reacher3Push-v0", 2)
    with pytest.raises(PvedError, match="reset"):
        env.step(np.zeros((2, 3)))
    env.reset(seed=0)
    with pytest.raises(PvedError, match="shape"):
        env.step(np.zeros((2, 4)))
    with pytest.raises(PvedError, match="NaN"):
        env.step(np.full((2, 3), np.nan))
    with pytest.raises(PvedError, match="target"):
        env.reset(options={"target": np.zeros((2, 2))})
    with pytest.raises(PvedError, match="channel"):
        env.reset(options={"button_start": np.array([-0.1, 0.0])})
    with pytest.raises(PvedError, match="link_lengths"):
        import dataclasses

        cfg = dataclasses.replace(default_config("Reacher3", "Push"), link_lengths=(0.1, 0.1, 0.1))
        make_batched("pved/Reacher3Push-v0", 1, config=cfg)
    with pytest.raises(PvedError, match="Reacher4"):
        make_batched("pved/Reacher3Reach-v0", 1, config=default_config("Reacher4", "Reach"))
