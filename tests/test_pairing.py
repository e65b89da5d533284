"""Alignment by subsampling (paper IV.A) and the paired dataset file contract."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pved.errors import PvedError
from pved.pairing.align import (
    align,
    dtw_indices,
    gait_phase,
    phase_indices,
    subsample_indices,
    time_indices,
)
from pved.pairing.dataset import PairedDataset, load_dataset, save_dataset


def test_subsample_keeps_shorter_and_spreads_longer() -> None:
    i_s, i_t = subsample_indices(10, 4)
    assert i_t.tolist() == [0, 1, 2, 3]
    assert i_s.tolist() == [0, 3, 6, 9]  # first and last kept, evenly spaced
    i_s, i_t = subsample_indices(3, 7)
    assert i_s.tolist() == [0, 1, 2] and i_t.tolist() == [0, 3, 6]
    i_s, i_t = subsample_indices(5, 5)
    assert i_s.tolist() == i_t.tolist() == [0, 1, 2, 3, 4]
    with pytest.raises(PvedError, match="unknown alignment 'warp'"):
        align("warp", 3, 3)
    with pytest.raises(PvedError, match="fitted to the collected episodes"):
        align("dtw", 3, 3)


def test_time_alignment_pairs_steps_at_the_same_moment() -> None:
    # Humanoid acts every 0.015 s, Ant every 0.05 s: 1000 Humanoid steps last 15 s, so
    # the first 300 Ant steps are paired, each with the Humanoid step nearest in time
    i_s, i_t = time_indices(1000, 1000, 0.015, 0.05)
    assert i_t.tolist() == list(range(300))
    assert np.all(np.abs(i_s * 0.015 - i_t * 0.05) <= 0.0075 + 1e-12)
    assert i_s[:4].tolist() == [0, 3, 7, 10]
    # the source is the coarse agent: the roles swap; a fallen (short) episode bounds it
    i_s, i_t = time_indices(100, 1000, 0.05, 0.015)
    assert i_s.tolist() == list(range(100)) and i_t[-1] == 330
    i_s, i_t = time_indices(1000, 20, 0.015, 0.05)  # the Ant fell after 1 s
    assert i_t.tolist() == list(range(20)) and i_s[-1] == 63
    # equal periods: the identity on the common length
    i_s, i_t = time_indices(7, 5, 0.02, 0.02)
    assert i_s.tolist() == i_t.tolist() == [0, 1, 2, 3, 4]
    assert align("time", 10, 10, 0.015, 0.05)[1].tolist() == [0, 1, 2]
    # 7 Humanoid steps end at 0.105 s: Ant's step at 0.1 s would need Humanoid step 7,
    # which never happened, so it is not paired (clamping to step 6 would be 0.01 s off)
    i_s, i_t = time_indices(7, 3, 0.015, 0.05)
    assert i_t.tolist() == [0, 1] and i_s.tolist() == [0, 3]
    # every pair, for any lengths, is at most half the finer period apart
    for length_source in range(1, 80):
        for length_target in range(1, 30):
            i_s, i_t = time_indices(length_source, length_target, 0.015, 0.05)
            assert len(i_s) >= 1
            assert np.abs(i_s * 0.015 - i_t * 0.05).max() <= 0.0075 + 1e-12
    with pytest.raises(PvedError, match="control periods"):
        align("time", 10, 10)


def test_dtw_pairs_a_stretched_episode_with_its_original() -> None:
    phase = np.linspace(0.0, 1.0, 6)
    source = np.stack([np.sin(3 * phase), phase], 1)  # (6, 2)
    target = np.repeat(source, 2, axis=0)  # the same motion at half speed, (12, 2)
    i_s, i_t = dtw_indices(source, target)
    # every target step is paired with the source step it repeats, and nothing else
    assert i_t.tolist() == list(range(12))
    assert i_s.tolist() == [k // 2 for k in range(12)]
    # identical episodes: the diagonal
    i_s, i_t = dtw_indices(source, source)
    assert i_s.tolist() == i_t.tolist() == list(range(6))
    # a shifted episode: monotone path from (0, 0) to the two last steps
    shifted = np.concatenate([source[:1].repeat(3, 0), source])
    i_s, i_t = dtw_indices(source, shifted)
    assert (i_s[0], i_t[0]) == (0, 0) and (i_s[-1], i_t[-1]) == (5, 8)
    assert np.all(np.diff(i_s) >= 0) and np.all(np.diff(i_t) >= 0)
    assert set(i_t.tolist()) == set(range(9))
    with pytest.raises(PvedError, match="equal K"):
        dtw_indices(source, np.zeros((4, 3)))
    with pytest.raises(PvedError, match="NaN"):
        dtw_indices(source, np.full((4, 2), np.nan))


def _dataset(rows: int = 12) -> PairedDataset:
    rng = np.random.default_rng(0)
    return PairedDataset(
        obs_source=rng.normal(size=(rows, 5)),
        act_source=rng.normal(size=(rows, 3)),
        obs_target=rng.normal(size=(rows, 7)),
        act_target=rng.normal(size=(rows, 4)),
        episode=np.repeat(np.arange(rows // 4), 4),
        t_source=np.tile(np.arange(4), rows // 4),
        t_target=np.tile(np.arange(4), rows // 4),
        task={"target": rng.normal(size=(rows // 4, 2))},
        header={
            "pair": "reacher",
            "source_agent": "Reacher3",
            "target_agent": "Reacher4",
            "robot_state_indices_source": [0, 1, 2],
            "robot_state_indices_target": [0, 2, 4, 6],
        },
    )


def test_dataset_round_trip_and_model_inputs(tmp_path: Path) -> None:
    data = _dataset()
    path = save_dataset(tmp_path / "pairs.npz", data)
    back = load_dataset(path)
    np.testing.assert_array_equal(back.obs_target, data.obs_target)
    np.testing.assert_array_equal(back.task["target"], data.task["target"])
    x_s, x_t = back.model_inputs()
    assert x_s.shape == (12, 3 + 3) and x_t.shape == (12, 4 + 4)
    np.testing.assert_allclose(x_t[:, :4], data.obs_target[:, [0, 2, 4, 6]].astype(np.float32))
    np.testing.assert_allclose(x_t[:, 4:], data.act_target.astype(np.float32))
    assert back.state_dims == (3, 4)
    back.check_agents("Reacher3", "Reacher4")
    with pytest.raises(PvedError, match="dataset is for"):
        back.check_agents("Walker2d", "Hopper")
    with pytest.raises(PvedError, match="obs_target has dim 7"):
        back.check_dims(5, 3, 8, 4)


def test_bad_datasets_are_one_line_errors(tmp_path: Path) -> None:
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 this is not a zip")
    with pytest.raises(PvedError, match="corrupt"):
        load_dataset(corrupt)
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, a=np.zeros(3))
    with pytest.raises(PvedError, match="not a pved paired dataset"):
        load_dataset(foreign)
    with pytest.raises(PvedError, match="not found"):
        load_dataset(tmp_path / "nope.npz")
    data = _dataset()
    data.obs_source[0, 0] = np.nan
    with pytest.raises(PvedError, match="NaN"):
        save_dataset(tmp_path / "nan.npz", data)
    assert not (tmp_path / "nan.npz").exists()


def test_phase_alignment_pairs_the_same_moment_of_two_strides() -> None:
    # two gaits at 20 steps a second, strides of 0.35 s and 0.5 s (the Humanoid's and the
    # Ant's on the Slope): by time their phases drift apart, by phase they meet
    t = np.arange(300) / 20.0
    phase_s = gait_phase(np.sin(2 * np.pi * t / 0.35))
    phase_t = gait_phase(np.cos(2 * np.pi * t / 0.5) + 0.1 * np.sin(2 * np.pi * t / 0.25))
    base = subsample_indices(300, 300)

    def gap(i_s: np.ndarray, i_t: np.ndarray) -> np.ndarray:
        return np.abs(np.angle(np.exp(1j * (phase_s[i_s] - phase_t[i_t]))))[20:-20]

    assert np.median(gap(*base)) > 1.0  # time pairing: about pi/2 on average
    i_s, i_t = phase_indices(phase_s, phase_t, base, window=10)
    assert i_t.tolist() == base[1].tolist()  # every target step kept, once, in order
    assert np.abs(i_s - base[0]).max() <= 10  # near its time partner
    # at the same moment of the stride, up to the source's sampling: a 7-step stride
    # leaves a gap of at most pi / 7 = 0.45 to the nearest step
    assert np.median(gap(i_s, i_t)) < 0.4
    # no room to move: the time pairing itself
    assert phase_indices(phase_s, phase_t, base, window=0)[0].tolist() == base[0].tolist()
    # the source steps between paired ones are candidates too (a finer source agent)
    fine = np.arange(0, 300, 3)
    i_s, _ = phase_indices(phase_s, phase_t, (fine, fine), window=1)
    assert set(i_s.tolist()) - set(fine.tolist())
    with pytest.raises(PvedError, match="equal non-empty"):
        phase_indices(phase_s, phase_t, (np.arange(3), np.arange(4)))
    with pytest.raises(PvedError, match="finite 1-D"):
        gait_phase(np.array([1.0, np.nan]))
