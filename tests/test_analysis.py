"""The analysis layer: t-SNE subspace data and plots, the Theorem 1 bound, rollout videos."""

from __future__ import annotations

import math
import os
from pathlib import Path

# Headless rendering (the t-SNE mark strips and videos render frames); without it this file
# passes only when another test module that sets it was collected first.
os.environ.setdefault("MUJOCO_GL", "osmesa")

import numpy as np
import pytest
import torch

import pved  # noqa: F401  (registers the env ids)
from pved.analysis.bound import (
    corollary1_rhs,
    estimate_bound,
    gaussian_kl,
    theorem1_bound,
    theorem1_rhs,
)
from pved.analysis.tsne import (
    SubspaceData,
    embed_rollouts,
    plot_tsne,
    probe_accuracy,
    subspace_numbers,
    time_correspondence,
    write_subspace_numbers,
)
from pved.analysis.video import render_rollout
from pved.envs import make_batched
from pved.models import PVED, ModelDims, PVEDConfig
from pved.pretrained import pretrained_policy_path
from pved.rl.policy import load_policy

# The shipped policies give a source on Push and, standing in for a transferred target
# (none is shipped), the Reacher4 Reach policy on its own env: the mechanics are the same.
SOURCE_ENV, TARGET_ENV = "pved/Reacher3Push-v0", "pved/Reacher4Reach-v0"
EPISODES, MAX_STEPS = 2, 25


@pytest.fixture(scope="module")
def model() -> PVED:
    src, tgt = make_batched(SOURCE_ENV, 1), make_batched(TARGET_ENV, 1)
    n_s, n_t = len(src.robot_state_indices), len(tgt.robot_state_indices)
    dims = ModelDims(
        n_s + src.single_action_space.shape[0], n_t + tgt.single_action_space.shape[0], n_s, n_t
    )
    torch.manual_seed(0)
    return PVED(dims, PVEDConfig())  # untrained: the analysis only needs the interface


@pytest.fixture(scope="module")
def data(model: PVED) -> SubspaceData:
    return embed_rollouts(
        model,
        load_policy(pretrained_policy_path("Reacher3", "Push")),
        load_policy(pretrained_policy_path("Reacher4", "Reach")),
        SOURCE_ENV,
        TARGET_ENV,
        EPISODES,
        seed=3,
        max_steps=MAX_STEPS,
    )


def test_subspace_data_shapes_and_time(data: SubspaceData) -> None:
    n = EPISODES * MAX_STEPS * 2  # neither policy finishes within 25 steps
    assert data.shared.shape == (n, 10)
    assert data.individual is not None and data.individual.shape == (n, 10)
    for arr in (data.agent, data.episode, data.step, data.time):
        assert arr.shape == (n,)
    assert np.array_equal(np.unique(data.agent), [0, 1])
    for a in (0, 1):
        for e in range(EPISODES):
            t = data.time[(data.agent == a) & (data.episode == e)]
            assert t[0] == 0.0 and t[-1] == 1.0 and np.all(np.diff(t) > 0)
    assert np.all(np.isfinite(data.shared))


def test_plot_tsne_writes_scatters_and_mark_strips(data: SubspaceData, tmp_path: Path) -> None:
    from PIL import Image

    paths = plot_tsne(data, tmp_path, marks=2, image_size=64)
    names = sorted(p.name for p in paths)
    assert names == ["mark_1.png", "mark_2.png", "tsne_individual.png", "tsne_shared.png"]
    for p in paths:
        with Image.open(p) as im:
            assert im.size[0] > 50 and im.size[1] > 50
            assert np.asarray(im).std() > 0  # not a blank image
    numbers = write_subspace_numbers(data, tmp_path)
    assert numbers.name == "numbers.json" and numbers.stat().st_size > 0


def test_subspace_numbers_reports_both_subspaces(data: SubspaceData) -> None:
    nums = subspace_numbers(data)
    for space in ("shared", "individual"):
        assert 0.0 <= nums[space]["nn_time_difference"] <= 1.0
        assert 0.0 <= nums[space]["agent_probe_accuracy"] <= 1.0
    assert nums["num_points"] == {"source": 50, "target": 50}


def test_probe_is_chance_on_one_distribution_and_perfect_on_separated() -> None:
    rng = np.random.default_rng(0)
    labels = np.repeat([0, 1], 300)
    same = rng.standard_normal((600, 5))
    assert abs(probe_accuracy(same, labels) - 0.5) < 0.1
    apart = same + 6.0 * labels[:, None]
    assert probe_accuracy(apart, labels) > 0.98


