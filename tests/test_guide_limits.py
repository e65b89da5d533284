"""Issue 64, item 2: a guide on the mean action that cannot take PPO's budget.

PPO's own gradient is clipped exactly as without a guide; the guide's parameter gradient is
scaled to at most ρ times that clipped norm and added (``pved.rl.guide``). The align
guide weighs 0 at rows whose D lies far past the matched training pairs' (the D gate), and
a reward gate turns any guide off for good once the task is being found.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from helpers import first_minibatch, params_of, push_bank_and_model
from pved.envs import make_batched
from pved.envs.toy import PointTarget1D
from pved.errors import PvedError
from pved.experiments.transfer_spec import gate_score, guide_limits
from pved.models import PVED
from pved.models.base import SharedRep
from pved.pair import resolve_pair
from pved.rl.guide import GATE_EPISODES, GUIDE_CONTEXT, GUIDE_GRAD_RATIO, GUIDE_MASK, RewardGate
from pved.rl.ppo import PPOConfig, _Trainer, train_ppo
from pved.run_layout import model_dataset_path
from pved.runs import Run, file_digest
from pved.spec import PRESETS
from pved.transfer.align_guide import D_GATE_FACTOR, D_GATE_QUANTILE, matched_distance_limit
from pved.transfer.shaping import LatentShaping, ShapedBatchedEnv
from pved.transfer.source_bank import SourceBank

TARGET_PUSH = "pved/Reacher4Push-v0"


class _Pull:
    """A guide pulling the mean action to the context's column: loss k·mean((μ − c)²); it
    counts the rows it is asked about."""

    context_dim = 1

    def __init__(self, k: float) -> None:
        self.k = k
        self.rows: list[int] = []

    def loss_grad(
        self, context: np.ndarray, mean: np.ndarray, progress: float
    ) -> tuple[float, np.ndarray]:
        self.rows.append(len(mean))
        gap = mean - context
        return self.k * float((gap**2).mean()), (2 * self.k * gap / gap.size).astype(np.float32)


class _Toy(PointTarget1D):
    """The toy task, with a guide (or none) whose context is 0.7 and, with ``mask``, the
    guide's rows of the even copies left out."""

    def __init__(self, n: int, guide: _Pull | None, mask: bool = False) -> None:
        super().__init__(n)
        self.action_guide = guide
        self.mask = mask

    def step(self, actions: np.ndarray):  # type: ignore[no-untyped-def]
        obs, reward, term, trunc, info = super().step(actions)
        info = dict(info)
        if self.action_guide is not None:
            info[GUIDE_CONTEXT] = np.full((self.num_envs, 1), 0.7)
            if self.mask:
                info[GUIDE_MASK] = np.arange(self.num_envs) % 2 == 1
        return obs, reward, term, trunc, info


def _cfg(backend: str = "numpy", **kw: Any) -> PPOConfig:
    base = dict(num_envs=4, steps_per_env=32, minibatch_size=128, epochs=1, hidden_sizes=(16, 16),
                total_steps=128, checkpoint_every=0, seed=1, backend=backend)  # fmt: skip
    return PPOConfig(**{**base, **kw})


def _one_step(env: _Toy, cfg: PPOConfig) -> dict[str, np.ndarray]:
    """One PPO update of one minibatch on ``env``: what Adam was given, and (with a
    guide) PPO's clipped gradient and the guide's, as they were before they were added."""
    tr = _Trainer(env, cfg)
    tr.reset_env(0)
    out: dict[str, np.ndarray] = {}
    step, add = tr.adam.step, tr._add_guide

    def spy_step(params: np.ndarray, grads: np.ndarray, lr: float) -> None:
        out["adam"] = grads.copy()
        step(params, grads, lr)

    def spy_add(stats: dict[str, float]) -> None:
        out["ppo"], out["guide"] = tr.flat.grad_np.copy(), tr.guide_grad.copy()
        add(stats)
        out["stats"] = np.array([stats["guide_grad_ratio"], stats["guide_bounded"]])

    tr.adam.step, tr._add_guide = spy_step, spy_add  # type: ignore[method-assign]
    tr.rollout()
    tr.learn(*tr.advantages())
    return out


