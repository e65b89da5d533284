"""``pved-align`` (issue 51): PVED's distance as a loss on the policy's mean action.

Why it exists: with the mean action encoded, Eq. 10's term does not depend on the action
PPO samples, so PPO's gradient cannot move the mean action towards the source's code.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch

import pved  # noqa: F401  (registers the env ids)
from helpers import (
    assert_ppo_resumes_exactly,
    first_minibatch,
    params_of,
    placeholder_shaping_inputs,
    push_bank_and_model,
)
from pved.envs import make_batched
from pved.envs.toy import PointTarget1D
from pved.errors import PvedError
from pved.experiments.stages import transfer_spec
from pved.models import PVED, build_model
from pved.rl.guide import GUIDE_CONTEXT, ActionGuide
from pved.rl.ppo import PPOConfig, _Trainer, train_ppo
from pved.transfer.align_guide import ALIGN_ANNEAL, AlignGuide
from pved.transfer.methods import get_method
from pved.transfer.shaping import LatentShaping, LatentShapingWrapper, ShapedBatchedEnv
from pved.transfer.source_bank import SourceBank

TARGET_PUSH = "pved/Reacher4Push-v0"
MATCH_KEYS = ("button_start",)


@pytest.fixture(scope="module")
def inputs() -> tuple[SourceBank, PVED]:
    return push_bank_and_model(episodes=4)


def _shaped(inputs: tuple[SourceBank, PVED], form: str, n: int = 4) -> ShapedBatchedEnv:
    bank, model = inputs
    env = make_batched(TARGET_PUSH, n)
    shaping = LatentShaping(model, bank, 0.5, env.robot_state_indices, form=form)
    return ShapedBatchedEnv(env, shaping, MATCH_KEYS)


def test_eq10_with_the_mean_action_does_not_depend_on_the_action_taken(
    inputs: tuple[SourceBank, PVED],
) -> None:
    # the reason for pved-align: two envs in the same state, the same mean action given,
    # different actions taken -> the same term, so PPO's likelihood ratio sees no signal
    terms = []
    for taken in (-0.9, 0.9):
        env = _shaped(inputs, "eq10")
        env.reset(seed=3)
        mean = np.full((4, env.single_action_space.shape[0]), 0.2)
        env.set_mean_actions(mean)
        *_, info = env.step(np.full_like(mean, taken))
        terms.append(info["reward_shaping"])
    assert np.all(terms[0] != 0)
    np.testing.assert_array_equal(terms[0], terms[1])


def test_the_align_form_pays_no_term_and_gives_the_context(
    inputs: tuple[SourceBank, PVED],
) -> None:
    env = _shaped(inputs, "align")
    guide = env.action_guide
    assert isinstance(guide, ActionGuide) and isinstance(guide, AlignGuide)
    model = inputs[1]
    state_dim = len(env.robot_state_indices)
    assert guide.context_dim == state_dim + 2 * model.config.shared_dim
    obs, _ = env.reset(seed=1)
    act = np.zeros((4, env.single_action_space.shape[0]))
    env.set_mean_actions(act)
    _, reward, _, _, info = env.step(act)
    np.testing.assert_array_equal(reward, info["env_reward"])
    assert np.all(info["reward_shaping"] == 0)
    ctx = info[GUIDE_CONTEXT]
    assert ctx.shape == (4, guide.context_dim) and ctx.dtype == np.float32
    # the pre-step robot state, then the source's code at step 0 of the matched episode
    np.testing.assert_array_equal(
        ctx[:, :state_dim], obs[:, env.robot_state_indices].astype(np.float32)
    )
    assert _shaped(inputs, "eq10").action_guide is None


def test_the_align_loss_gradient_is_the_loss_s_and_its_weight_anneals(
    inputs: tuple[SourceBank, PVED],
) -> None:
    env = _shaped(inputs, "align")
    guide = env.action_guide
    assert guide is not None
    obs, _ = env.reset(seed=2)
    ctx = guide.context(obs, env._episode, env._t)
    mean = np.random.default_rng(0).uniform(-0.8, 0.8, (4, 4)).astype(np.float32)
    loss, grad = guide.loss_grad(ctx, mean, 0.0)
    assert loss > 0 and grad.shape == mean.shape and np.abs(grad).max() > 0
    eps = 1e-2
    for i, j in ((0, 0), (3, 2)):
        up, down = mean.copy(), mean.copy()
        up[i, j] += eps
        down[i, j] -= eps
        numeric = (guide.loss_grad(ctx, up, 0.0)[0] - guide.loss_grad(ctx, down, 0.0)[0]) / (
            2 * eps
        )
        assert grad[i, j] == pytest.approx(numeric, rel=0.05, abs=1e-4)
    # β at the start, half at a quarter of the run, 0 from ALIGN_ANNEAL of it on
    assert guide.weight(0.0) == 0.5
    assert guide.weight(ALIGN_ANNEAL / 2) == pytest.approx(0.25)
    half_loss, _ = guide.loss_grad(ctx, mean, ALIGN_ANNEAL / 2)
    assert half_loss == pytest.approx(loss / 2, rel=1e-5)
    zero_loss, zero_grad = guide.loss_grad(ctx, mean, ALIGN_ANNEAL)
    assert zero_loss == 0.0 and not zero_grad.any()


@pytest.mark.parametrize("model_name", ["pved", "pved-state-only", "pved-det-shared"])
def test_the_numpy_guide_is_autograd_s(inputs: tuple[SourceBank, PVED], model_name: str) -> None:
    # the guide's loss and gradient in numpy (pved.models.numpy_distance) against the
    # autograd path it replaces, with means inside, on and outside the action box; a
    # model numpy does not cover (a point code) keeps autograd
    bank, pved_model = inputs
    env = make_batched(TARGET_PUSH, 8)
    torch.manual_seed(1)
    model = build_model(model_name, pved_model.dims)
    for norm in ("source_norm", "target_norm"):  # unit-scale inputs, as the helper's
        getattr(model, norm).load_state_dict(getattr(pved_model, norm).state_dict())
    shaping = LatentShaping(model, bank, 0.5, env.robot_state_indices, form="align")
    guide = AlignGuide(shaping, env.single_action_space.low, env.single_action_space.high, 8)
    if model_name == "pved-det-shared":
        assert guide.distance is None
        return
    assert guide.distance is not None
    obs, _ = env.reset(seed=4)
    ctx = guide.context(obs, np.arange(8) % len(bank.x), np.arange(8) * 3)
    mean = np.random.default_rng(1).uniform(-1.3, 1.3, (8, 4)).astype(np.float32)
    mean[0, 0], mean[1, 1] = 1.0, -1.0  # on the box's edge: clamp passes the gradient
    loss_np, grad_np = guide.loss_grad(ctx, mean, 0.1)
    loss_t, grad_t = guide._loss_grad_torch(ctx, mean, guide.weight(0.1))
    assert loss_np == pytest.approx(loss_t, rel=1e-5)
    np.testing.assert_allclose(grad_np, grad_t, rtol=1e-4, atol=1e-6 * np.abs(grad_t).max())
    outside = np.abs(mean) > 1.0
    assert outside.any() and not grad_np[outside].any()
    if model_name == "pved":
        assert np.abs(grad_np[~outside]).min() > 0
    else:  # the state-only encoder never sees the action
        assert not grad_np.any()


class _PullTo:
    """A guide pulling the mean action to the context's one column: loss 10·(mean − c)²."""

    context_dim = 1

    def loss_grad(
        self, context: np.ndarray, mean: np.ndarray, progress: float
    ) -> tuple[float, np.ndarray]:
        gap = mean - context
        return 10 * float((gap**2).mean()), (20 * gap / len(mean)).astype(np.float32)


