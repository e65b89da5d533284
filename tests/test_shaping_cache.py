"""Eq. 10's source half encoded once per run (pved.transfer.source_cache): the cached term
is the per-step one to the bit on pved's runs (16 copies a step), to float32 rounding on
other batch sizes, and still reads the target's own state and action."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import torch

import pved  # noqa: F401  (registers the env ids)
from pved.envs import env_id, make_batched
from pved.errors import PvedError
from pved.models import MODELS, ModelDims, build_model
from pved.models.base import SharedRep, SharedSpaceModel
from pved.pretrained import pretrained_policy_path
from pved.rl.policy import load_policy
from pved.spec import PRESETS, get_preset
from pved.transfer.shaping import LatentShaping, ShapedBatchedEnv
from pved.transfer.source_bank import SourceBank, build_source_bank, source_covered
from pved.transfer.source_cache import MIN_BATCH_ROWS, encode_bank, encode_batch_rows

TARGET_PUSH = "pved/Reacher4Push-v0"
SOURCE_PUSH = "pved/Reacher3Push-v0"
MATCH_KEYS = ("button_start",)
BETA = 0.1


@pytest.fixture(params=[1, 2], ids=["1-thread", "2-threads"])
def threads(request: pytest.FixtureRequest) -> Iterator[int]:
    """torch's (and MKL's) thread count, restored afterwards: PPO runs the shaping on
    one, and the bank is encoded otherwise on more (source_cache.py)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(request.param)
    yield request.param
    torch.set_num_threads(previous)


@pytest.fixture(scope="module")
def bank() -> SourceBank:
    env = make_batched(SOURCE_PUSH, 4)
    policy = load_policy(pretrained_policy_path("Reacher3", "Push"))
    full = build_source_bank(env, policy, 8, MATCH_KEYS, seed=5)
    # 7 episodes of 100 steps: 700 rows, not a multiple of 16, so the encode pads
    return SourceBank(full.x[:7], full.lengths[:7], full.keys[:7], full.header)


def _model(name: str, bank: SourceBank) -> SharedSpaceModel:
    target = make_batched(TARGET_PUSH, 1)
    n_tgt = len(target.robot_state_indices)
    n_src = len(bank.header["robot_state_indices"])
    dims = ModelDims(bank.dim, n_tgt + target.single_action_space.shape[0], n_src, n_tgt)
    torch.manual_seed(0)
    model = build_model(name, dims)
    # standardisation from rough data so the untrained encoders see unit-scale inputs
    model.fit_standardization(
        torch.as_tensor(bank.x.reshape(-1, bank.dim)), torch.randn(512, dims.target_dim)
    )
    return model.eval()


def _per_step_term(
    shaping: LatentShaping, obs: np.ndarray, act: np.ndarray, episode: np.ndarray, t: np.ndarray
) -> np.ndarray:
    """Eq. 10's term as it was computed before the cache: both halves encoded per step
    (and 0 past the source episode's end, the rule of docs/decisions/transfer.md)."""
    x_t = np.concatenate([obs[:, shaping.robot_state_indices], act], 1)
    x_s = shaping.bank.lookup(episode, t, shaping.time_scale)
    with torch.no_grad():
        d = shaping.model.shaping(
            torch.as_tensor(x_s, dtype=torch.float32), torch.as_tensor(x_t, dtype=torch.float32)
        )
    covered = source_covered(t, shaping.bank.lengths[episode], shaping.time_scale)
    return np.where(covered, -shaping.beta * d.double().numpy(), 0.0)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_models_shaping_is_its_distance_between_the_two_halves(name: str) -> None:
    # the cache relies on it: D(x_S, x_T) is a function of q_S(x_S) and q_T(x_T) alone
    model = build_model(name, ModelDims(14, 20, 10, 16)).eval()
    gen = torch.Generator().manual_seed(1)
    x_s, x_t = torch.randn(16, 14, generator=gen), torch.randn(16, 20, generator=gen)
    with torch.no_grad():
        d = model.shaping(x_s, x_t)
        split = model.shaping_between(model.shared_source(x_s), model.shared_target(x_t))
    assert torch.equal(d, split) and torch.all(d > 0)
    with pytest.raises(PvedError, match="batches differ in size"):
        model.shaping_between(model.shared_source(x_s[:1]), model.shared_target(x_t))


