"""``pved pair signal``: the pairing's R² on a few fresh paired episodes."""

from __future__ import annotations

from pathlib import Path

import pytest

from helpers import run_cli
from pved.diagnostics.pairing_signal import format_signal, pair_signal
from pved.errors import PvedError


def test_reachers_pairing_relates_the_arms_and_the_shuffled_floor_is_zero(
    tmp_path: Path,
) -> None:
    result = pair_signal("reacher", episodes=40, runs_root=tmp_path / "runs")
    r2 = result["r2"]
    # the shipped Reach policies steer both arms to the same target: one arm's step
    # predicts much of the other's, and nothing once the partners are shuffled
    assert r2["source_to_target"] > 0.3 and r2["target_to_source"] > 0.3
    assert abs(r2["source_to_shuffled_target"]) < 0.05
    assert result["episodes"] == 40 and result["rows"] == 2000
    text = format_signal(result)
    assert "relates the agents" in text and f"{r2['source_to_target']:.3f}" in text
    # kept under --runs, and collected once
    datasets = list((tmp_path / "runs").rglob("*.npz"))
    assert len(datasets) == 1
    assert pair_signal("reacher", episodes=40, runs_root=tmp_path / "runs")["r2"] == r2


def test_bad_options_are_refused_before_anything_is_collected(tmp_path: Path) -> None:
    with pytest.raises(PvedError, match="--episodes must be an integer >= 20, got 5"):
        pair_signal("reacher", episodes=5, runs_root=tmp_path / "runs")
    with pytest.raises(PvedError, match="unknown pair"):
        pair_signal("nope", runs_root=tmp_path / "runs")
    assert not (tmp_path / "runs").exists()


def test_pair_signal_verb_prints_the_table_and_its_reading(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = run_cli(
        capsys, "pair", "signal", "reacher", "--episodes", "20", "--runs", tmp_path / "runs"
    )
    assert code == 0
    assert "| source → target | target → source | source → shuffled target |" in out
    assert "The pairing relates the agents" in out