class _Guided(PointTarget1D):
    """The toy env with no reward and a guide that wants the mean action at 0.7."""

    def __init__(self, n: int) -> None:
        super().__init__(n)
        self.action_guide = _PullTo()

    def step(self, actions: np.ndarray):  # type: ignore[no-untyped-def]
        obs, _, term, trunc, info = super().step(actions)
        info = dict(info)
        info[GUIDE_CONTEXT] = np.full((self.num_envs, 1), 0.7)
        return obs, np.zeros(self.num_envs), term, trunc, info


def test_ppo_follows_a_guide_on_the_mean_action() -> None:
    cfg = PPOConfig(
        num_envs=4, steps_per_env=32, minibatch_size=64, hidden_sizes=(16, 16),
        total_steps=80 * 128, checkpoint_every=0, seed=1,
    )  # fmt: skip
    guided = train_ppo(_Guided(4), cfg, progress=False)
    plain = train_ppo(PointTarget1D(4), cfg, progress=False)
    obs = np.random.default_rng(0).uniform(-1, 1, (64, 2))
    # the guide's step is at most PPO's own (GUIDE_GRAD_RATIO), so it pulls, not pins
    assert np.abs(guided.act(obs, deterministic=True) - 0.7).max() < 0.25
    assert np.abs(plain.act(obs, deterministic=True) - 0.7).max() > 0.5


def test_the_guide_s_gradient_is_the_same_in_both_backends() -> None:
    cfg = PPOConfig(
        num_envs=4, steps_per_env=32, minibatch_size=64, hidden_sizes=(16, 16),
        total_steps=4 * 128, checkpoint_every=0, seed=1,
    )  # fmt: skip
    tr = _Trainer(_Guided(4), cfg)
    tr.reset_env(0)
    tr.rollout()
    mb = first_minibatch(tr, 64)
    s_np = tr._grad_numpy(*mb)
    g_np, h_np = tr.flat.grad_np.copy(), tr.guide_grad.copy()
    s_t = tr._grad_torch(*mb)
    g_t, h_t = tr.flat.grad_np.copy(), tr.guide_grad.copy()
    assert s_np["guide_loss"] > 0 and s_np["guide_loss"] == pytest.approx(s_t["guide_loss"])
    assert s_np["loss"] == pytest.approx(s_t["loss"], rel=1e-5)
    # PPO's gradient and the guide's, kept apart until PPO's is clipped (pved.rl.guide)
    for a, b in ((g_np, g_t), (h_np, h_t)):
        assert np.abs(a - b).max() <= 1e-5 * np.abs(b).max()
    assert np.abs(h_np).max() > 1e-4
    # PPO's own part is the gradient without the guide
    s_plain = tr._grad_numpy(*mb[:-1])
    assert "guide_loss" not in s_plain and np.array_equal(tr.flat.grad_np, g_np)


