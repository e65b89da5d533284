"""Transfer methods as recipes (pved.transfer.methods), and the potential-based Eq. 10
of ``pved-potential``, the first method beyond the paper (issue 51)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pved  # noqa: F401  (registers the env ids)
from helpers import assert_ppo_resumes_exactly, placeholder_shaping_inputs, push_bank_and_model
from pved.envs import make_batched
from pved.errors import PvedError
from pved.experiments.stages import transfer_spec
from pved.models import PVED
from pved.protocol.plan import ProtocolPlan
from pved.rl.ppo import PPOConfig
from pved.runs import config_hash
from pved.transfer.methods import METHODS, get_method
from pved.transfer.shaping import LatentShaping, ShapedBatchedEnv
from pved.transfer.source_bank import SourceBank

TARGET_PUSH = "pved/Reacher4Push-v0"
SOURCE_PUSH = "pved/Reacher3Push-v0"
MATCH_KEYS = ("button_start",)
GAMMA = 0.9  # far from 1, so a missing 1/γ shows


@pytest.fixture(scope="module")
def inputs() -> tuple[SourceBank, PVED]:
    return push_bank_and_model(episodes=6)


@pytest.fixture(scope="module")
def bank(inputs: tuple[SourceBank, PVED]) -> SourceBank:
    return inputs[0]


@pytest.fixture(scope="module")
def model(inputs: tuple[SourceBank, PVED]) -> PVED:
    return inputs[1]


def _shaped(model: PVED, bank: SourceBank, form: str, n: int = 3) -> ShapedBatchedEnv:
    env = make_batched(TARGET_PUSH, n)
    shaping = LatentShaping(
        model, bank, 0.1, env.robot_state_indices, form=form, gamma=GAMMA, action="taken"
    )
    return ShapedBatchedEnv(env, shaping, MATCH_KEYS)


def test_the_potential_form_pays_phi_t_minus_phi_before_over_gamma(
    model: PVED, bank: SourceBank
) -> None:
    # the same episodes shaped both ways: Eq. 10's term is the potential Φ_t = −β·D_t
    eq10, potential = _shaped(model, bank, "eq10"), _shaped(model, bank, "potential")
    eq10.reset(seed=4)
    potential.reset(seed=4)
    rng = np.random.default_rng(0)
    phi: list[np.ndarray] = []
    paid: list[np.ndarray] = []
    for _ in range(130):  # Push episodes are 100 steps: one boundary crossed
        act = rng.uniform(-1, 1, (3, eq10.single_action_space.shape[0]))
        *_, info_e = eq10.step(act)
        _, reward, _, trunc, info_p = potential.step(act)
        phi.append(info_e["reward_shaping"])
        paid.append(info_p["reward_shaping"])
        np.testing.assert_array_equal(reward, info_p["env_reward"] + info_p["reward_shaping"])
        if len(phi) == 100:
            assert trunc.all()
    phi_a, paid_a = np.array(phi), np.array(paid)
    assert np.all(phi_a < 0)
    # step 0 of each episode pays Φ_0 (Φ_{−1} = 0); later steps Φ_t − Φ_{t−1}/γ
    np.testing.assert_allclose(paid_a[0], phi_a[0], rtol=1e-12)
    np.testing.assert_allclose(paid_a[100], phi_a[100], rtol=1e-12)
    np.testing.assert_allclose(paid_a[1:100], phi_a[1:100] - phi_a[:99] / GAMMA, rtol=1e-9)
    np.testing.assert_allclose(paid_a[101:], phi_a[101:] - phi_a[100:-1] / GAMMA, rtol=1e-9)
    # so an episode's discounted sum of the term is one step's: γ^{T−1}·Φ_{T−1}
    discounts = GAMMA ** np.arange(100)
    np.testing.assert_allclose(
        discounts @ paid_a[:100], GAMMA**99 * phi_a[99], rtol=1e-6, atol=1e-12
    )
    # where Eq. 10's sum grows with the episode's length
    assert np.all(np.abs(discounts @ phi_a[:100]) > 10 * np.abs(GAMMA**99 * phi_a[99]))


def test_potential_shaped_ppo_resumes_exactly(
    model: PVED, bank: SourceBank, tmp_path: Path
) -> None:
    # the checkpoint at update 2 falls mid-episode: a resume that lost each copy's Φ_{t−1}
    # would pay its first step Φ_t and end elsewhere
    cfg = PPOConfig(
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
    assert_ppo_resumes_exactly(lambda: _shaped(model, bank, "potential", n=4), cfg, tmp_path)


def test_every_method_is_a_recipe_the_registry_checks() -> None:
    assert get_method("pved").model == "pved" and get_method("pved").paper
    assert get_method("ppo").model is None and get_method("oracle").train_reward == "full"
    potential = get_method("pved-potential")
    assert (potential.model, potential.shaping_form, potential.paper) == (
        "pved",
        "potential",
        False,
    )
    # every model is a method of the paper under its own name
    assert {m.name for m in METHODS.values() if m.paper and m.shaped} == {
        m.model for m in METHODS.values() if m.paper and m.shaped
    }
    with pytest.raises(PvedError, match=r"unknown method 'pved-typo'; known methods: .*pved-pot"):
        get_method("pved-typo")


def test_pved_potential_runs_on_pveds_model_with_its_own_config(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    model, bank = placeholder_shaping_inputs(runs)
    plain = transfer_spec("reacher", "pved", runs_root=runs)
    potential = transfer_spec("reacher", "pved-potential", runs_root=runs)
    # the same model and bank by default, the method's form, a config of its own
    assert potential.shaping_inputs == plain.shaping_inputs == (model, bank)
    assert potential.shaping_form == "potential" and potential.config["shaping_form"] == "potential"
    assert plain.shaping_form == "eq10" and "shaping_form" not in plain.config
    assert config_hash(potential.config) != config_hash(plain.config)
    assert potential.run_dir.parent.name == "pved-potential"
    # the form can still be set by hand, and a method with no term refuses one
    assert transfer_spec("reacher", "pved", runs_root=runs, shaping_form="potential").config[
        "shaping_form"
    ] == ("potential")
    with pytest.raises(PvedError, match="'ppo' has no shaping term"):
        transfer_spec("reacher", "ppo", runs_root=runs, shaping_form="potential")


def test_protocol_trains_one_model_for_the_methods_that_share_it(tmp_path: Path) -> None:
    plan = ProtocolPlan(["reacher"], ["pved", "pved-potential", "ppo"], "smoke", tmp_path)
    jobs = plan.expand({})
    keys = {j.key for j in jobs}
    assert "reacher/model/pved/init0" in keys
    assert not any(k.startswith("reacher/model/pved-potential") for k in keys)
    tuning = [j for j in jobs if j.key.startswith("reacher/transfer/pved-potential-")]
    assert tuning and all(
        j.kwargs["model_path"].parent == tmp_path.resolve() / "runs/reacher/model/pved/seed0"
        for j in tuning
    )
    # the method's own beta grid (smoke tries the first two values)
    assert {j.tags["beta"] for j in tuning} == {1.0, 0.1}
    assert plan.describe()["beta_grids"]["reacher"]["pved-potential"] == [1.0, 0.1]
    with pytest.raises(PvedError, match="unknown method 'pved-typo'"):
        ProtocolPlan(["reacher"], ["pved-typo"], "smoke", tmp_path)


def test_the_summary_reads_d_off_the_term_only_for_eq10s_form() -> None:
    from pved.protocol.driver import _scale_cells

    m = {
        "beta": 0.1,
        "reward_scale": {
            "shaping_first": -2.0,
            "shaping_last": -1.0,
            "env_reward_first": 0.5,
            "env_reward_last": 0.7,
        },
    }
    assert _scale_cells(m, "pved")[0] == "-2 → -1 (D 20 → 10)"
    # a potential's payment is a difference of potentials, not −β·D
    assert _scale_cells(m, "pved-potential")[0] == "-2 → -1"
    # align pays no reward term: its recorded 0 → 0 is not a reading of D
    assert _scale_cells(m, "pved-align")[0] == "none (a loss on the mean action)"