@pytest.mark.parametrize("backend", ["numpy", "torch"])
@pytest.mark.parametrize("k", [1e4, 1e-4])
def test_the_guide_adds_at_most_rho_times_ppo_s_clipped_step_which_it_leaves_alone(
    backend: str, k: float
) -> None:
    plain = _one_step(_Toy(4, None), _cfg(backend))
    guided = _one_step(_Toy(4, _Pull(k)), _cfg(backend))
    # PPO's own gradient, clipped, is plain PPO's to the bit
    np.testing.assert_array_equal(guided["ppo"], plain["adam"])
    added = guided["adam"] - guided["ppo"]
    ppo_norm, added_norm = np.linalg.norm(guided["ppo"]), np.linalg.norm(added)
    assert added_norm <= GUIDE_GRAD_RATIO * ppo_norm * (1 + 1e-5)
    guide_norm = np.linalg.norm(guided["guide"])
    assert guide_norm > 0 and not guided["guide"][-1]  # the actor's; log-std untouched
    ratio, bounded = guided["stats"]
    if k > 1:  # a strong guide is scaled down to ρ of PPO's step, along its own direction
        assert bounded == 1.0 and ratio == pytest.approx(GUIDE_GRAD_RATIO, rel=1e-5)
        np.testing.assert_allclose(added, guided["guide"] * (added_norm / guide_norm), atol=1e-6)
    else:  # a weak one is added as it is
        assert bounded == 0.0 and ratio == pytest.approx(guide_norm / ppo_norm, rel=1e-4)
        np.testing.assert_array_equal(guided["adam"], guided["ppo"] + guided["guide"])


@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_a_guide_of_zero_gradient_leaves_ppo_s_run_as_it_was(backend: str) -> None:
    cfg = _cfg(backend, total_steps=4 * 128, minibatch_size=64, epochs=2)
    plain = params_of(train_ppo(_Toy(4, None), cfg, progress=False))
    idle = params_of(train_ppo(_Toy(4, _Pull(0.0)), cfg, progress=False))
    np.testing.assert_array_equal(plain, idle)


def test_ppo_leaves_the_guide_s_masked_rows_out() -> None:
    guide = _Pull(1.0)
    tr = _Trainer(_Toy(4, guide, mask=True), _cfg())
    tr.reset_env(0)
    tr.rollout()
    mb = first_minibatch(tr, 64)
    mask = tr.buf_gmask.reshape(-1)[:64]
    assert 0 < mask.mean() < 1
    stats, grad = tr._guide(mb[-1], np.zeros((64, 1), np.float32), mask)  # type: ignore[misc]
    kept = int(mask.sum())
    assert guide.rows[-1] == kept and not grad[mask == 0].any() and grad[mask == 1].all()
    # the guide's mean over its rows, as a mean over all with 0 at the rows left out
    assert stats["guide_rows"] == kept / 64
    assert stats["guide_loss"] == pytest.approx(0.49 * kept / 64, rel=1e-6)
    np.testing.assert_allclose(grad[mask == 1], 2 * (0 - 0.7) / 64, rtol=1e-6)


# -- the reward gate ---------------------------------------------------------------------


def _feed(gate: RewardGate, scores: np.ndarray, lengths: np.ndarray | None = None) -> None:
    """Give ``gate`` the episodes 16 an update: success where ``lengths`` is None, else
    returns of those lengths."""
    for start in range(0, len(scores), 16):
        part = scores[start : start + 16]
        if lengths is None:
            gate.observe([0.0] * len(part), [1.0] * len(part), list(part), 1000 + start)
        else:
            gate.observe(list(part), list(lengths[start : start + 16]), [], 1000 + start)


def test_the_reward_gate_stays_open_on_noise() -> None:
    rng = np.random.default_rng(0)
    for _ in range(5):
        gate = RewardGate()
        _feed(gate, (rng.random(5000) < 0.3).astype(float))
        assert gate.open and gate.t is not None and abs(gate.t) < 5
    # rewards: long and short episodes at the same reward per step do not close it
    lengths = rng.integers(10, 1000, 5000).astype(float)
    ramp = np.sort(lengths)  # episodes lasting longer and longer, as a body learns to stand
    gate = RewardGate()
    _feed(gate, ramp * (1.0 + 0.1 * rng.standard_normal(5000)), ramp)
    assert gate.open and gate.kind == "reward_per_step"


def test_the_reward_gate_closes_for_good_once_the_task_is_found() -> None:
    gate = RewardGate()
    _feed(gate, np.zeros(GATE_EPISODES))
    assert gate.open and gate.scalars()["guide/gate_open"] == 1.0
    rng = np.random.default_rng(1)
    _feed(gate, (rng.random(200) < 0.7).astype(float))
    assert not gate.open and gate.closed_at is not None and gate.kind == "success"
    closed_at = gate.closed_at
    _feed(gate, np.zeros(400))  # it stays closed, and where it closed
    assert not gate.open and gate.closed_at == closed_at
    assert gate.scalars()["guide/gate_open"] == 0.0
    again = RewardGate()
    again.load_state_dict(gate.state_dict())
    assert again.state_dict() == gate.state_dict()
    with pytest.raises(PvedError, match="reward gate"):
        RewardGate(episodes=1)