def test_align_shaped_ppo_resumes_exactly(inputs: tuple[SourceBank, PVED], tmp_path: Path) -> None:
    cfg = PPOConfig(
        num_envs=4, steps_per_env=32, minibatch_size=64, epochs=2, hidden_sizes=(32, 32),
        total_steps=5 * 4 * 32, checkpoint_every=2 * 4 * 32, eval_every=4 * 32, seed=2,
    )  # fmt: skip
    assert_ppo_resumes_exactly(lambda: _shaped(inputs, "align"), cfg, tmp_path)
    # and the guide changed what was learned
    a = params_of(train_ppo(_shaped(inputs, "align"), cfg, progress=False))
    b = params_of(train_ppo(make_batched(TARGET_PUSH, 4), cfg, progress=False))
    assert not np.array_equal(a, b)


def test_a_faded_guide_s_zero_context_changes_nothing(
    inputs: tuple[SourceBank, PVED], monkeypatch: pytest.MonkeyPatch
) -> None:
    # once the weight is 0 the env stops looking the context up (AlignGuide.faded): the
    # run is the same to the bit as one that keeps looking it up
    cfg = PPOConfig(
        num_envs=4, steps_per_env=32, minibatch_size=64, epochs=2, hidden_sizes=(32, 32),
        total_steps=4 * 4 * 32, checkpoint_every=0, seed=3,
    )  # fmt: skip
    env = _shaped(inputs, "align")
    fading = params_of(train_ppo(env, cfg, progress=False))
    guide = env.action_guide
    assert isinstance(guide, AlignGuide) and guide.faded
    assert not guide.context(np.ones((2, env.single_observation_space.shape[0])), np.zeros(2, int),
                             np.zeros(2, int)).any()  # fmt: skip
    never = property(lambda self: False, lambda self, v: None)
    monkeypatch.setattr(AlignGuide, "faded", never, raising=False)
    looking = params_of(train_ppo(_shaped(inputs, "align"), cfg, progress=False))
    np.testing.assert_array_equal(fading, looking)


def test_pved_align_is_a_method_with_its_own_config(
    inputs: tuple[SourceBank, PVED], tmp_path: Path
) -> None:
    method = get_method("pved-align")
    assert (method.model, method.shaping_form, method.paper) == ("pved", "align", False)
    runs = tmp_path / "runs"
    placeholder_shaping_inputs(runs)
    spec = transfer_spec("reacher", "pved-align", runs_root=runs)
    assert spec.config["shaping_form"] == "align"
    assert spec.config["align_anneal"] == ALIGN_ANNEAL
    # a reward wrapper cannot carry a loss on the mean action; a start has no meaning
    bank_, model_ = inputs
    env = make_batched(TARGET_PUSH, 1)
    align = LatentShaping(model_, bank_, 0.1, env.robot_state_indices, form="align")
    with pytest.raises(PvedError, match="align form is a loss on the policy's mean action"):
        LatentShapingWrapper(gymnasium.make(TARGET_PUSH), align, MATCH_KEYS, lambda o: o)
    with pytest.raises(PvedError, match="align form has no shaping start"):
        LatentShaping(model_, bank_, 0.1, env.robot_state_indices, form="align", start=10)


def test_pved_align_short_fades_its_guide_by_a_quarter_of_the_run(
    inputs: tuple[SourceBank, PVED], tmp_path: Path
) -> None:
    runs = tmp_path / "runs"
    placeholder_shaping_inputs(runs)
    short = transfer_spec("reacher", "pved-align-short", runs_root=runs)
    assert short.config["align_anneal"] == short.align_anneal == 0.25
    # pved-align's config, and so its finished runs' hashes, are as they were
    assert transfer_spec("reacher", "pved-align", runs_root=runs).align_anneal == ALIGN_ANNEAL
    bank_, model_ = inputs
    env = make_batched(TARGET_PUSH, 2)
    shaping = LatentShaping(
        model_, bank_, 0.4, env.robot_state_indices, form="align", align_anneal=0.25
    )
    guide = ShapedBatchedEnv(env, shaping, MATCH_KEYS).action_guide
    assert guide is not None
    assert guide.weight(0.0) == 0.4 and guide.weight(0.125) == pytest.approx(0.2)
    assert guide.weight(0.25) == 0.0 and guide.weight(0.3) == 0.0
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(PvedError, match="align_anneal"):
            LatentShaping(
                model_, bank_, 0.4, env.robot_state_indices, form="align", align_anneal=bad
            )
