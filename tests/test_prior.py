"""``pved-prior`` (issue 64): the source's behaviour decoded through PVED's c-only decoder
(Eq. 8) into the target's action, as a prior the policy's mean action is pulled towards."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import gymnasium
import numpy as np
import pytest
import torch

import pved  # noqa: F401  (registers the env ids)
from helpers import placeholder_shaping_inputs, push_bank_and_model, run_cli
from pved.envs import make_batched
from pved.errors import PvedError
from pved.experiments.transfer_spec import transfer_spec
from pved.models import PVED, build_model, save_model
from pved.protocol.driver import _scale_cells
from pved.protocol.plan import ProtocolPlan
from pved.rl.guide import GUIDE_CONTEXT, ActionGuide
from pved.transfer.align_guide import AlignGuide
from pved.transfer.methods import get_method
from pved.transfer.prior_guide import PriorGuide
from pved.transfer.shaping import LatentShaping, LatentShapingWrapper, ShapedBatchedEnv
from pved.transfer.source_bank import SourceBank, save_bank

TARGET_PUSH = "pved/Reacher4Push-v0"
MATCH_KEYS = ("button_start",)


@pytest.fixture(scope="module")
def inputs() -> tuple[SourceBank, PVED]:
    return push_bank_and_model(episodes=4)


def _shaped(model: PVED, bank: SourceBank, form: str = "prior", n: int = 4) -> ShapedBatchedEnv:
    env = make_batched(TARGET_PUSH, n)
    shaping = LatentShaping(model, bank, 0.5, env.robot_state_indices, form=form)
    return ShapedBatchedEnv(env, shaping, MATCH_KEYS)


def _guide(model: PVED, bank: SourceBank, n: int = 4) -> PriorGuide:
    guide = _shaped(model, bank, n=n).action_guide
    assert isinstance(guide, PriorGuide) and isinstance(guide, ActionGuide)
    return guide


def test_the_prior_is_the_c_only_decoders_action_at_the_sources_code(
    inputs: tuple[SourceBank, PVED],
) -> None:
    bank, untouched = inputs
    # the decoder's actions scaled past the box, so the clip is seen working
    model = copy.deepcopy(untouched)
    s = model.target_state_dim
    model.target_norm.std[s:] = 40.0
    guide = _guide(model, bank)
    with torch.no_grad():
        code = model.shared_source(torch.as_tensor(bank.x.reshape(-1, bank.dim))).mean
        raw = model.target_norm.inverse(model.decoder_S_prime(code))[:, s:].numpy()
    box = make_batched(TARGET_PUSH, 1).single_action_space
    assert (raw > box.high).any() and (raw < box.low).any()
    expected = np.clip(raw, box.low, box.high).reshape(*bank.x.shape[:2], -1)
    np.testing.assert_allclose(guide.decoded.mean, expected, rtol=1e-5, atol=1e-6)
    # a step's row is the decode of the code the align form looks up at that step, past
    # the source episode's end included (the same lookup, the same time base)
    align = AlignGuide(guide.shaping, box.low, box.high, 4)
    episode = np.array([0, 1, 2, 3, 3])
    t = np.array([0, 7, 50, 99, 400])
    obs = np.zeros((5, make_batched(TARGET_PUSH, 1).single_observation_space.shape[0]))
    codes = align.context(obs, episode, t)[:, len(guide.shaping.robot_state_indices) :]
    with torch.no_grad():
        decoded = model.decode_target_shared(torch.as_tensor(codes[:, : code.shape[1]]))
    np.testing.assert_allclose(
        guide.context(obs, episode, t), np.clip(decoded[:, s:].numpy(), box.low, box.high),
        rtol=1e-5, atol=1e-6,
    )  # fmt: skip


def test_the_prior_form_pays_no_term_and_gives_the_prior_as_context(
    inputs: tuple[SourceBank, PVED],
) -> None:
    bank, model = inputs
    env = _shaped(model, bank)
    guide = env.action_guide
    assert isinstance(guide, PriorGuide) and guide.context_dim == 4
    env.reset(seed=1)
    episode, t = env._episode.copy(), env._t.copy()
    act = np.zeros((4, 4))
    env.set_mean_actions(act)
    _, reward, _, _, info = env.step(act)
    np.testing.assert_array_equal(reward, info["env_reward"])
    assert not info["reward_shaping"].any()
    ctx = info[GUIDE_CONTEXT]
    assert ctx.dtype == np.float32
    np.testing.assert_array_equal(ctx, guide.decoded.mean[episode, t])


def test_the_loss_gradient_is_autograd_s_and_points_to_the_prior(
    inputs: tuple[SourceBank, PVED],
) -> None:
    bank, model = inputs
    guide = _guide(model, bank)
    rng = np.random.default_rng(0)
    prior = rng.uniform(-0.9, 0.9, (6, 4)).astype(np.float32)
    mean = rng.uniform(-1.5, 1.5, (6, 4)).astype(np.float32)  # some outside the box
    loss, grad = guide.loss_grad(prior, mean, 0.1)
    w = 0.5 * (1 - 0.1 / 0.5)
    mu = torch.as_tensor(mean).requires_grad_(True)
    half = torch.as_tensor(guide.half_width)
    ref = w * (((mu - torch.as_tensor(prior)) / half) ** 2).sum(1).mean() / 4
    (ref_grad,) = torch.autograd.grad(ref, mu)
    assert loss == pytest.approx(float(ref.detach()), rel=1e-6) and loss > 0
    np.testing.assert_allclose(grad, ref_grad.numpy(), rtol=1e-5)
    eps = 1e-3
    for i, j in ((0, 0), (5, 3)):
        up, down = mean.copy(), mean.copy()
        up[i, j] += eps
        down[i, j] -= eps
        numeric = (guide.loss_grad(prior, up, 0.1)[0] - guide.loss_grad(prior, down, 0.1)[0]) / (
            2 * eps
        )
        assert grad[i, j] == pytest.approx(numeric, rel=1e-3)
    # descent moves every coordinate towards the prior, outside the box too
    assert np.all(np.sign(grad) == np.sign(mean - prior))
    step = mean - 0.5 * grad / np.abs(grad).max() * np.abs(mean - prior).min()
    assert np.all(np.abs(step - prior) < np.abs(mean - prior))
    assert guide.loss_grad(prior, prior, 0.1) == (0.0, pytest.approx(np.zeros((6, 4))))


def test_the_weight_decays_to_zero_and_the_guide_fades(inputs: tuple[SourceBank, PVED]) -> None:
    bank, model = inputs
    guide = _guide(model, bank)
    prior = np.full((2, 4), 0.5, dtype=np.float32)
    mean = np.zeros((2, 4), dtype=np.float32)
    assert guide.weight(0.0) == 0.5 and guide.weight(0.25) == pytest.approx(0.25)
    assert guide.loss_grad(prior, mean, 0.25)[0] == pytest.approx(
        guide.loss_grad(prior, mean, 0.0)[0] / 2
    )
    assert not guide.faded
    obs = np.zeros((2, make_batched(TARGET_PUSH, 1).single_observation_space.shape[0]))
    assert guide.context(obs, np.zeros(2, int), np.zeros(2, int)).any()
    loss, grad = guide.loss_grad(prior, mean, 0.5)
    assert loss == 0.0 and not grad.any() and guide.faded
    assert guide.weight(0.9) == 0.0
    assert not guide.context(obs, np.zeros(2, int), np.zeros(2, int)).any()


def test_pved_prior_is_a_method_with_its_own_config(tmp_path: Path) -> None:
    method = get_method("pved-prior")
    assert (method.model, method.shaping_form, method.paper, method.anneal) == (
        "pved", "prior", False, 0.5,
    )  # fmt: skip
    runs = tmp_path / "runs"
    placeholder_shaping_inputs(runs)
    spec = transfer_spec("reacher", "pved-prior", runs_root=runs)
    assert spec.config["shaping_form"] == "prior" and spec.config["align_anneal"] == 0.5
    assert spec.run_dir.parent.name == "pved-prior"
    # the protocol trains pved's model for it and tries its own beta grid
    plan = ProtocolPlan(["reacher"], ["pved-prior", "ppo"], "smoke", tmp_path / "p")
    keys = {j.key for j in plan.expand({})}
    assert "reacher/model/pved/init0" in keys
    assert plan.describe()["beta_grids"]["reacher"]["pved-prior"] == [10.0, 1.0]
    # its summary reads no D off a reward term it never pays
    scale = {"shaping_first": 0.0, "shaping_last": 0.0, "env_reward_first": 0.1,
             "env_reward_last": 0.2}  # fmt: skip
    summary = {"beta": 1.0, "reward_scale": scale}
    assert _scale_cells(summary, "pved-prior")[0] == "none (a loss on the mean action)"


@pytest.mark.parametrize(
    ("model", "message"),
    [
        ("pved-state-only", "decodes the target's state only"),
        ("gupta2017", "does not provide it"),
        ("pved-det-shared", "does not provide it"),
    ],
)
def test_a_model_without_the_decoder_is_refused_in_one_line(
    inputs: tuple[SourceBank, PVED],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    model: str,
    message: str,
) -> None:
    # through the CLI before any file is read (there is none), and where a caller builds
    # the shaping itself
    code, _, err = run_cli(capsys, "transfer", "--runs", tmp_path, "--model", model,
                           "--shaping-form", "prior")  # fmt: skip
    assert code != 0 and message in err and len(err.strip().splitlines()) == 1
    bank, pved_model = inputs
    env = make_batched(TARGET_PUSH, 1)
    other = build_model(model, pved_model.dims)
    with pytest.raises(PvedError, match=message):
        LatentShaping(other, bank, 0.1, env.robot_state_indices, form="prior")


def test_invalid_prior_settings_are_refused(inputs: tuple[SourceBank, PVED]) -> None:
    bank, model = inputs
    env = make_batched(TARGET_PUSH, 1)
    with pytest.raises(PvedError, match="prior form has no shaping start"):
        LatentShaping(model, bank, 0.1, env.robot_state_indices, form="prior", start=10)
    prior = LatentShaping(model, bank, 0.1, env.robot_state_indices, form="prior")
    with pytest.raises(PvedError, match="prior form is a loss on the policy's mean action"):
        LatentShapingWrapper(gymnasium.make(TARGET_PUSH), prior, MATCH_KEYS, lambda o: o)
    with pytest.raises(PvedError, match="bounded action box"):
        PriorGuide(prior, np.full(4, -np.inf), np.ones(4), 1)
    with pytest.raises(PvedError, match="action box has 3 dims"):
        PriorGuide(prior, -np.ones(3), np.ones(3), 1)
    guide = PriorGuide(prior, -np.ones(4), np.ones(4), 1)
    with pytest.raises(PvedError, match=r"takes \(B, 4\) context and mean rows"):
        guide.loss_grad(np.zeros((2, 4)), np.zeros((3, 4)), 0.0)


def test_a_smoke_transfer_with_pved_prior_writes_its_result(
    inputs: tuple[SourceBank, PVED], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the CLI end to end on a tiny model and bank: 2 updates of 2048 rows at progress 0
    # and 1/2, so the prior guides the first and has faded by the second
    bank, model = inputs
    model_file = save_model(model, tmp_path / "model.pt")
    bank_file = save_bank(tmp_path / "bank.npz", bank)
    code, _, err = run_cli(capsys, "transfer", "--runs", tmp_path / "runs", "--model",
                           "pved-prior", "--model-path", model_file, "--bank", bank_file,
                           "--steps", "4096", "--eval-every", "4096", "--eval-episodes", "4",
                           "--final-eval-episodes", "4")  # fmt: skip
    assert code == 0, err
    run = tmp_path / "runs/reacher/transfer/pved-prior/seed20000"
    assert json.loads((run / "result.json").read_text())["steps"] == 4096
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    losses = [r["loss/guide_loss"] for r in rows if "loss/guide_loss" in r]
    assert len(losses) == 2 and losses[0] > 0 and losses[1] == 0.0
    assert json.loads((run / "config.json").read_text())["config"]["shaping_form"] == "prior"


def test_the_prior_acted_out_is_the_guides_context_beside_zero_and_random(
    inputs: tuple[SourceBank, PVED], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from helpers import run_cli
    from pved.diagnostics.prior_policy import prior_policy
    from pved.models.registry import save_model
    from pved.transfer.source_bank import save_bank

    bank, model = inputs
    # the context guide_context gives before a step is the one that step carries
    env = _shaped(model, bank)
    env.reset(seed=3)
    before = env.guide_context()
    assert before is not None
    env.set_mean_actions(before)
    _, _, _, _, info = env.step(before.astype(np.float64))
    np.testing.assert_array_equal(before, info[GUIDE_CONTEXT])
    model_file = save_model(model, tmp_path / "model.pt", {"pair": "reacher"})
    bank_file = save_bank(tmp_path / "bank.npz", bank)
    result = prior_policy("reacher", model_file, bank_file, episodes=8, seed=1)
    for label in ("prior", "zero", "random"):
        assert result[label]["episodes"] == 8 and "success_rate" in result[label]
        assert "metric_ee_button_mean" in result[label]
    # the random peer moves the arm; the prior's actions differ from both peers'
    assert result["random"]["metric_ctrl_mean"] < result["zero"]["metric_ctrl_mean"] == 0.0
    assert result["prior"]["metric_ee_button_mean"] != result["zero"]["metric_ee_button_mean"]
    code, out, _ = run_cli(
        capsys, "prior-policy", "--model", model_file, "--bank", bank_file, "--episodes", 4
    )
    assert code == 0 and out.startswith("| policy | success_rate | return_mean |")
    code, _, err = run_cli(
        capsys, "prior-policy", "--model", model_file, "--bank", bank_file, "--episodes", 0
    )
    assert code != 0 and "--episodes" in err and len(err.strip().splitlines()) == 1