def test_the_encoded_bank_is_a_16_copy_steps_encode(bank: SourceBank) -> None:
    # a step encodes 16 rows from any episodes and steps, each at the place of its copy;
    # the bank is encoded 16 rows at a time in its own order: each row must come out the
    # same, wherever it sat in its batch (and in the padded last batch)
    model = _model("pved", bank)
    encoded = encode_bank(model, bank, 16)
    assert encoded.mean.shape == (7, bank.x.shape[1], 10) and encoded.logvar is not None
    assert bank.x.shape[0] * bank.x.shape[1] % 16 != 0  # the padded tail is covered
    rng = np.random.default_rng(0)
    with torch.no_grad():
        for _ in range(40):
            e, s = rng.integers(0, 7, 16), rng.integers(0, bank.x.shape[1], 16)
            q = model.shared_source(torch.as_tensor(bank.x[e, s]))
            assert q.logvar is not None
            assert np.array_equal(encoded.mean[e, s], q.mean.numpy())
            assert np.array_equal(encoded.logvar[e, s], q.logvar.numpy())
    with pytest.raises(PvedError, match="batches of >= 1 rows"):
        encode_bank(model, bank, 0)


@pytest.mark.parametrize(("name", "time_scale"), [("pved", 1.0), ("gupta2017", 0.3)])
def test_the_cached_term_is_the_per_step_one_to_the_bit(
    bank: SourceBank, name: str, time_scale: float, threads: int
) -> None:
    # a 16-copy shaped env (every transfer run's num_envs) over 130 steps: one episode
    # boundary, where the bank episodes are drawn again; every step's term is the one
    # the per-step encode of both halves gave
    model = _model(name, bank)
    shaping = _shaping(model, bank, time_scale)
    env = ShapedBatchedEnv(make_batched(TARGET_PUSH, 16), shaping, MATCH_KEYS)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(3)
    n_act = env.single_action_space.shape[0]
    for _ in range(130):
        mean = rng.uniform(-1.2, 1.2, (16, n_act))
        before = _per_step_term(env.shaping, obs, np.clip(mean, -1, 1), env._episode, env._t)
        env.set_mean_actions(mean)
        obs, _, _, _, info = env.step(rng.uniform(-1, 1, (16, n_act)))
        assert np.array_equal(info["reward_shaping"], before)
    assert np.all(before < 0)
    assert shaping._encoded is not None
    assert shaping._encoded.batch_rows == (512 if threads == 1 else 16)


@pytest.mark.parametrize("pair", sorted(PRESETS))
def test_each_presets_encoder_rounds_a_row_alike_in_16_and_512_rows(pair: str) -> None:
    # what the single-thread cache relies on, on each preset's encoder shapes: a 16-copy
    # step's rows encoded in batches of 512 come out as in the step's batch of 16
    preset = get_preset(pair)
    source = make_batched(env_id(preset.source_agent, preset.target_task), 1)
    target = make_batched(env_id(preset.target_agent, preset.target_task), 1)
    n_s, n_t = len(source.robot_state_indices), len(target.robot_state_indices)
    a_s, a_t = source.single_action_space.shape[0], target.single_action_space.shape[0]
    torch.manual_seed(0)
    dims = ModelDims(n_s + a_s, n_t + a_t, n_s, n_t)
    model = build_model("pved", dims, preset.model_config("pved"))
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(1024, n_s + a_s, generator=gen)
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    # and the target's: a rollout's deferred terms encode its rows 512 at a time
    x_t = torch.randn(1024, n_t + a_t, generator=gen)
    try:
        with torch.no_grad():
            big = torch.cat([model.shared_source(b).mean for b in x.split(512)])
            steps = torch.cat([model.shared_source(b).mean for b in x.split(16)])
            big_t = [model.shared_target(b) for b in x_t.split(512)]
            steps_t = [model.shared_target(b) for b in x_t.split(16)]
    finally:
        torch.set_num_threads(previous)
    assert torch.equal(big, steps)
    for part in ("mean", "logvar"):
        assert torch.equal(
            torch.cat([getattr(q, part) for q in big_t]),
            torch.cat([getattr(q, part) for q in steps_t]),
        )


def _shaping(model: SharedSpaceModel, bank: SourceBank, time_scale: float = 1.0) -> LatentShaping:
    target = make_batched(TARGET_PUSH, 1)
    return LatentShaping(model, bank, BETA, target.robot_state_indices, time_scale=time_scale)


