"""The alignments fitted to collected episode pairs (``pved.pairing.rounds``), without a
simulator or a model: the DTW rounds take their trainer as a function."""

from __future__ import annotations

import numpy as np

from pved.pairing.align import subsample_indices
from pved.pairing.collect import Episode, EpisodePair
from pved.pairing.rounds import (
    Embedder,
    base_alignment,
    dtw_rounds,
    model_rows,
    partner,
    phase_alignment,
)

HEADER = {"robot_state_indices_source": [0], "robot_state_indices_target": [1]}


def _stride_pair(length_s: int, length_t: int) -> EpisodePair:
    """One stride of each agent, the target's slower: the same curve over a different
    number of steps (state ``[signal]`` for the source, ``[noise, signal]`` for the
    target, one action each)."""
    s = np.sin(np.linspace(0.0, np.pi, length_s)) ** 2
    t = np.sin(np.linspace(0.0, np.pi, length_t) ** 1.5 / np.pi**0.5) ** 2
    source = Episode(s[:, None], np.zeros((length_s, 1)), {}, True)
    target = Episode(np.stack([np.ones(length_t), t], 1), np.zeros((length_t, 1)), {}, True)
    return source, target


def test_base_alignment_is_the_time_alignment_each_method_starts_from() -> None:
    assert base_alignment("dtw", 0.02, 0.05) == "subsample"
    assert base_alignment("phase", 0.02, 0.05) == "time"
    assert base_alignment("phase", None, 0.05) == "subsample"
    assert base_alignment("time", 0.02, 0.05) == "time"
    assert base_alignment("subsample", None, None) == "subsample"


def test_partner_is_the_mean_target_step_of_each_source_step() -> None:
    got = partner((np.array([0, 0, 2]), np.array([0, 2, 3])), 4)
    assert got[0] == 1.0 and got[2] == 3.0
    assert np.isnan(got[1]) and np.isnan(got[3])


def test_model_rows_are_robot_state_then_action_per_agent() -> None:
    pairs = [_stride_pair(5, 7), _stride_pair(6, 4)]
    rows = model_rows(pairs, HEADER)
    assert [r.shape for r in rows] == [(5, 2), (7, 2), (6, 2), (4, 2)]
    assert rows[1].dtype == np.float32
    np.testing.assert_allclose(rows[1][:, 0], pairs[0][1].obs[:, 1], rtol=1e-6)


def test_dtw_rounds_train_on_the_current_alignment_and_warp_by_the_embedding() -> None:
    pairs = [_stride_pair(20, 30), _stride_pair(25, 40)]
    start = [subsample_indices(len(s.obs), len(t.obs)) for s, t in pairs]
    trained_on: list[int] = []

    def fit(x_s: np.ndarray, x_t: np.ndarray) -> Embedder:
        trained_on.append(len(x_s))
        assert x_s.shape[1] == x_t.shape[1] == 2  # [robot state, action] of both agents
        # a "model" whose shared mean is its input (robot state, and an action of 0)
        return lambda rows_s, rows_t: (rows_s, rows_t)

    alignment, stats = dtw_rounds(pairs, start, HEADER, 2, fit)
    # round 1 trains on the subsample alignment's rows, round 2 on the warped pairs
    assert trained_on[0] == sum(len(i_s) for i_s, _ in start) and len(trained_on) == 2
    assert [s["round"] for s in stats] == [1.0, 2.0]
    assert stats[0]["moved_fraction"] > 0  # the warp re-pairs the stretched stride
    assert stats[1]["moved_fraction"] == 0  # the same embedding warps the same way
    for (e_s, e_t), (i_s, i_t) in zip(pairs, alignment, strict=True):
        gap = np.abs(e_s.obs[i_s, 0] - e_t.obs[i_t, 1])
        base = subsample_indices(len(e_s.obs), len(e_t.obs))
        assert gap.mean() < np.abs(e_s.obs[base[0], 0] - e_t.obs[base[1], 1]).mean()
    assert dtw_rounds(pairs, start, HEADER, 0, fit) == (start, [])


def test_phase_alignment_reports_what_moved() -> None:
    pairs = [_stride_pair(40, 40), _stride_pair(40, 40)]
    start = [subsample_indices(40, 40) for _ in pairs]
    alignment, stats = phase_alignment(pairs, start, HEADER)
    assert stats["window"] > 0 and 0 < stats["pc1_variance_source"] <= 1
    for (i_s, i_t), (_, base_t) in zip(alignment, start, strict=True):
        assert i_t.tolist() == base_t.tolist()  # every target step kept, once, in order
        assert np.abs(i_s - i_t).max() <= stats["window"]
    moved = np.concatenate([np.abs(a[0] - b[0]) for a, b in zip(alignment, start, strict=True)])
    assert stats["moved_fraction"] == float(np.mean(moved > 0))
    assert stats["mean_source_steps_moved"] == float(moved.mean())