def test_time_correspondence_of_aligned_and_shuffled_points() -> None:
    time = np.tile(np.linspace(0, 1, 50), 2)
    agent = np.repeat([0, 1], 50)
    aligned = np.stack([time * 10, np.zeros(100)], axis=1)  # same place at same time
    assert time_correspondence(aligned, agent, time) == pytest.approx(0.0)
    shuffled = aligned.copy()
    shuffled[agent == 1] = shuffled[agent == 1][::-1]  # target runs backwards
    assert time_correspondence(shuffled, agent, time) > 0.3


def test_bound_formulas_match_hand_computation() -> None:
    delta, a, b, m = 0.08, -2.0, 0.5, 0.3
    hand = 0.3 + (0.5 - -2.0) / 2 * math.sqrt(2 * 0.08)  # 0.3 + 1.25 * 0.4
    assert theorem1_rhs(delta, a, b, m) == pytest.approx(0.8)
    assert theorem1_rhs(delta, a, b, m) == pytest.approx(hand)
    assert corollary1_rhs(delta, a, b, m, 0.9) == pytest.approx(hand / 0.1)
    assert corollary1_rhs(delta, a, b, m, 0.5, horizon=3) == pytest.approx(hand * 1.75)
    assert theorem1_rhs(0.0, a, b, 0.0) == 0.0  # same morphology, perfect match


def test_estimate_bound_estimators() -> None:
    kl = np.linspace(0.0, 1.0, 101)
    r_s = [np.array([-1.0, -0.5, 0.0]), np.array([-2.0, -1.0])]
    r_t = [np.array([-1.2, -0.5, 0.1]), np.array([-2.5, -1.0])]
    res = estimate_bound(
        kl, np.concatenate(r_s), np.concatenate(r_t), r_s, r_t, quantile=0.9, gamma=0.5
    )
    assert res.delta == pytest.approx(0.9) and res.kl_max == pytest.approx(1.0)
    assert (res.a, res.b) == (-2.0, 0.0)
    assert res.m == pytest.approx(0.5)
    assert res.bound == pytest.approx(0.5 + 1.0 * math.sqrt(1.8))
    assert res.gap == pytest.approx(abs(np.mean([-1.2, -0.5, 0.1, -2.5, -1.0]) + 0.9))
    assert res.held and res.horizon == 3


def test_gaussian_kl_zero_for_equal_and_known_value() -> None:
    z = torch.zeros(2, 3)
    assert torch.allclose(gaussian_kl(z, z, z, z), torch.zeros(2))
    one = torch.ones(1, 1)
    # KL(N(1, 1) || N(0, 1)) = 1/2
    assert gaussian_kl(one, 0 * one, 0 * one, 0 * one).item() == pytest.approx(0.5)


def test_theorem1_bound_on_rollouts(model: PVED) -> None:
    res = theorem1_bound(
        model,
        load_policy(pretrained_policy_path("Reacher3", "Push")),
        load_policy(pretrained_policy_path("Reacher4", "Reach")),
        SOURCE_ENV,
        TARGET_ENV,
        episodes=2,
        seed=1,
        max_steps=10,
        target_env_kwargs={},
    )
    assert res.matched_pairs == 20 and res.kl_max >= res.delta >= 0
    assert res.bound == pytest.approx(theorem1_rhs(res.delta, res.a, res.b, res.m))
    assert res.a <= res.b and res.m >= 0


def test_render_rollout_frame_count(tmp_path: Path) -> None:
    import imageio.v3 as iio

    push = pretrained_policy_path("Reacher3", "Push")
    single = render_rollout(push, SOURCE_ENV, tmp_path / "one.gif", seed=0, max_steps=6,
                            width=48, height=48)  # fmt: skip
    frames = iio.imread(single, index=None)
    assert frames.shape[0] == 7 and frames.shape[1:3] == (48, 48)
    both = render_rollout(
        push,
        SOURCE_ENV,
        tmp_path / "both.gif",
        seed=0,
        max_steps=6,
        side_by_side_with=(pretrained_policy_path("Reacher4", "Reach"), TARGET_ENV),
        width=48,
        height=48,
    )
    frames = iio.imread(both, index=None)
    assert frames.shape[0] == 7 and frames.shape[2] == 48 * 2 + 4


def test_render_rollout_to_mp4(tmp_path: Path) -> None:
    import imageio.v3 as iio

    push = pretrained_policy_path("Reacher3", "Push")
    path = render_rollout(push, SOURCE_ENV, tmp_path / "one.mp4", seed=0, max_steps=9,
                          width=64, height=48)  # fmt: skip
    frames = iio.imread(path, index=None)
    assert frames.shape[0] == 10 and frames.shape[1:3] == (48, 64)
    assert not list(tmp_path.glob(".*tmp*"))
