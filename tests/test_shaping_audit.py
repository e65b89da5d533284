"""pved.diagnostics.shaping_audit: the clip shares of the two reward treatments and the
audit of a fresh transfer policy's rollout."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

import pved  # noqa: F401  (registers the env ids)
from helpers import push_bank_and_model
from pved.diagnostics.shaping_audit import audit, clip_shares, rollout_terms
from pved.errors import PvedError
from pved.models import PVED, ModelDims, PVEDConfig
from pved.rl.ppo import PPOConfig


def test_clip_shares_of_the_two_treatments() -> None:
    rng = np.random.default_rng(0)
    env = rng.normal(0.0, 1.0, (200, 4))
    done = np.zeros_like(env)
    done[49::50] = 1.0
    # no term: both treatments are plain PPO's normaliser, and it never clips unit rewards
    none = clip_shares(env, np.zeros_like(env), done)
    assert none["sum"] == none["env"] == none["env_part"] == none["shaping_over_clip"] == 0.0
    assert none["env_weight"] == pytest.approx(1.0)
    # a term 1000x the env reward on a tenth of the steps: fed to the normaliser it
    # inflates σ, shrinking the env reward's weight 100-fold; on the env reward alone
    # nothing changes for the env part, and the term passes unclipped
    shaping = np.where(rng.random(env.shape) < 0.1, -1000.0, 0.0)
    both = clip_shares(env, shaping, done)
    assert both["env"] == both["env_part"] == 0.0 and both["shaping_over_clip"] > 0.05
    assert both["env_weight"] < 0.02
    # one spike after a calm stretch: the old treatment clips it
    spike = np.zeros_like(env)
    spike[150, 0] = -1e4
    assert clip_shares(env, spike, done)["sum"] == pytest.approx(1 / env.size)
    with pytest.raises(PvedError, match="equal"):
        clip_shares(env, shaping[:10], done)


def test_audit_of_a_fresh_policy_on_the_push_target() -> None:
    bank, model = push_bank_and_model()
    ppo = PPOConfig(num_envs=4, seed=3)
    terms = rollout_terms("pved/Reacher4Push-v0", model, bank, ("button_start",), ppo, 400)
    assert terms["d_mean"].shape == (100, 4)
    assert np.all(terms["d_mean"] >= 0) and np.all(terms["d_taken"] >= 0)
    # with std 1 on [-1, 1] actuators the taken action differs from the mean
    assert not np.allclose(terms["d_mean"], terms["d_taken"])
    assert terms["done"][99].all()  # Push episodes are 100 steps
    result = audit(terms, (0.1, 1.0), 0.99, 10.0)
    assert set(result["by_beta"]) == {"0.1", "1"}
    assert result["by_beta"]["1"]["term_over_env"] == pytest.approx(
        10 * result["by_beta"]["0.1"]["term_over_env"]
    )
    with pytest.raises(PvedError, match="betas must be positive"):
        audit(terms, (-0.1,), 0.99, 10.0)


def test_likelihood_reading_fits_both_variances_on_the_same_pairs(tmp_path: Path) -> None:
    from pved.diagnostics.shaping_audit import likelihood_reading
    from pved.experiments.stages import collect_pairs

    data = collect_pairs("reacher", episodes=8, runs_root=tmp_path, progress=False)
    out = tmp_path / "likelihood.json"
    got = likelihood_reading("reacher", data, epochs=1, rows=200, runs_root=tmp_path, out=out)
    assert json.loads(out.read_text()) == json.loads(json.dumps(got))
    for variance in ("learned", "unit"):
        assert set(got[variance]) == {"matched", "shuffled", "shared_std_mean"}
        assert got[variance]["matched"]["q50"] >= 0.0
        assert (tmp_path / "reacher" / "likelihood" / variance / "seed0" / "result.json").exists()
    # the two fits differ only in the decoder variance, so their D differ
    assert got["learned"]["matched"] != got["unit"]["matched"]


@pytest.fixture
def one_thread() -> Iterator[None]:
    """One torch thread, as every pved stage runs (800 small steps a search: on two
    threads of a busy machine they take 30 times as long)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.usefixtures("one_thread")
def test_the_search_over_actions_finds_an_action_whose_code_is_the_source_s() -> None:
    from pved.diagnostics.shaping_audit import min_over_actions

    dims = ModelDims(10, 12, 6, 8)
    torch.manual_seed(0)
    model = PVED(dims, PVEDConfig())
    model.fit_standardization(torch.randn(512, 10), torch.randn(512, 12))
    rng = np.random.default_rng(0)
    state = rng.normal(size=(64, 8)).astype(np.float32)
    target_action = rng.uniform(-0.8, 0.8, (64, 4)).astype(np.float32)
    with torch.no_grad():  # the source's code is the target's own at a known action: D 0 there
        source = model.shared_target(torch.as_tensor(np.concatenate([state, target_action], 1)))
    first = -target_action  # start far from it
    low, high = -np.ones(4, np.float32), np.ones(4, np.float32)
    with torch.no_grad():
        at_first = model.shaping_between(
            source, model.shared_target(torch.as_tensor(np.concatenate([state, first], 1)))
        ).numpy()
    least = min_over_actions(model, source, state, first, low, high, seed=1)
    assert least.shape == (64,) and np.all(least <= at_first + 1e-6)
    assert np.median(least) < 0.05 * np.median(at_first)  # the search gets (near) to 0
    # an action outside the box is not searched: with the optimum outside, D stays above 0
    outside = min_over_actions(model, source, state, first, low, low + 1e-3, seed=1)
    assert np.median(outside) > np.median(least)


@pytest.mark.usefixtures("one_thread")
def test_the_audit_reads_how_much_of_d_the_action_can_remove() -> None:
    bank, model = push_bank_and_model()
    ppo = PPOConfig(num_envs=4, seed=3)
    terms = rollout_terms(
        "pved/Reacher4Push-v0", model, bank, ("button_start",), ppo, 200, min_rows=32
    )
    assert terms["d_min"].shape == terms["d_min_rows"].shape == (32,)
    assert set(terms["d_min_rows"]) <= set(terms["d_mean"].reshape(-1))
    assert np.all(terms["d_min"] <= terms["d_min_rows"] + 1e-6)
    removable = audit(terms, (1.0,), 0.99, 10.0)["removable_by_action"]
    assert removable["rows"] == 32 and 0.0 <= removable["share_median"] <= 1.0
    assert "removable_by_action" not in audit(
        rollout_terms("pved/Reacher4Push-v0", model, bank, ("button_start",), ppo, 40),
        (1.0,),
        0.99,
        10.0,
    )