def test_a_gate_scored_by_the_task_stays_open_while_a_body_merely_lasts_longer() -> None:
    # Hopper's restricted reward: healthy 1 a step but 0 on the last, a little control
    # cost; episodes lengthen from 14 to 24 steps as it learns to stand, and it falls a
    # little further forward (x from about 0 to 0.15 m, a few cm apart), as walker-hopper's
    # guided runs did in their first 8k steps
    rng = np.random.default_rng(2)
    lengths = np.linspace(14, 24, 800).round()
    returns = (lengths - 1.0) - 0.001 * lengths
    x = np.linspace(0.0, 0.15, 800) + 0.03 * rng.standard_normal(800)
    by_step, by_t = RewardGate(), RewardGate(score="x_position")
    by_task = RewardGate(score="x_position", min_gap=0.5)
    for start in range(0, 800, 16):
        part = slice(start, start + 16)
        for gate in (by_step, by_t, by_task):
            gate.observe(list(returns[part]), list(lengths[part]), [], start, list(x[part]))
    # the reward per step rises from 13/14 to 23/24, and t alone calls 15 cm found
    assert not by_step.open and by_step.kind == "reward_per_step"
    assert not by_t.open and by_t.kind == "x_position"
    assert by_task.open and by_task.t is not None and by_task.t > 5
    # once the body gets half a metre further, it closes
    far = 0.8 + 0.1 * rng.standard_normal(64)
    for start in range(0, 64, 16):
        by_task.observe([1.0] * 16, [20.0] * 16, [], 900 + start, list(far[start : start + 16]))
    assert not by_task.open and by_task.closed_at is not None


def test_a_gate_refuses_episodes_it_cannot_score() -> None:
    with pytest.raises(PvedError, match="'x_position', which the env did not report"):
        RewardGate(score="x_position").observe([1.0, 2.0], [5.0, 6.0], [], 10, [0.3])
    with pytest.raises(PvedError, match="'is_success'"):
        RewardGate(score="is_success").observe([1.0], [5.0], [], 10)
    with pytest.raises(PvedError, match="non-empty name"):
        RewardGate(score="")
    with pytest.raises(PvedError, match="min_gap must be finite and >= 0"):
        RewardGate(min_gap=-0.1)
    old = RewardGate()
    old.observe([1.0], [5.0], [], 10)
    with pytest.raises(PvedError, match="cannot resume one that scored by 'reward_per_step'"):
        RewardGate(score="x_position").load_state_dict(old.state_dict())
    scored = RewardGate(score="x_position")
    scored.observe([1.0], [5.0], [], 10, [0.2])
    with pytest.raises(PvedError, match="scoring by None cannot resume one that scored by 'x_"):
        RewardGate().load_state_dict(scored.state_dict())
    assert RewardGate(score="return").info_key is None
    done = RewardGate(score="completed", episodes=2)
    done.observe([1.0] * 4, [5.0] * 4, [], 10, [0.0, 0.0, 1.0, 1.0])
    assert done.start == [0.0, 0.0] and done.recent == [1.0, 1.0]
    assert RewardGate(score="x_position").info_key == "x_position"


def test_each_pair_s_gate_scores_by_the_pair_s_own_measure_of_the_task() -> None:
    scores = {name: gate_score(resolve_pair(name).preset) for name in PRESETS}
    assert scores == {
        "reacher": "is_success",
        "jaco-fetch": "is_success",
        # the Hopper's reward has no forward term: nothing to hand the run over to
        "walker-hopper": "never",
        "humanoid-ant": "x_position",
    }
    preset = resolve_pair("humanoid-ant").preset
    assert guide_limits("prior", preset)["gate_score"] == "x_position"
    assert guide_limits("prior", preset)["gate_min_gap"] == 0.5  # the metric's resolution
    assert guide_limits("align", resolve_pair("reacher").preset)["gate_min_gap"] == 0.0
    odd = dataclasses.replace(preset, metric="height_mean")
    with pytest.raises(PvedError, match="cannot score an episode by the metric 'height_mean'"):
        gate_score(odd)
    # a pair whose target reward lacks the task never hands over, whatever its metric
    assert gate_score(dataclasses.replace(odd, metric_in_target_reward=False)) == "never"
    assert gate_score(dataclasses.replace(odd, metric="completion_rate")) == "completed"
    never = RewardGate(score="never")
    _feed(never, np.r_[np.zeros(GATE_EPISODES), np.ones(400)])
    assert never.open and never.info_key is None


