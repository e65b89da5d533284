"""The Eq. 10 shaping: the source bank, the batched form, the Gymnasium wrapper."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import pved  # noqa: F401  (registers the env ids)
from helpers import assert_ppo_resumes_exactly, placeholder_shaping_inputs, push_bank_and_model
from pved.envs import make_batched
from pved.envs.base import BatchedEnv
from pved.errors import PvedError
from pved.experiments.transfer_spec import transfer_spec
from pved.models import PVED, ModelDims, PVEDConfig
from pved.rl.ppo import PPOConfig
from pved.runs import config_hash
from pved.transfer.shaping import LatentShaping, LatentShapingWrapper, ShapedBatchedEnv
from pved.transfer.source_bank import (
    SourceBank,
    bank_time_scale,
    load_bank,
    save_bank,
    source_steps,
)

TARGET_PUSH = "pved/Reacher4Push-v0"
SOURCE_PUSH = "pved/Reacher3Push-v0"
MATCH_KEYS = ("button_start",)


# 5 updates of 4 x 32 steps, a checkpoint every 2: they cross the Push env's 100-step
# episodes' boundary, where the bank is drawn
RESUME_CFG = PPOConfig(
    num_envs=4,
    steps_per_env=32,
    minibatch_size=64,
    epochs=2,
    hidden_sizes=(32, 32),
    total_steps=5 * 4 * 32,
    checkpoint_every=2 * 4 * 32,
    eval_every=4 * 32,
    seed=2,
)


_MEAN_W = np.random.default_rng(7).normal(0.0, 0.3, (4, 64))


def _mean_action(obs: np.ndarray) -> np.ndarray:
    """A fixed deterministic "policy mean" for the Push target (4 actuators)."""
    o = np.asarray(obs, dtype=np.float64).ravel()
    return np.tanh(_MEAN_W[:, : len(o)] @ o)


@pytest.fixture(scope="module")
def inputs() -> tuple[SourceBank, PVED]:
    return push_bank_and_model(episodes=8)


@pytest.fixture(scope="module")
def bank(inputs: tuple[SourceBank, PVED]) -> SourceBank:
    return inputs[0]


@pytest.fixture(scope="module")
def shaping(inputs: tuple[SourceBank, PVED]) -> LatentShaping:
    bank, model = inputs
    target = make_batched(TARGET_PUSH, 1)
    return LatentShaping(model, bank, beta=0.1, robot_state_indices=target.robot_state_indices)


def test_bank_holds_source_rollouts_and_matches_nearest(bank: SourceBank) -> None:
    assert bank.x.shape[0] == 8 and bank.keys.shape == (8, 2)
    assert bank.header["success_rate"] == 1.0  # the shipped Push policy solves the task
    # each key is the button start the episode was reset with; the nearest is itself
    assert np.array_equal(bank.match(bank.keys), np.arange(8))
    shifted = bank.keys[3] + np.array([1e-4, 0.0])
    assert bank.match(shifted[None])[0] == 3
    # past the episode's end the lookup repeats its last row
    last = bank.lengths[2] - 1
    assert np.array_equal(bank.lookup(np.array([2]), np.array([last + 50]))[0], bank.x[2, last])
    with pytest.raises(PvedError, match="task parameters have 3 entries"):
        bank.match(np.zeros((1, 3)))


def test_bank_file_round_trip_and_bad_files(tmp_path: Path, bank: SourceBank) -> None:
    path = save_bank(tmp_path / "bank.npz", bank)
    again = load_bank(path)
    assert np.array_equal(again.x, bank.x) and again.header["match_keys"] == list(MATCH_KEYS)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(PvedError, match="corrupt or foreign"):
        load_bank(tmp_path / "junk.npz")
    np.savez(tmp_path / "foreign.npz", x=np.zeros(3))
    with pytest.raises(PvedError, match=r"corrupt or foreign|not a pved source bank"):
        load_bank(tmp_path / "foreign.npz")
    with pytest.raises(PvedError, match="not found"):
        load_bank(tmp_path / "missing.npz")


def _push_rows(
    shaping: LatentShaping, n: int, seed: int
) -> tuple[BatchedEnv, np.ndarray, np.ndarray, np.ndarray]:
    """n target Push copies reset with ``seed``: the env, its first observations, random
    actions, and the bank episodes matched to its buttons."""
    env = make_batched(TARGET_PUSH, n)
    obs, info = env.reset(seed=seed)
    actions = np.random.default_rng(seed).uniform(-1, 1, (n, env.single_action_space.shape[0]))
    return env, obs, actions, shaping.bank.match(np.asarray(info["button_start"]))


def test_shaping_is_minus_beta_times_the_models_kl(shaping: LatentShaping) -> None:
    env, obs, actions, episode = _push_rows(shaping, 3, 1)
    t = np.array([0, 7, 99])
    got = shaping.reward(obs, actions, episode, t)
    x_t = np.concatenate([obs[:, env.robot_state_indices], actions], 1)
    x_s = shaping.bank.lookup(episode, t)
    with torch.no_grad():
        kl = shaping.model.shaping(torch.as_tensor(x_s).float(), torch.as_tensor(x_t).float())
    # to float32 rounding: the bank's rows are encoded 16 or more at a time, here 3, and
    # MKL may round a row otherwise in a batch of 3 (tests/test_shaping_cache.py)
    np.testing.assert_allclose(got, -0.1 * kl.double().numpy(), rtol=1e-5)
    assert np.all(got <= 0.0)


def test_shaped_ppo_resumes_exactly(shaping: LatentShaping, tmp_path: Path) -> None:
    # the checkpoint holds the wrapper's bank episodes and steps with the Push env's state

    def make_env() -> ShapedBatchedEnv:
        return ShapedBatchedEnv(make_batched(TARGET_PUSH, 4), shaping, MATCH_KEYS)

    assert_ppo_resumes_exactly(make_env, RESUME_CFG, tmp_path)


def test_shaping_start_holds_the_term_at_zero_until_then(shaping: LatentShaping) -> None:
    env, obs, actions, episode = _push_rows(shaping, 4, 1)
    t = np.array([0, 3, 50, 99])
    # both built now: each encodes the bank at its first term, on the threads torch has
    # then, whose count MKL's rounding depends on (source_cache.py)
    from_step_0 = LatentShaping(shaping.model, shaping.bank, 0.1, env.robot_state_indices)
    full = from_step_0.reward(obs, actions, episode, t)
    late = LatentShaping(shaping.model, shaping.bank, 0.1, env.robot_state_indices, start=8)
    # calls of 4 rows: 0 and 4 rows shaped before the first two, 8 before the third
    assert np.array_equal(late.reward(obs, actions, episode, t), np.zeros(4))
    assert np.array_equal(late.reward(obs, actions, episode, t), np.zeros(4))
    assert np.array_equal(late.reward(obs, actions, episode, t), full)
    assert late.steps == 12 and np.all(full < 0.0)
    with pytest.raises(PvedError, match="shaping start must be >= 0"):
        LatentShaping(shaping.model, shaping.bank, 0.1, env.robot_state_indices, start=-1)


def test_a_shaping_stop_anneals_the_term_linearly_to_zero(shaping: LatentShaping) -> None:
    env, obs, actions, episode = _push_rows(shaping, 4, 1)
    t = np.array([0, 3, 50, 99])
    idx = env.robot_state_indices
    full = LatentShaping(shaping.model, shaping.bank, 0.1, idx).reward(obs, actions, episode, t)
    annealed = LatentShaping(shaping.model, shaping.bank, 0.1, idx, stop=16)
    # calls of 4 rows: 0, 4, 8, 12 and 16 rows shaped before them
    got = [annealed.reward(obs, actions, episode, t) for _ in range(5)]
    assert np.array_equal(got[0], full) and np.all(full < 0.0)
    for k, weight in ((1, 0.75), (2, 0.5), (3, 0.25)):
        np.testing.assert_array_equal(got[k], weight * full)
    assert np.array_equal(got[4], np.zeros(4)) and annealed.steps == 20
    # with a start, the weight still counts from the first row: 0, then 0.5
    both = LatentShaping(shaping.model, shaping.bank, 0.1, idx, start=4, stop=8)
    assert np.array_equal(both.reward(obs, actions, episode, t), np.zeros(4))
    np.testing.assert_array_equal(both.reward(obs, actions, episode, t), 0.5 * full)
    for options, message in (
        ({"stop": -1}, "shaping stop must be 0 or after the start"),
        ({"stop": 8, "start": 8}, "shaping stop must be 0 or after the start"),
        ({"stop": 8, "form": "potential"}, "potential form cannot be annealed"),
        ({"stop": 8, "form": "align"}, "align form has no shaping start or stop"),
    ):
        with pytest.raises(PvedError, match=message):
            LatentShaping(shaping.model, shaping.bank, 0.1, idx, **options)


def _spec_maker(tmp_path: Path) -> Any:
    """``spec(method, **options)``: reacher's transfer spec with placeholder model and bank
    files (hashed, not read)."""
    model, bank = placeholder_shaping_inputs(tmp_path)

    def spec(method: str, **options: Any) -> Any:
        return transfer_spec(
            "reacher", method, model_path=model, bank_path=bank, runs_root=tmp_path, **options
        )

    return spec


def test_pved_anneal_is_eq10_with_its_beta_gone_by_half_the_run(tmp_path: Path) -> None:
    spec = _spec_maker(tmp_path)

    plain, annealed = spec("pved"), spec("pved-anneal", steps=300_000)
    assert annealed.shaping_form == "eq10" and annealed.shaping_stop == 150_000
    assert annealed.config["reward_anneal"] == 0.5 and "reward_anneal" not in plain.config
    assert plain.shaping_stop == 0 and config_hash(plain.config) != config_hash(annealed.config)
    assert spec("pved-anneal", shaping_form="log1p").shaping_stop > 0
    with pytest.raises(PvedError, match="potential form cannot take"):
        spec("pved-anneal", shaping_form="potential")
    with pytest.raises(PvedError, match="term is gone by step 150000"):
        spec("pved-anneal", steps=300_000, shaping_start=200_000)


def test_the_log1p_form_is_minus_beta_times_log1p_of_the_same_distance(
    shaping: LatentShaping,
) -> None:
    env, obs, actions, episode = _push_rows(shaping, 3, 2)
    t = np.array([0, 20, 60])
    eq10 = shaping.reward(obs, actions, episode, t)
    logged = LatentShaping(
        shaping.model, shaping.bank, 0.1, env.robot_state_indices, form="log1p"
    ).reward(obs, actions, episode, t)
    # the same D either way: −0.1·D against −0.1·log(1 + D)
    np.testing.assert_allclose(logged, -0.1 * np.log1p(eq10 / -0.1), rtol=1e-9)
    # log(1 + D) < D for D > 0, so the log form is the smaller penalty
    assert np.all(eq10 < logged) and np.all(logged < 0.0)
    with pytest.raises(PvedError, match="unknown shaping form 'sqrt'"):
        LatentShaping(shaping.model, shaping.bank, 0.1, env.robot_state_indices, form="sqrt")


@pytest.mark.parametrize("clock", [{"start": 3 * 4 * 32}, {"stop": 4 * 4 * 32}])
def test_shaped_ppo_with_a_start_or_stop_resumes_exactly(
    shaping: LatentShaping, tmp_path: Path, clock: dict[str, int]
) -> None:
    # the term starts at update 3, or its weight falls over updates 1-4, across the
    # checkpoint at update 2: a resume that lost the count of rows shaped would start or
    # weigh the term an update off and end elsewhere

    def make_env() -> ShapedBatchedEnv:
        env = make_batched(TARGET_PUSH, 4)
        timed = LatentShaping(shaping.model, shaping.bank, 0.1, env.robot_state_indices, **clock)
        return ShapedBatchedEnv(env, timed, MATCH_KEYS)

    assert_ppo_resumes_exactly(make_env, RESUME_CFG, tmp_path)


def test_the_shaping_options_are_in_the_run_config_only_when_set(tmp_path: Path) -> None:
    spec = _spec_maker(tmp_path)

    plain = spec("pved")
    late, logged = spec("pved", shaping_start=300_000), spec("pved", shaping_form="log1p")
    # runs made before the options existed keep their config hashes
    assert "shaping_start" not in plain.config and plain.shaping_start == 0
    assert "shaping_form" not in plain.config and plain.shaping_form == "eq10"
    assert plain.config == spec("pved", shaping_start=0, shaping_form="eq10").config
    assert late.config["shaping_start"] == 300_000 and late.shaping_start == 300_000
    assert logged.config["shaping_form"] == "log1p" and logged.shaping_form == "log1p"
    hashes = {config_hash(x.config) for x in (plain, late, logged)}
    assert len(hashes) == 3
    for option in ({"shaping_start": 10}, {"shaping_form": "log1p"}):
        with pytest.raises(PvedError, match="'ppo' has no shaping term"):
            spec("ppo", **option)
    with pytest.raises(PvedError, match="--shaping-start must be an integer >= 0, got -5"):
        spec("pved", shaping_start=-5)
    with pytest.raises(PvedError, match="unknown shaping form 'log'"):
        spec("pved", shaping_form="log")


def test_shaped_env_refuses_a_state_for_other_copies_and_changes_nothing(
    shaping: LatentShaping,
) -> None:
    # a state saved with 4 copies loaded into 2: one-line error, the inner env untouched
    four = ShapedBatchedEnv(make_batched(TARGET_PUSH, 4), shaping, MATCH_KEYS)
    four.reset(seed=0)
    two = ShapedBatchedEnv(make_batched(TARGET_PUSH, 2), shaping, MATCH_KEYS)
    two.reset(seed=1)
    before = two.env.state_dict()  # type: ignore[attr-defined]
    with pytest.raises(PvedError, match="copies"):
        two.load_state_dict(four.state_dict())
    after = two.env.state_dict()  # type: ignore[attr-defined]
    assert repr(after) == repr(before)


def test_shaped_env_state_is_none_over_an_env_that_cannot_save(shaping: LatentShaping) -> None:
    class NoState(BatchedEnv):  # the Push env without its state_dict
        def __init__(self) -> None:
            self.inner = make_batched(TARGET_PUSH, 2)
            for name in ("num_envs", "single_observation_space", "single_action_space"):
                setattr(self, name, getattr(self.inner, name))
            self.robot_state_indices = self.inner.robot_state_indices
            self.max_episode_steps = self.inner.max_episode_steps

        def reset(self, seed: int | None = None, options: dict | None = None) -> Any:
            return self.inner.reset(seed=seed, options=options)

        def step(self, actions: np.ndarray) -> Any:
            return self.inner.step(actions)

    env = ShapedBatchedEnv(NoState(), shaping, MATCH_KEYS)
    env.reset(seed=0)
    assert env.state_dict() is None


def test_batched_and_gymnasium_forms_give_identical_shaped_transitions(
    shaping: LatentShaping,
) -> None:
    n, steps = 2, 130  # crosses one episode boundary (Push episodes are 100 steps)
    batched = ShapedBatchedEnv(make_batched(TARGET_PUSH, n), shaping, MATCH_KEYS)
    singles = [
        LatentShapingWrapper(
            gym.make(TARGET_PUSH).unwrapped, shaping, MATCH_KEYS, mean_action=_mean_action
        )
        for _ in range(n)
    ]
    obs_b, _ = batched.reset(seed=11)
    obs_s = [env.reset(seed=11 + i)[0] for i, env in enumerate(singles)]
    np.testing.assert_array_equal(obs_b, np.stack(obs_s))
    rng = np.random.default_rng(3)
    for _ in range(steps):
        act = rng.uniform(-1, 1, (n, batched.single_action_space.shape[0]))
        batched.set_mean_actions(np.stack([_mean_action(o) for o in obs_b]))
        obs_b, rew_b, term_b, trunc_b, info_b = batched.step(act)
        np.testing.assert_allclose(rew_b, info_b["env_reward"] + info_b["reward_shaping"])
        for i, env in enumerate(singles):
            o, r, term, trunc, info = env.step(act[i])
            assert info["env_reward"] == info_b["env_reward"][i]
            # the model runs in float32, whose matmuls may round differently per batch size
            assert info["reward_shaping"] == pytest.approx(info_b["reward_shaping"][i], rel=1e-5)
            assert r == pytest.approx(rew_b[i], rel=1e-5)
            assert (term, trunc) == (bool(term_b[i]), bool(trunc_b[i]))
            if term or trunc:  # the batched form autoresets; reset the single one alike
                o, _ = env.reset()
            np.testing.assert_array_equal(o, obs_b[i])


def test_wrapper_passes_gymnasium_checker(shaping: LatentShaping) -> None:
    env = LatentShapingWrapper(
        gym.make(TARGET_PUSH).unwrapped, shaping, MATCH_KEYS, mean_action=_mean_action
    )
    check_env(env, skip_render_check=True)


def test_stable_baselines3_trains_on_the_wrapper(shaping: LatentShaping) -> None:
    sb3 = pytest.importorskip("stable_baselines3")
    learner: dict[str, Any] = {}  # the model, built after the env it learns on

    def sb3_mean(obs: np.ndarray) -> np.ndarray:
        return np.asarray(learner["model"].predict(obs, deterministic=True)[0])

    env = LatentShapingWrapper(gym.make(TARGET_PUSH), shaping, MATCH_KEYS, mean_action=sb3_mean)
    model = sb3.PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    learner["model"] = model
    model.learn(total_timesteps=128)
    assert model.num_timesteps == 128


def test_the_shaping_encodes_the_mean_action_not_the_one_taken(shaping: LatentShaping) -> None:
    # Eq. 10's a_T is the policy's mean action, as in the pairs and the bank: the same
    # states with different exploration actions get the same term, that of the mean
    terms = []
    for taken in (-1.0, 1.0):
        env = ShapedBatchedEnv(make_batched(TARGET_PUSH, 3), shaping, MATCH_KEYS)
        obs, _ = env.reset(seed=4)
        mean = np.stack([_mean_action(o) for o in obs])
        env.set_mean_actions(mean)
        act = np.full((3, env.single_action_space.shape[0]), taken)
        terms.append(env.step(act)[4]["reward_shaping"])
    np.testing.assert_array_equal(terms[0], terms[1])
    expected = shaping.reward(obs, np.clip(mean, -1, 1), env._episode, np.zeros(3, dtype=int))
    np.testing.assert_allclose(terms[0], expected, rtol=1e-6)
    # without a mean for the step the env says so, rather than encode the action taken
    with pytest.raises(PvedError, match="mean action"):
        env.step(act)
    with pytest.raises(PvedError, match="mean_action"):
        LatentShapingWrapper(gym.make(TARGET_PUSH).unwrapped, shaping, MATCH_KEYS)
    # "taken" encodes the action the env is stepped with, as before
    taken = LatentShaping(shaping.model, shaping.bank, 0.1, env.robot_state_indices, action="taken")
    env = ShapedBatchedEnv(make_batched(TARGET_PUSH, 3), taken, MATCH_KEYS)
    obs, _ = env.reset(seed=4)
    got = env.step(act)[4]["reward_shaping"]
    np.testing.assert_allclose(
        got, taken.reward(obs, act, env._episode, np.zeros(3, dtype=int)), rtol=1e-6
    )
    with pytest.raises(PvedError, match="unknown shaping action 'noisy'"):
        LatentShaping(shaping.model, shaping.bank, 0.1, env.robot_state_indices, action="noisy")


def test_bank_lookup_follows_the_pairs_time_base() -> None:
    # Humanoid acts every 0.015 s, Ant every 0.05 s: the pairs put Ant step t beside the
    # Humanoid step taken at the same moment, round(t * 0.05 / 0.015); so must the bank
    steps = np.arange(400, dtype=np.float32)
    x = np.repeat(steps[None, :, None], 2, axis=0)  # each row holds its own step index
    bank = SourceBank(x, np.array([400, 100]), np.zeros((2, 0)), {"dt": 0.015})
    scale = bank_time_scale("time", bank.dt, 0.05)
    assert scale == pytest.approx(0.05 / 0.015)
    t = np.array([0, 3, 30, 60])
    got = bank.lookup(np.array([0, 0, 0, 1]), t, scale)[:, 0]
    np.testing.assert_array_equal(got, [0, 10, 100, 99])  # the short episode holds its end
    # pairs aligned by step keep step t for step t, and equal periods change nothing
    assert bank_time_scale("subsample", 0.015, 0.05) == 1.0
    assert bank_time_scale("time", 0.008, 0.008) == 1.0
    np.testing.assert_array_equal(source_steps(t, np.full(4, 400)), t)
    with pytest.raises(PvedError, match="control periods must be positive"):
        bank_time_scale("time", 0.0, 0.05)


def test_humanoid_ant_transfer_reads_its_bank_in_physical_time() -> None:
    # the preset aligns its pairs by time; its agents' envs give the periods
    from pved.spec import get_preset

    preset = get_preset("humanoid-ant")
    dt_s = make_batched("pved/HumanoidCurve-v0", 1).dt  # type: ignore[attr-defined]
    dt_t = make_batched("pved/AntCurve-v0", 1).dt  # type: ignore[attr-defined]
    assert preset.pairing.align == "time"
    assert bank_time_scale(preset.pairing.align, dt_s, dt_t) == pytest.approx(0.05 / 0.015)
    assert bank_time_scale(get_preset("walker-hopper").pairing.align, 0.008, 0.008) == 1.0


def test_mismatched_model_and_bank_are_rejected(bank: SourceBank) -> None:
    target = make_batched(TARGET_PUSH, 1)
    wrong = PVED(ModelDims(bank.dim + 1, 20, 10, 16), PVEDConfig())
    with pytest.raises(PvedError, match="source bank rows have dim"):
        LatentShaping(wrong, bank, 0.1, target.robot_state_indices)
