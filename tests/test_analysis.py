"""The analysis layer: t-SNE subspace data and plots, the Theorem 1 bound, rollout videos."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

# Headless rendering (the t-SNE mark strips and videos render frames); without it this file
# passes only when another test module that sets it was collected first.
import numpy as np
import pytest
import torch

import pved  # noqa: F401  (registers the env ids)
from pved.diagnostics.bound import (
    corollary1_rhs,
    estimate_bound,
    gaussian_kl,
    theorem1_bound,
    theorem1_rhs,
)
from pved.diagnostics.pair_report import build_pair_report
from pved.diagnostics.tsne import (
    StripFrame,
    SubspaceData,
    default_later_frames,
    embed_rollouts,
    later_frame_indices,
    mark_strip,
    normalised_time,
    plot_tsne,
    probe_accuracy,
    subspace_numbers,
    time_correspondence,
    write_subspace_numbers,
    write_x_split,
    x_split_by_group,
)
from pved.diagnostics.video import render_rollout
from pved.envs import make_batched
from pved.envs.terrain import CURVE_RAMP_LENGTH
from pved.errors import PvedError
from pved.models import PVED, ModelDims, PVEDConfig
from pved.pretrained import pretrained_policy_path
from pved.rl.policy import Policy, load_policy
from pved.spec import PRESETS

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
    # Theorem 1 assumes KL <= δ for every pair: δ is the max, the quantile only a reading
    assert res.delta == pytest.approx(1.0) and res.kl_max == pytest.approx(1.0)
    assert res.delta_quantile == pytest.approx(0.9)
    assert (res.a, res.b) == (-2.0, 0.0)
    assert res.m == pytest.approx(0.5)
    assert res.bound == pytest.approx(0.5 + 1.0 * math.sqrt(2.0))
    assert res.bound_quantile == pytest.approx(0.5 + 1.0 * math.sqrt(1.8))
    assert res.gap == pytest.approx(abs(np.mean([-1.2, -0.5, 0.1, -2.5, -1.0]) + 0.9))
    assert res.held and res.horizon == 3
    assert not res.vacuous  # √(2·1) < 2
    # one pair at KL 2 makes √(2δ) = 2: the bound is then no tighter than (b − a) + m
    kl_out = np.append(kl, 2.0)
    out = estimate_bound(
        kl_out, np.append(np.concatenate(r_s), -1.0), np.append(np.concatenate(r_t), -1.0),
        r_s, r_t, quantile=0.9,
    )  # fmt: skip
    assert out.vacuous and out.delta == 2.0
    assert out.bound == pytest.approx(out.m + (out.b - out.a))
    assert "vacuous" in out.summary() and "vacuous" not in res.summary()


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


# ------------------------------------------------ Humanoid -> Ant additions (Figs. 7, 8)
def test_later_frame_indices_steps_and_clamp_at_episode_end() -> None:
    assert later_frame_indices(3, 20, 2, 5) == [3, 8, 13]
    assert later_frame_indices(12, 20, 2, 5) == [12, 17, 19]  # t + 2*5 = 22 > last step 19
    assert later_frame_indices(19, 20, 2, 5) == [19, 19, 19]
    assert later_frame_indices(7, 20, 0, 5) == [7]
    assert later_frame_indices(0, 20, 3, 1) == [0, 1, 2, 3]
    for bad in ((20, 20, 2, 5), (-1, 20, 2, 5), (3, 20, -1, 5), (3, 20, 2, 0)):
        with pytest.raises(PvedError):
            later_frame_indices(*bad)


def test_later_frames_default_only_for_an_ant_target() -> None:
    for name, preset in PRESETS.items():
        want = 2 if name == "humanoid-ant" else 0
        assert default_later_frames(preset.target_agent) == want, name


def _synthetic(
    shared: np.ndarray, agent: np.ndarray, episode: np.ndarray, step: np.ndarray
) -> SubspaceData:
    time = np.zeros(len(agent))
    for a in (0, 1):
        for e in np.unique(episode[agent == a]):
            sel = (agent == a) & (episode == e)
            time[sel] = normalised_time(int(sel.sum()))
    return SubspaceData(shared, None, agent, episode, step, time, [], [], "s", "t")


def test_mark_strip_adds_later_target_frames_of_one_episode() -> None:
    # Source: one episode of 10 steps; target: two episodes of 12 steps. Every point has
    # its own place on a line, so the point nearest a mark is known.
    agent = np.repeat([0, 1, 1], [10, 12, 12])
    episode = np.repeat([0, 0, 1], [10, 12, 12])
    step = np.concatenate([np.arange(10), np.arange(12), np.arange(12)])
    emb = np.stack([np.arange(34.0), np.zeros(34)], axis=1)
    emb[:10, 1] = 100.0  # source points far off the line
    data = _synthetic(emb, agent, episode, step)
    mark = emb[10 + 12 + 4]  # target episode 1, step 4
    strip = mark_strip(emb, data, mark, target_later_frames=2, later_frame_stride=3)
    assert strip[0].agent == 0 and strip[0].offset == 0
    assert strip[1:] == [StripFrame(1, 1, 4, 0), StripFrame(1, 1, 7, 3), StripFrame(1, 1, 10, 6)]
    near_end = mark_strip(emb, data, emb[10 + 12 + 9], target_later_frames=2, later_frame_stride=3)
    assert near_end[1:] == [
        StripFrame(1, 1, 9, 0),
        StripFrame(1, 1, 11, 2, clamped=True),
        StripFrame(1, 1, 11, 2, clamped=True),
    ]
    assert [f.agent for f in mark_strip(emb, data, mark)] == [0, 1]  # default: no later


def test_plot_tsne_strip_grows_by_the_later_frames(data: SubspaceData, tmp_path: Path) -> None:
    from PIL import Image

    emb = {"shared": data.shared[:, :2], "individual": data.shared[:, 2:4]}  # no t-SNE cost
    plain = plot_tsne(data, tmp_path / "plain", marks=1, image_size=48, embeddings=emb)
    later = plot_tsne(data, tmp_path / "later", marks=1, image_size=48, embeddings=emb,
                      target_later_frames=2, later_frame_stride=3)  # fmt: skip
    (p0,) = [p for p in plain if p.name == "mark_1.png"]
    (p2,) = [p for p in later if p.name == "mark_1.png"]
    with Image.open(p0) as im0, Image.open(p2) as im2:
        assert 1.7 < im2.size[1] / im0.size[1] < 2.3  # 4 rows instead of 2
    with pytest.raises(PvedError):
        plot_tsne(data, tmp_path / "bad", marks=1, embeddings=emb, later_frame_stride=0)


def _blobs(
    n_left: int, after_left: int, n_right: int, after_right: int
) -> tuple[np.ndarray, np.ndarray]:
    """Two well separated blobs (left at x_emb = -10, right at +10) whose points have
    ``after_*`` torso positions at or beyond 12 m, the rest before."""
    rng = np.random.default_rng(1)
    emb = np.concatenate(
        [rng.normal((-10.0, 0.0), 0.5, (n_left, 2)), rng.normal((10.0, 0.0), 0.5, (n_right, 2))]
    )

    def xs(n: int, after: int) -> np.ndarray:
        return np.concatenate([rng.uniform(0.0, 11.9, n - after), 12.0 + rng.uniform(0, 8, after)])

    # The right blob first in the arrays: the groups must still come left to right.
    order = np.r_[n_left : n_left + n_right, 0:n_left]
    return emb[order], np.concatenate([xs(n_left, after_left), xs(n_right, after_right)])[order]


def test_x_split_of_blobs_before_and_after_12m() -> None:
    emb, x = _blobs(100, 0, 80, 80)
    x[np.argmax(x)] = 12.0  # exactly at the threshold counts as after
    split = x_split_by_group(emb, x, 12.0, marks=np.array([[10.0, 0.0], [-10.0, 0.0]]))
    assert split["threshold_m"] == 12.0 and (split["before"], split["after"]) == (100, 80)
    left, right = split["groups"]
    assert (left["size"], left["before"], left["after"], left["frac_after"]) == (100, 100, 0, 0.0)
    assert (right["size"], right["before"], right["after"], right["frac_after"]) == (80, 0, 80, 1.0)
    assert left["centre"][0] < -9 and right["centre"][0] > 9
    assert (left["nearest_mark"], right["nearest_mark"]) == (2, 1)
    assert split["frac_after_range"] == 1.0
    json.dumps(split)  # plain JSON for numbers.json


def test_x_split_of_mixed_groups() -> None:
    emb, x = _blobs(100, 30, 50, 40)
    split = x_split_by_group(emb, x, 12.0, seed=3)
    left, right = split["groups"]
    assert (left["before"], left["after"]) == (70, 30) and left["frac_after"] == pytest.approx(0.3)
    assert (right["before"], right["after"]) == (10, 40)
    assert right["frac_after"] == pytest.approx(0.8) and right["frac_before"] == pytest.approx(0.2)
    assert split["frac_after_range"] == pytest.approx(0.5)
    assert "nearest_mark" not in left
    with pytest.raises(PvedError):
        x_split_by_group(emb, np.r_[x[:-1], np.nan], 12.0)
    with pytest.raises(PvedError):
        x_split_by_group(emb, x[:-1], 12.0)


class _ZeroPolicy:
    """Stands in for a locomotion policy (none is shipped): zero torques."""

    def __init__(self, obs_dim: int, act_dim: int) -> None:
        self.obs_dim, self.act_dim = obs_dim, act_dim

    def act(self, obs: np.ndarray, deterministic: bool = True, rng: Any = None) -> np.ndarray:
        return np.zeros((obs.shape[0], self.act_dim))


def test_locomotion_rollouts_record_x_and_write_fig8(data: SubspaceData, tmp_path: Path) -> None:
    # The arm pairs' envs report no x: the split is skipped, nothing written.
    assert data.x_position is None
    assert write_x_split(data, data.shared[:, :2], tmp_path / "arm", 12.0) is None
    assert not (tmp_path / "arm").exists()

    src_id, tgt_id = "pved/Walker2dCurve-v0", "pved/HopperCurve-v0"
    src, tgt = make_batched(src_id, 1), make_batched(tgt_id, 1)
    n_s, n_t = len(src.robot_state_indices), len(tgt.robot_state_indices)
    a_s, a_t = src.single_action_space.shape[0], tgt.single_action_space.shape[0]
    torch.manual_seed(0)
    model = PVED(ModelDims(n_s + a_s, n_t + a_t, n_s, n_t), PVEDConfig())
    policies = [
        cast(Policy, _ZeroPolicy(env.single_observation_space.shape[0], a))
        for env, a in ((src, a_s), (tgt, a_t))
    ]
    loco = embed_rollouts(model, *policies, src_id, tgt_id, 2, seed=0, max_steps=8)
    assert loco.x_position is not None and loco.x_position.shape == (loco.num_points,)
    assert np.all(np.isfinite(loco.x_position))
    assert np.all(loco.x_position[loco.step == 0] == 0.0)  # every episode starts at x = 0
    ep = loco.target_episodes[0]
    assert ep.x_position is not None and ep.x_position.shape == (ep.length,)

    # Real rollouts never reach 12 m in 8 steps: place the target's later half beyond it,
    # and in its own region of a synthetic embedding, so the split has a known answer.
    tgt_rows = np.flatnonzero(loco.agent == 1)
    x = loco.x_position.copy()
    far = loco.step[tgt_rows] >= 4
    x[tgt_rows[far]] = CURVE_RAMP_LENGTH + loco.step[tgt_rows[far]]  # 16 m, 17 m, ...
    emb = np.zeros((loco.num_points, 2))
    emb[tgt_rows, 0] = np.where(far, 5.0, -5.0) + 0.01 * loco.step[tgt_rows]
    out = tmp_path / "loco"
    split = write_x_split(replace(loco, x_position=x), emb, out, CURVE_RAMP_LENGTH)
    assert split is not None and split["agent"] == "target"
    assert [g["frac_after"] for g in split["groups"]] == [0.0, 1.0]
    assert [g["size"] for g in split["groups"]] == [8, 8]

    from PIL import Image

    with Image.open(out / "fig8_groups.png") as im:
        assert im.size[0] > 200 and np.asarray(im).std() > 0

    # The pair report shows the figure and the numbers of a tsne folder holding them.
    numbers = subspace_numbers(loco)
    numbers["x_split"] = split
    numbers["mark_frames"] = {"target_later_frames": 2, "later_frame_stride": 5}
    (out / "numbers.json").write_text(json.dumps(numbers))
    html = build_pair_report("walker-hopper", [out], tmp_path / "r.html").read_text()
    assert "Fig. 8" in html and "x split: group G2" in html


def test_bound_matches_steps_on_the_banks_time_base() -> None:
    # pved bound pairs target step t with the source step the bank gives it in transfer:
    # on humanoid-ant (0.015 s against 0.05 s) Ant step 3 meets Humanoid step 10
    from pved.diagnostics.bound import match_steps
    from pved.diagnostics.rollouts import EpisodeRecord

    def episode(length: int) -> EpisodeRecord:
        return EpisodeRecord(
            np.zeros((length, 2)), np.zeros((length, 1)), np.zeros(length), 0, None, {}, False
        )

    source, target = episode(400), episode(150)
    np.testing.assert_array_equal(match_steps(source, target)[:4], [0, 1, 2, 3])
    scaled = match_steps(source, target, 0.05 / 0.015)
    np.testing.assert_array_equal(scaled[[0, 3, 30, 149]], [0, 10, 100, 399])