class _Scored(_Toy):
    """The toy task whose guide's gate scores by ``info["progress"]``, which stays 0."""

    def __init__(self, n: int, guide: _Pull, report: bool = True) -> None:
        super().__init__(n, guide)
        guide.gate_score = "progress"  # type: ignore[attr-defined]
        self.report = report

    def step(self, actions: np.ndarray):  # type: ignore[no-untyped-def]
        obs, reward, term, trunc, info = super().step(actions)
        if self.report:
            info["progress"] = np.zeros(self.num_envs)
        return obs, reward, term, trunc, info


def test_ppo_scores_the_gate_by_the_guide_s_entry(tmp_path: Path) -> None:
    # the same run as below, whose success rate closes a success gate: scored by an entry
    # that never rises, the gate stays open and the guide is asked at every update
    cfg = PPOConfig(num_envs=8, steps_per_env=64, minibatch_size=128, epochs=10,
                    hidden_sizes=(32, 32), activation="tanh", total_steps=24_576,
                    checkpoint_every=0, seed=1)  # fmt: skip
    train_ppo(_Scored(8, _Pull(0.0)), cfg, Run(tmp_path / "run", {"c": 1}), progress=False)
    rows = Run(tmp_path / "run", {"c": 1}).read_metrics()
    gate = [r["guide/gate_open"] for r in rows if "guide/gate_open" in r]
    assert len(gate) == 48 and set(gate) == {1.0}
    assert all("loss/guide_loss" in r for r in rows if "guide/gate_open" in r)
    with pytest.raises(PvedError, match="'progress', which the env did not report"):
        train_ppo(_Scored(8, _Pull(0.0), report=False), cfg, None, progress=False)


class _Logged(_Toy):
    """The toy task whose guide's gate scores by ``"completed"``: whether an episode ran to
    the time limit. It keeps that of each finished episode, in the order PPO meets them
    (copies in index order at each step): the toy ends an episode early on success, so a
    gate fed successes would see the complement."""

    def __init__(self, n: int, guide: _Pull) -> None:
        super().__init__(n, guide)
        guide.gate_score = "completed"  # type: ignore[attr-defined]
        self.completed: list[float] = []

    def step(self, actions: np.ndarray):  # type: ignore[no-untyped-def]
        obs, reward, term, trunc, info = super().step(actions)
        self.completed.extend((~term[term | trunc]).astype(float).tolist())
        return obs, reward, term, trunc, info


def test_ppo_scores_a_completion_gate_by_the_episodes_that_ran_to_the_time_limit(
    tmp_path: Path,
) -> None:
    # the run below closes a success gate; here successes end episodes early, so the share
    # that ran to the limit falls as the task is found and the gate stays open
    cfg = PPOConfig(num_envs=8, steps_per_env=64, minibatch_size=128, epochs=10,
                    hidden_sizes=(32, 32), activation="tanh", total_steps=24_576,
                    checkpoint_every=0, seed=1)  # fmt: skip
    env = _Logged(8, _Pull(0.0))
    train_ppo(env, cfg, Run(tmp_path / "run", {"c": 1}), progress=False)
    rows = [r for r in Run(tmp_path / "run", {"c": 1}).read_metrics() if "guide/gate_open" in r]
    assert {r["guide/gate_open"] for r in rows} == {1.0}
    done = np.asarray(env.completed)
    assert len(done) > 4 * GATE_EPISODES
    # PPO fed the gate each episode's completion, in order: the start is the first 50's,
    # the recent window the last 50's, and the task being found shows as a fall
    assert rows[-1]["guide/gate_start"] == pytest.approx(done[:GATE_EPISODES].mean())
    assert rows[-1]["guide/gate_recent"] == pytest.approx(done[-GATE_EPISODES:].mean())
    assert rows[-1]["guide/gate_recent"] < rows[-1]["guide/gate_start"] - 0.3