def test_other_batch_sizes_match_to_float32_rounding(bank: SourceBank) -> None:
    # a batch's leftover rows (1 of the Gymnasium wrapper, 3 here) may take another BLAS
    # kernel in the per-step encode and round otherwise in the last bit; the term, a sum
    # of ten such terms, then agrees to about 1e-6 of itself
    shaping = _shaping(_model("pved", bank), bank)
    env = make_batched(TARGET_PUSH, 3)
    obs, _ = env.reset(seed=8)
    rng = np.random.default_rng(8)
    for _ in range(20):
        act = rng.uniform(-1, 1, (3, env.single_action_space.shape[0]))
        episode, t = rng.integers(0, 7, 3), rng.integers(0, 120, 3)
        for rows in (slice(0, 1), slice(0, 3)):
            got = shaping.reward(obs[rows], act[rows], episode[rows], t[rows])
            want = _per_step_term(shaping, obs[rows], act[rows], episode[rows], t[rows])
            np.testing.assert_allclose(got, want, rtol=1e-5)
        obs = env.step(act)[0]


def test_the_term_reads_each_targets_own_state_and_action(bank: SourceBank) -> None:
    shaping = _shaping(_model("pved", bank), bank)
    env = make_batched(TARGET_PUSH, 4)
    obs, _ = env.reset(seed=2)
    act = np.random.default_rng(2).uniform(-1, 1, (4, env.single_action_space.shape[0]))
    episode, t = np.array([0, 3, 3, 6]), np.array([0, 10, 10, 99])
    base = shaping.reward(obs, act, episode, t)
    # another action for copy 1, another state for copy 2: their terms move, no other's
    act2, obs2 = act.copy(), obs.copy()
    act2[1] = -act2[1]
    obs2[2, shaping.robot_state_indices[0]] += 0.5
    moved = shaping.reward(obs2, act2, episode, t)
    assert np.array_equal(moved[[0, 3]], base[[0, 3]])
    assert moved[1] != base[1] and moved[2] != base[2]
    # the rows travel with their bank episode and step: a permuted batch permutes the terms
    # (to float32 rounding: in a 4-row batch the BLAS may round a row by its place)
    perm = np.array([3, 0, 2, 1])
    permuted = shaping.reward(obs[perm], act[perm], episode[perm], t[perm])
    np.testing.assert_allclose(permuted, base[perm], rtol=1e-6)
    assert len(set(base.tolist())) == 4  # four different terms, so a mix-up shows
    # a bank swapped in is encoded anew, not read from the old one's cache
    shifted = SourceBank(bank.x + np.float32(0.25), bank.lengths, bank.keys, bank.header)
    shaping.bank = shifted
    per_step = _per_step_term(shaping, obs, act, episode, t)
    # 4 rows a call: to float32 rounding, as above
    np.testing.assert_allclose(shaping.reward(obs, act, episode, t), per_step, rtol=1e-5)
    assert not np.array_equal(shaping.reward(obs, act, episode, t), base)


