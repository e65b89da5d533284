"""``pved scoreboard``: one method against PPO on every pair, and the goal's verdict, from
synthetic protocol summaries whose answers are known."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import run_cli
from pved.analysis.judge import FOUR
from pved.analysis.scoreboard import (
    AHEAD,
    BEHIND,
    LEVEL,
    load_merged,
    scoreboard,
    scoreboard_markdown,
    write_scoreboard,
)
from pved.errors import PvedError

PPO_STEPS = [0, 25_000, 50_000, 75_000, 100_000]


def method_entry(
    pair: str, method: str, finals: list[float], reach: int | None = 40_000, improved: bool = True
) -> dict[str, Any]:
    """A summary's method entry: 15 runs (5 seeds x 3 sources for a shaped method, 15
    seeds for ppo and the oracle) with these final scores, cycled."""
    runs = []
    for i in range(15):
        if method in ("ppo", "oracle"):
            key, seed = f"{pair}/transfer/{method}/seed{i}", i
        else:
            seed = 20000 * (1 + i // 3)
            key = f"{pair}/transfer/{method}-beta0.1-init0-src{i % 3}/seed{seed}"
        runs.append({"key": key, "seed": seed, "score": finals[i % len(finals)]})
    entry: dict[str, Any] = {"runs": runs, "curve_steps": PPO_STEPS}
    if improved:
        entry["ppo_final"] = 0.3
        entry["steps_to_ppo_final"] = reach
    else:
        entry["ppo_improved"] = False
    return entry


def write_protocol(
    root: Path, pairs: dict[str, dict[str, dict[str, Any]]], budget: str = "paper"
) -> Path:
    root.mkdir(parents=True)
    summary = {
        "budget": budget,
        "pairs": {p: {"metric": "score", "methods": m} for p, m in pairs.items()},
    }
    (root / "summary.json").write_text(json.dumps(summary))
    return root


def board(
    pair: str, method: list[float], reach: int | None = 40_000, ppo: list[float] | None = None
) -> dict[str, dict[str, Any]]:
    """A pair's methods: ppo around 0.3, the method with ``method``'s finals."""
    return {
        "ppo": method_entry(pair, "ppo", ppo or [0.25, 0.3, 0.35], reach=100_000),
        "new": method_entry(pair, "new", method, reach=reach),
    }


def test_goal_reached_when_ahead_and_fast_on_three_and_behind_on_none(tmp_path: Path) -> None:
    pairs = {p: board(p, [0.9, 0.95, 1.0]) for p in FOUR[:3]}
    pairs[FOUR[3]] = board(FOUR[3], [0.2, 0.3, 0.4])  # level with ppo
    result = scoreboard("new", [write_protocol(tmp_path / "p", pairs)])
    standing = {r["pair"]: r["standing"] for r in result["rows"]}
    assert standing == {**dict.fromkeys(FOUR[:3], AHEAD), FOUR[3]: LEVEL}
    assert result["goal"]["verdict"] == "reached"
    row = result["rows"][0]
    assert row["fraction_of_ppo_steps"] == pytest.approx(0.4) and row["fast"]
    np.testing.assert_allclose(row["difference"]["value"], 0.95 - 0.3)
    assert row["columns"]["ppo"]["runs"] == 15 and "pved" not in row["columns"]
    md = scoreboard_markdown(result)
    assert "**reached**" in md and md.count("| ahead, fast |") == 3


def test_goal_not_reached_when_behind_anywhere_or_slow(tmp_path: Path) -> None:
    pairs = {p: board(p, [0.9, 0.95, 1.0]) for p in FOUR}
    pairs[FOUR[2]] = board(FOUR[2], [0.0, 0.01, 0.02])
    result = scoreboard("new", [write_protocol(tmp_path / "behind", pairs)])
    assert [r["standing"] for r in result["rows"]].count(BEHIND) == 1
    assert result["goal"]["verdict"] == "not reached"
    # ahead on all four, but past half of PPO's steps on two of them
    slow = {
        p: board(p, [0.9, 0.95, 1.0], reach=60_000 if i < 2 else 50_000) for i, p in enumerate(FOUR)
    }
    result = scoreboard("new", [write_protocol(tmp_path / "slow", slow)])
    assert result["goal"]["ahead_and_fast"] == list(FOUR[2:])
    assert result["goal"]["verdict"] == "not reached"
    never = {p: board(p, [0.9, 0.95, 1.0], reach=None) for p in FOUR}
    result = scoreboard("new", [write_protocol(tmp_path / "never", never)])
    assert not any(r["fast"] for r in result["rows"])
    assert "not reached |" in scoreboard_markdown(result)


def test_missing_pairs_leave_the_goal_unjudged(tmp_path: Path) -> None:
    pairs = {p: board(p, [0.9, 0.95, 1.0]) for p in FOUR[:3]}
    pairs[FOUR[3]] = {"ppo": board(FOUR[3], [0.5])["ppo"]}  # the method did not run here
    result = scoreboard("new", [write_protocol(tmp_path / "p", pairs)])
    assert result["goal"]["verdict"] == "not judged"
    assert result["goal"]["missing_pairs"] == [FOUR[3]]
    assert "no runs of new" in result["rows"][3]["reason"]
    # the pair's baselines still show, the method's cells say it did not run
    assert result["rows"][3]["columns"]["ppo"]["mean"] == pytest.approx(0.3)
    row = scoreboard_markdown(result).splitlines()[9]
    assert row.startswith(f"| {FOUR[3]} | score | 0.300 [") and "(15) | – | not run | – |" in row


def test_missing_pairs_do_not_hold_back_a_goal_already_out_of_reach(tmp_path: Path) -> None:
    # ahead on one, level on two: the fourth cannot make three ahead
    pairs = {FOUR[0]: board(FOUR[0], [0.9, 0.95, 1.0])}
    pairs.update({p: board(p, [0.2, 0.3, 0.4]) for p in FOUR[1:3]})
    result = scoreboard("new", [write_protocol(tmp_path / "level", pairs)])
    assert result["goal"]["verdict"] == "not reached"
    assert result["goal"]["why"].endswith(f"whatever {FOUR[3]} show(s)")
    # ahead on two, the other two missing: still open
    two = {p: board(p, [0.9, 0.95, 1.0]) for p in FOUR[:2]}
    assert scoreboard("new", [write_protocol(tmp_path / "two", two)])["goal"]["verdict"] == (
        "not judged"
    )
    # behind on one pair: missed, however many are missing
    behind = {FOUR[0]: board(FOUR[0], [0.0, 0.01, 0.02])}
    result = scoreboard("new", [write_protocol(tmp_path / "behind", behind)])
    assert result["goal"]["verdict"] == "not reached" and result["goal"]["behind"] == [FOUR[0]]


def test_a_pair_the_method_skipped_keeps_pved_and_the_oracle(tmp_path: Path) -> None:
    ran = board(FOUR[0], [0.9, 0.95, 1.0])
    skipped = {
        "ppo": board(FOUR[1], [0.2, 0.3, 0.4])["ppo"],
        "pved": method_entry(FOUR[1], "pved", [0.6]),
        "oracle": method_entry(FOUR[1], "oracle", [0.8]),
    }
    result = scoreboard("new", [write_protocol(tmp_path / "p", {FOUR[0]: ran, FOUR[1]: skipped})])
    columns = result["rows"][1]["columns"]
    assert sorted(columns) == ["oracle", "ppo", "pved"]
    assert columns["pved"]["mean"] == pytest.approx(0.6)
    assert columns["oracle"]["mean"] == pytest.approx(0.8)
    assert columns["ppo"]["mean"] == pytest.approx(0.3)
    assert "difference" not in result["rows"][1] and result["goal"]["verdict"] == "not judged"


def test_a_ppo_that_did_not_improve_is_reached_at_once(tmp_path: Path) -> None:
    pair = board("walker-hopper", [2.0, 2.5, 3.0])
    pair["new"] = method_entry("walker-hopper", "new", [2.0, 2.5, 3.0], improved=False)
    result = scoreboard("new", [write_protocol(tmp_path / "p", {"walker-hopper": pair})])
    (row,) = result["rows"]
    assert row["fast"] and not row["ppo_improved"] and row["steps_to_ppo_final"] is None
    assert "ppo did not improve" in scoreboard_markdown(result)


def test_pairs_merge_across_protocols_of_one_budget(tmp_path: Path) -> None:
    shared_ppo = board("reacher", [0.9])["ppo"]
    screen = write_protocol(
        tmp_path / "screen",
        {"reacher": {"ppo": shared_ppo, **{"new": board("reacher", [1])["new"]}}},
    )
    full = write_protocol(
        tmp_path / "full",
        {
            "reacher": {
                "ppo": shared_ppo,
                "pved": method_entry("reacher", "pved", [0.1]),
                "oracle": method_entry("reacher", "oracle", [0.8]),
            }
        },
    )
    pairs = load_merged([screen, full])
    assert sorted(pairs["reacher"].methods) == ["new", "oracle", "ppo", "pved"]
    row = scoreboard("new", [screen, full])["rows"][0]
    assert sorted(row["columns"]) == ["new", "oracle", "ppo", "pved"]
    assert row["columns"]["oracle"]["mean"] == pytest.approx(0.8)
    # only the oracle taken from the full protocol
    only = load_merged([screen, f"oracle={full}"])
    assert sorted(only["reacher"].methods) == ["new", "oracle", "ppo"]


@pytest.mark.parametrize(
    "case, message",
    [
        ("budgets", "give one budget per pair"),
        ("different-ppo", "has different runs in"),
        ("absent-method", "no runs of pved there"),
        ("twice", "is given twice"),
        ("not-a-protocol", "no summary.json"),
    ],
)
def test_bad_inputs_fail_with_one_line(tmp_path: Path, case: str, message: str) -> None:
    a = write_protocol(tmp_path / "a", {"reacher": board("reacher", [0.9])})
    other_ppo = board("reacher", [0.9], ppo=[0.1, 0.2])
    budget = "quick" if case == "budgets" else "paper"
    b = write_protocol(tmp_path / "b", {"reacher": other_ppo}, budget=budget)
    inputs: list[str | Path] = {
        "budgets": [a, b],
        "different-ppo": [a, b],
        "absent-method": [a, f"pved={b}"],
        "twice": [a, a],
        "not-a-protocol": [a, tmp_path],
    }[case]
    with pytest.raises(PvedError, match=message):
        load_merged(inputs)


def test_cli_writes_both_files_or_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    proto = write_protocol(tmp_path / "p", {p: board(p, [0.9, 1.0]) for p in FOUR})
    out = tmp_path / "out"
    code, stdout, stderr = run_cli(capsys, "scoreboard", "--method", "new", proto, "--out", out)
    assert code == 0, stderr
    assert "Goal" in stdout and (out / "scoreboard.md").read_text() == stdout
    assert json.loads((out / "scoreboard.json").read_text())["goal"]["verdict"] == "reached"
    bad = tmp_path / "bad"
    code, _, stderr = run_cli(capsys, "scoreboard", "--method", "ppo", proto, "--out", bad)
    assert code != 0 and len(stderr.strip().splitlines()) == 1
    assert "not a column beside it" in stderr and not bad.exists()
    assert write_scoreboard("new", [proto]).startswith("# new against plain PPO (paper budget)")