def test_ppo_stops_asking_the_guide_once_the_gate_closes(tmp_path: Path) -> None:
    # the toy task's success rises from a few in a hundred to most within the run
    cfg = PPOConfig(num_envs=8, steps_per_env=64, minibatch_size=128, epochs=10,
                    hidden_sizes=(32, 32), activation="tanh", total_steps=24_576,
                    checkpoint_every=0, seed=1)  # fmt: skip
    guide = _Pull(0.0)
    env = _Toy(8, guide)
    train_ppo(env, cfg, Run(tmp_path / "run", {"c": 1}), progress=False)
    rows = Run(tmp_path / "run", {"c": 1}).read_metrics()
    gate = [r["guide/gate_open"] for r in rows if "guide/gate_open" in r]
    asked = ["loss/guide_loss" in r for r in rows if "guide/gate_open" in r]
    closed = gate.index(0.0)
    assert 0 < closed < len(gate) - 1 and set(gate[closed:]) == {0.0}
    # the update that saw the gate close is the first without the guide
    assert all(asked[:closed]) and not any(asked[closed:])
    assert all(
        r["loss/guide_grad_ratio"] <= GUIDE_GRAD_RATIO for r in rows if "loss/guide_grad_ratio" in r
    )


# -- the D gate ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def inputs() -> tuple[SourceBank, PVED]:
    return push_bank_and_model(episodes=4)


@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_the_d_gate_gives_rows_far_past_the_training_pairs_no_weight(
    inputs: tuple[SourceBank, PVED], backend: str
) -> None:
    bank, model = inputs
    target = make_batched(TARGET_PUSH, 16)
    shaping = LatentShaping(model, bank, 0.5, target.robot_state_indices, form="align")
    env = ShapedBatchedEnv(target, shaping, ("button_start",))
    guide = env.action_guide
    assert guide is not None
    if backend == "torch":
        guide.distance = None
    obs, _ = env.reset(seed=2)
    ctx = guide.context(obs, env._episode, env._t)
    mean = np.random.default_rng(0).uniform(-0.9, 0.9, (16, 4)).astype(np.float32)
    loss, grad = guide.loss_grad(ctx, mean, 0.0)
    assert guide.last_stats["d_masked"] == 0.0
    s, k = guide.state_dim, guide.code_dim
    q_s = SharedRep(torch.as_tensor(ctx[:, s : s + k]), torch.as_tensor(ctx[:, s + k :]))
    with torch.no_grad():  # the means lie inside the action box: D as Eq. 10 reads it
        x_t = torch.as_tensor(np.concatenate([ctx[:, :s], mean], 1))
        d = model.shaping_between(q_s, model.shared_target(x_t)).double().numpy()
    guide.d_limit = float(np.median(d))
    kept = d <= guide.d_limit
    gated_loss, gated = guide.loss_grad(ctx, mean, 0.0)
    assert guide.last_stats["d_masked"] == pytest.approx(1 - kept.mean())
    assert not gated[~kept].any()
    np.testing.assert_allclose(gated[kept], grad[kept], rtol=1e-5, atol=1e-8)
    assert gated_loss == pytest.approx(0.5 * np.log1p(d[kept]).sum() / 16, rel=1e-4)
    assert gated_loss < loss


def test_the_d_gate_s_limit_is_read_on_the_model_s_own_pairs(
    inputs: tuple[SourceBank, PVED], tmp_path: Path
) -> None:
    bank, model = inputs
    rng = np.random.default_rng(3)
    x_s = bank.x.reshape(-1, bank.dim)
    x_t = rng.standard_normal((len(x_s), model.target_dim)).astype(np.float32)
    with torch.no_grad():
        d = model.shaping(torch.as_tensor(x_s), torch.as_tensor(x_t)).double().numpy()
    limit = matched_distance_limit(model, x_s, x_t)
    assert limit == pytest.approx(D_GATE_FACTOR * np.quantile(d, D_GATE_QUANTILE), rel=1e-6)
    with pytest.raises(PvedError, match="matched pairs"):
        matched_distance_limit(model, x_s[:0], x_t[:0])
    # the transfer stage finds the pairs by the digest the model names
    pair = resolve_pair("reacher", tmp_path)
    pairs = tmp_path / "reacher/pairs/time/seed3/pairs.npz"
    pairs.parent.mkdir(parents=True)
    pairs.write_bytes(b"pairs")
    model.metadata["dataset"] = file_digest(pairs)
    assert model_dataset_path(pair, model) == pairs
    model.metadata["dataset"] = "0" * 16
    with pytest.raises(PvedError, match="training pairs"):
        model_dataset_path(pair, model)
    del model.metadata["dataset"]
    with pytest.raises(PvedError, match="names no training dataset"):
        model_dataset_path(pair, model)
    assert math.isfinite(limit)