def test_the_source_half_is_encoded_once(bank: SourceBank, monkeypatch: pytest.MonkeyPatch) -> None:
    shaping = _shaping(_model("pved", bank), bank)
    calls: list[int] = []
    encode = shaping.model.shared_source

    def counting(x: torch.Tensor) -> SharedRep:
        calls.append(len(x))
        return encode(x)

    monkeypatch.setattr(shaping.model, "shared_source", counting)
    env = make_batched(TARGET_PUSH, 2)
    obs, _ = env.reset(seed=0)
    act = np.zeros((2, env.single_action_space.shape[0]))
    for step in range(5):
        shaping.reward(obs, act, np.array([0, 1]), np.array([step, step]))
    # the bank's 700 rows once, padded to whole batches (16 rows for a 2-copy call, below
    # MIN_BATCH_ROWS, or 512 on one thread); nothing per step
    rows = encode_batch_rows(2)
    assert rows == (512 if torch.get_num_threads() == 1 else MIN_BATCH_ROWS)
    assert set(calls) == {rows} and sum(calls) == -(-700 // rows) * rows


@pytest.mark.parametrize(
    ("name", "form", "copies", "start", "stop"),
    [
        ("pved", "eq10", 16, 0, 0),
        ("pved", "potential", 16, 500, 0),
        ("gupta2017", "log1p", 16, 0, 0),
        ("pved", "potential", 3, 0, 0),
        ("pved", "eq10", 16, 160, 1600),  # pved-anneal's weight falls to 0 mid-rollout
    ],
)
def test_a_rollouts_deferred_terms_are_the_per_step_ones_to_the_bit(
    bank: SourceBank, name: str, form: str, copies: int, start: int, stop: int, threads: int
) -> None:
    # the same actions through a per-step env and a deferred one, 130 steps (an episode
    # boundary, a shaping start or stop mid-rollout), the terms taken in rollouts of 70, 60
    model = _model(name, bank)

    def make() -> ShapedBatchedEnv:
        env = make_batched(TARGET_PUSH, copies)
        shaping = LatentShaping(
            model, bank, BETA, env.robot_state_indices, form=form, start=start, gamma=0.9,
            time_scale=0.3 if name == "gupta2017" else 1.0, stop=stop,
        )  # fmt: skip
        return ShapedBatchedEnv(env, shaping, MATCH_KEYS)

    per_step, deferred = make(), make()
    deferred.defer_terms()
    per_step.reset(seed=2)
    deferred.reset(seed=2)
    rng = np.random.default_rng(2)
    n_act = per_step.single_action_space.shape[0]
    terms, taken = [], []
    for step in range(130):
        mean = rng.uniform(-1.2, 1.2, (copies, n_act))
        act = rng.uniform(-1, 1, (copies, n_act))
        per_step.set_mean_actions(mean)
        deferred.set_mean_actions(mean)
        _, reward, _, _, info = per_step.step(act)
        _, d_reward, _, _, d_info = deferred.step(act)
        terms.append(info["reward_shaping"])
        assert np.array_equal(reward, info["env_reward"] + info["reward_shaping"])
        assert "reward_shaping" not in d_info
        assert np.array_equal(d_reward, info["env_reward"])
        if step in (69, 129):
            taken.append(deferred.deferred_terms())
    assert [len(t) for t in taken] == [70, 60]
    assert np.array_equal(np.concatenate(taken), np.array(terms))
    assert np.any(np.array(terms) != 0)
    if start:
        assert np.all(np.array(terms)[: -(-start // copies)] == 0)
    if stop:  # 0 from the step whose rows start at the stop on, and not all 0 before it
        assert np.all(np.array(terms)[stop // copies :] == 0)
        assert np.all(np.array(terms)[start // copies : stop // copies] != 0)
    assert np.array_equal(deferred._previous, per_step._previous)


def test_shaped_ppo_is_the_same_whether_the_terms_come_per_step_or_deferred(
    bank: SourceBank,
) -> None:
    from pved.rl.ppo import PPOConfig, train_ppo

    class PerStep(ShapedBatchedEnv):
        defer_terms = None  # type: ignore[assignment]  # PPO then takes each step's term per step

    model = _model("pved", bank)
    cfg = PPOConfig(
        num_envs=16, steps_per_env=64, minibatch_size=256, epochs=2, hidden_sizes=(16, 16),
        total_steps=3 * 16 * 64, checkpoint_every=0, seed=4,
    )  # fmt: skip
    params = []
    for cls in (ShapedBatchedEnv, PerStep):
        env = make_batched(TARGET_PUSH, 16)
        shaping = LatentShaping(model, bank, BETA, env.robot_state_indices, form="potential")
        policy = train_ppo(cls(env, shaping, MATCH_KEYS), cfg, progress=False)
        params.append(torch.cat([p.detach().flatten() for p in policy.net.parameters()]))
    assert torch.equal(params[0], params[1])


def test_a_shaped_env_with_deferred_terms_pending_refuses_to_save(bank: SourceBank) -> None:
    inner = make_batched(TARGET_PUSH, 2)
    shaping = LatentShaping(_model("pved", bank), bank, BETA, inner.robot_state_indices)
    env = ShapedBatchedEnv(inner, shaping, MATCH_KEYS)
    env.defer_terms()
    env.reset(seed=0)
    act = np.zeros((2, env.single_action_space.shape[0]))
    env.set_mean_actions(act)
    env.step(act)
    with pytest.raises(PvedError, match="deferred terms not yet taken"):
        env.state_dict()
    assert env.deferred_terms().shape == (1, 2)
    assert env.state_dict() is not None
