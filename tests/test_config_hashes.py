"""Config hashes pinned: a run directory is reused, and the committed and archived
protocol runs are matched, by the hash of its resolved config (``pved.runs.Run``). These
values were computed at commit 4fc9087, before options were checked by type and range
and before checkpoints by time; a change to what goes into a config must not move them.
The shaped runs' pins are those of 1bc0bb8, where Eq. 10's reward scaling took its final
form (``transfer_spec.eq10_config``: the env part clipped, the term never), which moved them on
purpose: shaped runs made before compute otherwise and must not be taken for these. Issue 64
moved them again on purpose (``source_end``: a target step past its source episode's end is
compared with nothing, where the frozen last row was before).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import pved.experiments.stages as stages
from pved.rl.ppo import PPOConfig
from pved.runs import Run, config_hash
from pved.spec import PRESETS, get_preset


def _spec_hash(tmp_path: Path, pair: str, method: str, **options: Any) -> str:
    model, bank = tmp_path / "model.pt", tmp_path / "bank.npz"
    model.write_bytes(b"model")  # hashed by its bytes, not read
    bank.write_bytes(b"bank")
    if method not in ("ppo", "oracle"):
        options.update(model_path=model, bank_path=bank)
    spec = stages.transfer_spec(pair, method, runs_root=tmp_path / "runs", **options)
    return config_hash(spec.config)


@pytest.mark.parametrize(
    ("pair", "method", "options", "expected"),
    [
        ("reacher", "ppo", {}, "ff1d081450c13b6e"),
        (
            "reacher",
            "ppo",
            {
                "seed": 2000,
                "steps": 8192,
                "eval_every": 4096,
                "eval_episodes": 16,
                "final_eval_episodes": 32,
            },
            "2a119187cc69edca",
        ),
        ("jaco-fetch", "oracle", {}, "8f38f7386e5e6ec6"),
        ("reacher", "pved", {}, "00a7f6dae2aecce4"),
        ("walker-hopper", "pved", {"beta": 0.01}, "7fd31d2c86258a62"),
    ],
)
def test_transfer_config_hashes_are_those_of_the_runs_made_before(
    tmp_path: Path, pair: str, method: str, options: dict[str, Any], expected: str
) -> None:
    assert _spec_hash(tmp_path, pair, method, **options) == expected


class _Started(Exception):
    """Raised where a stage would make its run directory: its config is resolved."""


@pytest.mark.parametrize(
    ("stage", "args", "options", "expected"),
    [
        ("train_policy", ("Reacher4", "Push"), {"seed": 3}, "c47fcc82e248fe65"),
        ("train_policy", ("Hopper", "Slope"), {"seed": 1, "steps": 16384}, "6bea4aa36b9b2e86"),
        ("collect_pairs", ("reacher",), {"episodes": 64}, "c194bbcd0fea0e43"),
        ("build_bank", ("reacher",), {"episodes": 16, "seed": 1}, "ba27a92f9c815dae"),
    ],
)
def test_stage_config_hashes_are_those_of_the_runs_made_before(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    stage: str,
    args: tuple[str, ...],
    options: dict[str, Any],
    expected: str,
) -> None:
    hashes: list[str] = []

    def record_and_stop(run: Run) -> None:
        hashes.append(run.hash)
        raise _Started

    monkeypatch.setattr(Run, "start", record_and_stop)
    with pytest.raises(_Started):
        getattr(stages, stage)(*args, runs_root=tmp_path / "runs", **options)
    assert hashes == [expected]


def test_config_dataclass_hashes_are_those_of_the_runs_made_before() -> None:
    assert config_hash({"ppo": PPOConfig()}) == "27cc87a62db7e879"
    pinned = {
        "reacher": ("6e6bab0e6f4ee4a0", "b4fcd3a3e6391bf5"),
        "jaco-fetch": ("6e6bab0e6f4ee4a0", "74cc767d92b6c5cd"),
        "walker-hopper": ("6e6bab0e6f4ee4a0", "5b4295bca2d01732"),
        "humanoid-ant": ("f31d1f45c51b852e", "2f48ea4c0e4f792b"),
    }
    assert set(pinned) == set(PRESETS)
    for pair, (model, transfer_and_pairing) in pinned.items():
        preset = get_preset(pair)
        assert config_hash({"m": preset.model_config("pved", seed=1)}) == model, pair
        assert config_hash({"t": preset.transfer, "pairing": preset.pairing}) == (
            transfer_and_pairing
        ), pair
        gupta = preset.model_config("gupta2017", seed=0, epochs=2)
        assert config_hash({"g": gupta}) == "79ef5bd7a38c8c0c", pair
