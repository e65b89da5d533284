"""pved.rl: GAE, the PPO loss and its hand-written gradient, training, resume, policies,
evaluation, and the batched envs PPO is benchmarked on."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch

from helpers import Interrupt, assert_ppo_resumes_exactly, first_minibatch, params_of
from pved.envs.gym_adapter import GymnasiumBatch
from pved.envs.hopper_v5 import HopperV5Batch
from pved.envs.registry import make_batched
from pved.envs.toy import PointTarget1D
from pved.errors import PvedError
from pved.flat import FlatAdam
from pved.rl.evaluate import evaluate_policy
from pved.rl.losses import compute_gae, ppo_loss, ppo_loss_grad
from pved.rl.policy import Policy, load_policy
from pved.rl.ppo import PPOConfig, _Trainer, train_ppo
from pved.runs import Run

TOY = {
    "num_envs": 8,
    "steps_per_env": 32,
    "minibatch_size": 64,
    "epochs": 4,
    "hidden_sizes": (32, 32),
    "checkpoint_every": 0,
}


def toy_config(**overrides: Any) -> PPOConfig:
    return PPOConfig(**{"total_steps": 4 * 8 * 32, **TOY, **overrides})


# -- GAE ------------------------------------------------------------------------------


def test_compute_gae_matches_hand_computation() -> None:
    g, lam = 0.9, 0.8
    # one env, 4 steps: the episode terminates at t=1; a new one starts at t=2 and is
    # truncated at t=3 (bootstrapped from V(final_obs) = 5).
    rewards = np.array([[1.0], [2.0], [3.0], [4.0]])
    values = np.array([[0.5], [1.0], [1.5], [2.0]])
    dones = np.array([[False], [True], [False], [True]])
    next_values = np.array([[1.0], [0.0], [2.0], [5.0]])  # V(s1), terminal 0, V(s3), V(final)
    adv, ret = compute_gae(rewards, values, dones, next_values, g, lam)
    d3 = 4.0 + g * 5.0 - 2.0
    d2 = 3.0 + g * 2.0 - 1.5
    d1 = 2.0 + 0.0 - 1.0
    d0 = 1.0 + g * 1.0 - 0.5
    a3 = d3
    a2 = d2 + g * lam * a3
    a1 = d1  # episode ended: no recursion into the next episode
    a0 = d0 + g * lam * a1
    np.testing.assert_allclose(adv[:, 0], [a0, a1, a2, a3], rtol=1e-12)
    np.testing.assert_allclose(ret, adv + values, rtol=1e-12)


def test_compute_gae_rejects_mismatched_shapes() -> None:
    with pytest.raises(PvedError, match="shapes"):
        compute_gae(
            np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((3, 1), bool), np.zeros((3, 2)), 0.9, 0.9
        )


def test_rollout_bootstraps_truncation_and_not_termination() -> None:
    # Actions are zero, so the point's position x is constant within an episode and new
    # at each reset. With reward r = 1 + (1-γ)·w·x, the critic V(s) = 1/(1-γ) + w·x is
    # exact for an endless episode: every TD error is 0 when a truncated episode is
    # bootstrapped from V(final_obs) (the same x), but not from V of the next episode's
    # first observation (a new x). Copy 0 terminates instead, where V' must be 0.
    gamma, w = 0.9, 2.0
    c = 1.0 / (1.0 - gamma)

    class Env(PointTarget1D):
        def step(self, actions: np.ndarray) -> Any:
            x = self._x.copy()
            obs, _, _, trunc, info = super().step(np.zeros_like(actions))
            reward = 1.0 + (1.0 - gamma) * w * x
            terminated = np.zeros(self.num_envs, dtype=bool)
            terminated[0] = bool(trunc[0])  # copy 0 terminates where the others truncate
            return obs, reward, terminated, trunc & ~terminated, info

    cfg = PPOConfig(num_envs=3, steps_per_env=12, minibatch_size=36, gamma=gamma,
                    hidden_sizes=(4,), activation="relu", normalize_obs=False,
                    normalize_reward=False, checkpoint_every=0)  # fmt: skip
    tr = _Trainer(Env(3, max_episode_steps=5), cfg)
    (W1, b1), (W2, b2) = tr.critic  # V = c + w·(relu(x) − relu(−x)) = c + w·x
    W1[...], b1[...], W2[...], b2[...] = 0.0, 0.0, 0.0, c
    W1[0, 0], W1[1, 0], W2[0, 0], W2[0, 1] = 1.0, -1.0, w, -w
    tr.reset_env(0)
    tr.rollout()
    adv, _ = tr.advantages()
    assert tr.buf_trunc[:, 1:].sum() == 4 and tr.buf_term[:, 0].sum() == 2
    np.testing.assert_allclose(adv[:, 1:], 0.0, atol=1e-4)
    ends = np.flatnonzero(tr.buf_term[:, 0])
    td_end = tr.buf_rew[ends, 0] - tr.buf_val[ends, 0]  # r − V(s), no bootstrap
    assert np.all(np.abs(td_end) > 1.0)
    np.testing.assert_allclose(adv[ends, 0], td_end, rtol=1e-5)


def test_a_shaped_reward_is_scaled_but_never_clipped() -> None:
    # A shaped env reports its term in info["reward_shaping"]: PPO divides its reward by
    # the running std σ of the return of what it optimises, r_env − β·D, clips the env
    # part as plain PPO does and never the term, so the optimised reward is (r_env −
    # β·D)/σ wherever the env clip does not bind (linear in β).
    class Shaped(PointTarget1D):
        def __init__(self, n: int, shaping: np.ndarray | None) -> None:
            super().__init__(n, max_episode_steps=7)
            self.shaping, self.t = shaping, 0
            self.env_rewards: list[np.ndarray] = []

        def step(self, actions: np.ndarray) -> Any:
            obs, reward, term, trunc, info = super().step(actions)
            self.env_rewards.append(np.asarray(reward, dtype=np.float64).copy())
            if self.shaping is not None:
                added = self.shaping[self.t]
                info = {**info, "env_reward": reward, "reward_shaping": added}
                reward = reward + added
            self.t += 1
            return obs, reward, term, trunc, info

    # a term that is small but for one spike of −1000 at step 15 of copy 1
    spike = np.full((20, 3), -0.01)
    spike[15, 1] = -1000.0
    cfg = PPOConfig(num_envs=3, steps_per_env=20, minibatch_size=60, hidden_sizes=(4,),
                    reward_clip=5.0, checkpoint_every=0)  # fmt: skip
    plain, shaped = _Trainer(Shaped(3, None), cfg), _Trainer(Shaped(3, spike), cfg)
    for tr in (plain, shaped):
        tr.reset_env(0)
        tr.rollout()
    assert np.all(np.abs(plain.buf_rew) <= cfg.reward_clip)
    # the spike passes unclipped, scaled by the running σ of the shaped returns
    assert shaped.buf_rew[15, 1] < -cfg.reward_clip
    # the last step's reward is (r_env + term)/σ with σ the final running std
    sigma = math.sqrt(float(shaped.ret_rms.var) + 1e-8)
    env_last = shaped.env.env_rewards[-1]  # type: ignore[attr-defined]
    np.testing.assert_allclose(shaped.buf_rew[-1], (env_last + spike[-1]) / sigma)
    # the env part is clipped as in plain PPO (here it never reaches the clip) ...
    assert shaped.clipped_share == plain.clipped_share == 0.0
    # ... so a zero term is plain PPO's reward to the bit
    zero = _Trainer(Shaped(3, np.zeros((20, 3))), cfg)
    zero.reset_env(0)
    zero.rollout()
    np.testing.assert_array_equal(zero.buf_rew, plain.buf_rew)


def test_ppo_gives_a_shaped_env_the_clipped_mean_action_before_each_step() -> None:
    # Eq. 10 encodes the policy's mean action (the pairs' and the bank's), not the sampled one
    class Recording(PointTarget1D):
        def __init__(self) -> None:
            super().__init__(2, max_episode_steps=5)
            self.means: list[np.ndarray] = []
            self.taken: list[np.ndarray] = []

        def set_mean_actions(self, mean: np.ndarray) -> None:
            self.means.append(mean.copy())

        def step(self, actions: np.ndarray) -> Any:
            assert len(self.means) == len(self.taken) + 1  # the mean came first
            self.taken.append(np.asarray(actions).copy())
            return super().step(actions)

    env = Recording()
    cfg = PPOConfig(num_envs=2, steps_per_env=8, minibatch_size=16, hidden_sizes=(4,),
                    init_log_std=1.0, checkpoint_every=0)  # fmt: skip
    tr = _Trainer(env, cfg)
    tr.reset_env(0)
    tr.rollout()
    means, taken = np.stack(env.means), np.stack(env.taken)
    assert means.shape == taken.shape == (8, 2, 1)
    low, high = env.single_action_space.low, env.single_action_space.high
    assert np.all(means >= low) and np.all(means <= high)
    np.testing.assert_allclose(
        means[:, :, 0], np.clip(_first_means(tr), low, high)[:, :, 0], rtol=1e-5, atol=1e-6
    )
    assert not np.allclose(means, taken)  # exploration noise is in the taken actions only


def _first_means(tr: _Trainer) -> np.ndarray:
    """The policy's mean actions (T, N, A) at the rollout's normalised observations."""
    return np.stack([tr._forward(o.astype(np.float64))[0] for o in tr.buf_obs])


# -- loss and gradient --------------------------------------------------------------


@pytest.mark.parametrize("clip_value", [None, 0.1])
def test_ppo_loss_grad_matches_autograd(clip_value: float | None) -> None:
    rng = np.random.default_rng(0)
    B, A = 64, 3
    f = np.float32
    mean = rng.normal(size=(B, A)).astype(f)
    log_std = rng.normal(scale=0.3, size=A).astype(f)
    actions = (mean + rng.normal(size=(B, A))).astype(f)
    values = rng.normal(size=B).astype(f)
    old_values = (values + rng.normal(scale=0.2, size=B)).astype(f)
    returns = rng.normal(size=B).astype(f)
    advantages = rng.normal(size=B).astype(f)
    # old log-probs far enough from the new ones that many ratios are clipped
    old_lp = (
        -0.5 * (((actions - mean) / np.exp(log_std)) ** 2).sum(1)
        - log_std.sum()
        - 1.5 * math.log(2 * math.pi)
    ).astype(f)
    old_lp = (old_lp + rng.normal(scale=0.3, size=B)).astype(f)
    kw = {"clip": 0.2, "clip_value": clip_value, "ent_coef": 0.01, "vf_coef": 0.7}
    stats, d_mean, d_log_std, d_values = ppo_loss_grad(
        mean, log_std, values, actions, old_lp, advantages, returns, old_values, **kw
    )

    t = {
        k: torch.tensor(v, requires_grad=k in ("mean", "log_std", "values"))
        for k, v in {"mean": mean, "log_std": log_std, "values": values}.items()
    }
    loss, tstats = ppo_loss(
        t["mean"],
        t["log_std"],
        t["values"],
        *(torch.tensor(x) for x in (actions, old_lp, advantages, returns, old_values)),
        **kw,
    )
    loss.backward()
    assert 0.1 < stats["clip_fraction"] < 0.9
    assert stats["loss"] == pytest.approx(float(loss.detach()), rel=1e-5)
    for k in ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction"):
        assert stats[k] == pytest.approx(float(tstats[k]), rel=1e-5, abs=1e-7)
    np.testing.assert_allclose(d_mean, t["mean"].grad.numpy(), rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(d_log_std, t["log_std"].grad.numpy(), rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(d_values, t["values"].grad.numpy(), rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize("activation", ["tanh", "relu", "leaky_relu"])
def test_numpy_backward_matches_autograd_through_networks(activation: str) -> None:
    cfg = PPOConfig(
        num_envs=4,
        steps_per_env=32,
        minibatch_size=64,
        activation=activation,
        ent_coef=0.01,
        checkpoint_every=0,
    )
    tr = _Trainer(HopperV5Batch(4), cfg)
    tr.reset_env(0)
    tr.rollout()
    mb = first_minibatch(tr, 64)
    tr.flat.flat_np += (
        np.random.default_rng(1).normal(scale=0.05, size=tr.flat.flat_np.size).astype(np.float32)
    )
    s_np = tr._grad_numpy(*mb)
    g_np = tr.flat.grad_np.copy()
    s_t = tr._grad_torch(*mb)
    g_t = tr.flat.grad_np.copy()
    assert s_np["clip_fraction"] > 0.0
    assert s_np["loss"] == pytest.approx(s_t["loss"], rel=1e-5)
    assert np.abs(g_np - g_t).max() <= 1e-5 * np.abs(g_t).max()


def test_flat_adam_matches_torch_adam() -> None:
    rng = np.random.default_rng(0)
    p0 = rng.normal(size=50).astype(np.float32)
    ours, theirs = p0.copy(), torch.nn.Parameter(torch.tensor(p0))
    adam = FlatAdam(50, eps=1e-5)
    opt = torch.optim.Adam([theirs], lr=3e-3, eps=1e-5)
    for _ in range(20):
        g = rng.normal(size=50).astype(np.float32)
        adam.step(ours, g, 3e-3)
        theirs.grad = torch.tensor(g)
        opt.step()
    np.testing.assert_allclose(ours, theirs.detach().numpy(), rtol=0, atol=1e-6)


# -- training --------------------------------------------------------------------------


def test_same_seed_same_parameters_different_seed_different() -> None:
    a = params_of(train_ppo(PointTarget1D(8), toy_config(seed=3), progress=False))
    b = params_of(train_ppo(PointTarget1D(8), toy_config(seed=3), progress=False))
    c = params_of(train_ppo(PointTarget1D(8), toy_config(seed=4), progress=False))
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)


def test_numpy_and_torch_backends_train_alike() -> None:
    a = params_of(train_ppo(PointTarget1D(8), toy_config(seed=5, total_steps=256), progress=False))
    b = params_of(
        train_ppo(
            PointTarget1D(8), toy_config(seed=5, total_steps=256, backend="torch"), progress=False
        )
    )
    assert np.allclose(a, b, atol=1e-4)


class RandomPolicy:
    def act(
        self, obs: np.ndarray, deterministic: bool = False, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        assert rng is not None
        return rng.uniform(-1.0, 1.0, size=(obs.shape[0], 1))


def test_learns_toy_env_within_seconds() -> None:
    cfg = toy_config(
        total_steps=24_576,
        steps_per_env=64,
        minibatch_size=128,
        epochs=10,
        activation="tanh",
        seed=1,
    )
    policy = train_ppo(PointTarget1D(8), cfg, progress=False)
    learned = evaluate_policy(policy, PointTarget1D(8), episodes=40, seed=99)
    random = evaluate_policy(
        RandomPolicy(), PointTarget1D(8), episodes=40, seed=99, deterministic=False
    )  # type: ignore[arg-type]
    assert random["return_mean"] < -15.0
    assert learned["return_mean"] > -6.0
    assert learned["success_rate"] > 0.9


def test_logs_and_evaluates(tmp_path: Path) -> None:
    cfg = toy_config(eval_every=512)
    calls: list[int] = []

    def eval_fn(policy: Policy, steps: int) -> dict[str, float]:
        calls.append(steps)
        return {"return_mean": float(steps)}

    run = Run(tmp_path / "run", {"ppo": cfg})
    train_ppo(PointTarget1D(8), cfg, run, eval_fn=eval_fn, progress=False)
    assert calls == [0, 512, 1024]
    records = run.read_metrics()
    updates = [r for r in records if "loss/approx_kl" in r]
    assert len(updates) == 4
    for key in (
        "loss/clip_fraction",
        "loss/value_loss",
        "time/steps_per_s",
        "episode/return_mean",
        "episode/success_rate",
    ):
        assert any(r.get(key) is not None for r in updates), key
    assert [r["eval/return_mean"] for r in records if "eval/return_mean" in r] == [
        0.0,
        512.0,
        1024.0,
    ]
    assert load_policy(run.path / "policy.pt").metadata["training_steps"] == 1024


@pytest.mark.parametrize(
    "make_env",
    [
        PointTarget1D,
        HopperV5Batch,
        # pved's own MuJoCo envs, one of each family: their state goes into the checkpoint
        lambda n: make_batched("pved/Reacher4Push-v0", n),
        lambda n: make_batched("pved/Fetch4Peg-v0", n),
        lambda n: make_batched("pved/AntCurve-v0", n),
    ],
    ids=["toy", "hopper-v5", "reacher4-push", "fetch4-peg", "ant-curve"],
)
def test_resume_from_checkpoint_is_exact(tmp_path: Path, make_env: Any) -> None:
    n = 8
    cfg = toy_config(total_steps=5 * n * 32, checkpoint_every=2 * n * 32, eval_every=n * 32, seed=2)
    assert_ppo_resumes_exactly(lambda: make_env(n), cfg, tmp_path)


def test_a_run_killed_before_its_first_checkpoint_starts_over_cleanly(tmp_path: Path) -> None:
    n = 8
    cfg = toy_config(total_steps=4 * n * 32, checkpoint_every=10**9, eval_every=n * 32, seed=2)

    def crash_at_3rd_update(policy: Policy, steps: int) -> dict[str, float]:
        if steps == 3 * n * 32:
            raise Interrupt
        return {"score": float(steps)}

    run = Run(tmp_path / "r", {"c": 1})
    with pytest.raises(Interrupt):
        train_ppo(PointTarget1D(n), cfg, run, eval_fn=crash_at_3rd_update, progress=False)
    assert run.latest_checkpoint() is None and run.read_metrics()

    def score(policy: Policy, steps: int) -> dict[str, float]:
        return {"score": float(steps)}

    train_ppo(PointTarget1D(n), cfg, Run(tmp_path / "r", {"c": 1}), eval_fn=score, progress=False)
    # the records of the killed attempt are gone: each step is logged once
    evals = [r["step"] for r in run.read_metrics() if "eval/score" in r]
    assert evals == [k * n * 32 for k in range(5)]


def test_a_run_killed_after_its_last_checkpoint_logs_its_final_evaluation_once(
    tmp_path: Path,
) -> None:
    # killed after the checkpoint of its last update and its final evaluation, before the
    # stage wrote its result (seen when a Ray node died): the retry resumes from that
    # checkpoint, evaluates again and must not leave that evaluation logged twice
    n = 8
    cfg = toy_config(total_steps=2 * n * 32, checkpoint_every=10**9, eval_every=n * 32)

    def score(policy: Policy, steps: int) -> dict[str, float]:
        return {"score": float(steps)}

    run = Run(tmp_path / "r", {"c": 1})
    options: dict[str, Any] = {"eval_fn": score, "checkpoint_every_s": 0, "progress": False}
    first = train_ppo(PointTarget1D(n), cfg, run, **options)
    again = train_ppo(PointTarget1D(n), cfg, Run(tmp_path / "r", {"c": 1}), **options)
    assert np.array_equal(params_of(first), params_of(again))
    evals = [r["step"] for r in run.read_metrics() if "eval/score" in r]
    assert evals == [0, n * 32, 2 * n * 32]
    assert [r["step"] for r in run.read_metrics() if "loss/loss" in r] == [n * 32, 2 * n * 32]


def test_checkpoints_by_wall_time_resume_exactly_and_leave_the_step_schedule(
    tmp_path: Path,
) -> None:
    n = 8
    per_update = n * 32
    # no checkpoint by steps within the run: only the clock takes them
    cfg = toy_config(total_steps=6 * per_update, checkpoint_every=10**9, eval_every=per_update)
    straight = train_ppo(
        PointTarget1D(n),
        cfg,
        Run(tmp_path / "a", {"c": 1}),
        progress=False,
        checkpoint_every_s=None,
    )
    assert not list((tmp_path / "a" / "checkpoints").glob("*.pt"))

    # A clock that reads 40 s per update (set as each update's evaluation sees it): with
    # a minute between checkpoints, one is due after updates 2 and 4.
    now = [0.0]

    def clock() -> float:
        return now[0]

    def crash_at(update: int | None) -> Callable[[Policy, int], dict[str, float]]:
        def evaluate(policy: Policy, steps: int) -> dict[str, float]:
            now[0] = 40.0 * steps / per_update
            if steps == (update or -1) * per_update:
                raise Interrupt
            return {"score": float(steps)}

        return evaluate

    run = Run(tmp_path / "b", {"c": 1})
    with pytest.raises(Interrupt):  # killed after update 4, before its checkpoint is taken
        train_ppo(PointTarget1D(n), cfg, run, eval_fn=crash_at(4), progress=False, clock=clock)
    state = run.latest_checkpoint()
    assert state is not None and state["global_step"] == 2 * per_update
    assert state["next_checkpoint"] == 10**9  # the schedule by steps is left as it was
    now[0] = 0.0
    resumed = train_ppo(
        PointTarget1D(n),
        cfg,
        Run(tmp_path / "b", {"c": 1}),
        eval_fn=crash_at(None),
        progress=False,
        clock=clock,
    )
    assert np.array_equal(params_of(straight), params_of(resumed))
    evals = [r["step"] for r in run.read_metrics() if "eval/score" in r]
    assert evals == [k * per_update for k in range(7)]  # resumed at update 3, each logged once
    with pytest.raises(PvedError, match="checkpoint_every_s must be a number >= 0, got -1"):
        train_ppo(PointTarget1D(n), cfg, progress=False, checkpoint_every_s=-1)


def test_resume_refuses_other_config(tmp_path: Path) -> None:
    cfg = toy_config(checkpoint_every=256)
    train_ppo(PointTarget1D(8), cfg, Run(tmp_path / "r", {"c": 1}), progress=False)
    with pytest.raises(PvedError, match="different PPOConfig"):
        train_ppo(
            PointTarget1D(8),
            toy_config(checkpoint_every=256, lr=1e-3),
            Run(tmp_path / "r", {"c": 1}),
            progress=False,
        )


class NaNRewardEnv(PointTarget1D):
    def __init__(self, n: int, at_step: int) -> None:
        super().__init__(n)
        self.count, self.at_step = 0, at_step

    def step(self, actions: np.ndarray) -> Any:
        obs, reward, term, trunc, info = super().step(actions)
        self.count += 1
        if self.count >= self.at_step:
            reward = reward * np.nan
        return obs, reward, term, trunc, info


def test_nan_in_loss_raises() -> None:
    # rewards turn NaN during the 2nd rollout (32 steps per env each)
    with pytest.raises(PvedError, match=r"NaN.* in PPO loss at update 2"):
        train_ppo(NaNRewardEnv(8, at_step=40), toy_config(normalize_reward=False), progress=False)


def test_config_and_env_checks() -> None:
    with pytest.raises(PvedError, match="minibatch_size"):
        PPOConfig(num_envs=4, steps_per_env=10, minibatch_size=16)
    with pytest.raises(PvedError, match="activation"):
        PPOConfig(activation="sigmoid")
    with pytest.raises(PvedError, match="num_envs"):
        train_ppo(PointTarget1D(4), toy_config(), progress=False)
    assert PPOConfig.from_dict(toy_config().to_dict()) == toy_config()


# -- policy files ------------------------------------------------------------------------


def test_policy_save_load_round_trip(tmp_path: Path) -> None:
    policy = train_ppo(PointTarget1D(8), toy_config(normalize_obs=True), progress=False)
    path = policy.save(tmp_path / "p.pt", {"note": "hello", "pair": ["a", "b"]})
    raw = torch.load(path, weights_only=True)
    assert raw["metadata"]["note"] == "hello"
    loaded = load_policy(path)
    obs = np.random.default_rng(0).normal(size=(5, 2))
    np.testing.assert_array_equal(
        loaded.act(obs, deterministic=True), policy.act(obs, deterministic=True)
    )
    np.testing.assert_array_equal(loaded.value(obs), policy.value(obs))
    a1 = loaded.act(obs, rng=np.random.default_rng(1))
    a2 = policy.act(obs, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(a1, a2)
    meta = loaded.metadata
    assert (meta["obs_dim"], meta["act_dim"], meta["hidden_sizes"]) == (2, 1, [32, 32])
    assert meta["env_id"] == PointTarget1D.env_id and meta["training_steps"] == 1024
    assert meta["seed"] == 0 and "pved_version" in meta
    assert loaded.obs_normalizer.enabled and loaded.obs_normalizer.rms.count > 1000
    with pytest.raises(PvedError, match="shape"):
        loaded.act(np.zeros((3, 5)))


def test_corrupt_or_foreign_policy_file_raises(tmp_path: Path) -> None:
    policy = train_ppo(PointTarget1D(8), toy_config(total_steps=256), progress=False)
    good = policy.save(tmp_path / "good.pt")
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[:200])
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a policy at all")
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    wrong_shape = tmp_path / "wrong.pt"
    state = policy.state()
    state["metadata"]["obs_dim"] = 7
    torch.save(state, wrong_shape)
    for path in (truncated, garbage, foreign, wrong_shape, tmp_path / "missing.pt"):
        with pytest.raises(PvedError):
            load_policy(path)


# -- evaluation ------------------------------------------------------------------------------


def test_evaluate_policy_runs_exact_episode_count() -> None:
    result = evaluate_policy(
        RandomPolicy(),
        PointTarget1D(3),
        episodes=7,
        seed=0,
        deterministic=False,
        info_keys=["distance"],
    )  # type: ignore[arg-type]
    assert result["episodes"] == 7.0
    assert {"return_mean", "return_std", "length_mean", "success_rate", "distance_mean"} <= set(
        result
    )
    again = evaluate_policy(
        RandomPolicy(),
        PointTarget1D(3),
        episodes=7,
        seed=0,
        deterministic=False,
        info_keys=["distance"],
    )  # type: ignore[arg-type]
    assert result == again
    with pytest.raises(PvedError, match="no 'nope'"):
        evaluate_policy(
            RandomPolicy(),
            PointTarget1D(3),
            episodes=2,
            seed=0,
            deterministic=False,
            info_keys=["nope"],
        )  # type: ignore[arg-type]


# -- envs ------------------------------------------------------------------------------------


def test_hopper_replica_matches_gymnasium_transitions() -> None:
    n, seed = 2, 11
    batch = HopperV5Batch(n)
    envs = [gym.make("Hopper-v5") for _ in range(n)]
    obs, _ = batch.reset(seed=seed)
    ref = np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(envs)])
    assert np.array_equal(obs, ref)
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(250):
        actions = rng.uniform(-1, 1, size=(n, 3)).astype(np.float32)
        obs, reward, term, trunc, info = batch.step(actions)
        for i, env in enumerate(envs):
            o, r, te, tr, inf = env.step(actions[i])
            assert np.array_equal(info["final_obs"][i], o)
            assert (reward[i], term[i], trunc[i]) == (r, te, tr)
            assert info["x_position"][i] == inf["x_position"]
            if te or tr:
                ended += 1
                o, _ = env.reset()
            assert np.array_equal(obs[i], o)
    assert ended >= 3  # random actions topple the hopper: autoreset was exercised


def test_hopper_state_restore_is_exact() -> None:
    env = HopperV5Batch(3)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(30):
        env.step(rng.uniform(-1, 1, size=(3, 3)))
    state = env.state_dict()
    actions = rng.uniform(-1, 1, size=(40, 3, 3))
    first = [env.step(a)[0] for a in actions]
    env.load_state_dict(state)
    second = [env.step(a)[0] for a in actions]
    assert all(np.array_equal(x, y) for x, y in zip(first, second, strict=True))


def test_gymnasium_batch_matches_hopper_replica() -> None:
    adapter = GymnasiumBatch(env_id="Hopper-v5", num_envs=2)
    replica = HopperV5Batch(2)
    assert adapter.max_episode_steps == 1000 and adapter.env_id == "Hopper-v5"
    o1, _ = adapter.reset(seed=4)
    o2, _ = replica.reset(seed=4)
    assert np.array_equal(o1, o2)
    rng = np.random.default_rng(1)
    dones = 0
    for _ in range(120):
        a = rng.uniform(-1, 1, size=(2, 3))
        s1, s2 = adapter.step(a), replica.step(a)
        for x, y in zip(s1[:4], s2[:4], strict=True):
            assert np.array_equal(x, y)
        assert np.array_equal(s1[4]["final_obs"], s2[4]["final_obs"])
        assert np.array_equal(s1[4]["x_position"], s2[4]["x_position"])
        dones += int((s1[2] | s1[3]).sum())
    assert dones >= 1
    adapter.close()
