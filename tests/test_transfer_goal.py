"""Issue 64's goal from the records (:mod:`pved.analysis.transfer_goal`): the area under
the curve ahead after Holm on three pairs, the final score behind PPO and the pooled PPO
runs on none, judged only at the paper's budget with issue 64's run counts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import CURVE_STEPS, protocol_dir
from pved.analysis.judge import Judge, load_pairs
from pved.analysis.transfer_goal import (
    PAPER_BUDGETS,
    POOLED,
    pooled_final,
    runs_needed,
    transfer_goal,
    transfer_goal_markdown,
)
from pved.analysis.transfer_measures import method_measures


def rising(start: float, end: float, n: int, spread: float = 0.05) -> list[list[float]]:
    """``n`` runs rising linearly from ``start`` to ``end``, each offset a little."""
    line = np.linspace(start, end, len(CURVE_STEPS))
    return [list(line + o) for o in np.linspace(-spread, spread, n)]


def four_pairs(new: dict[str, tuple[float, float]], aa: bool = True) -> dict[str, Any]:
    """Every pair with PPO rising 0 -> 0.4 (and its A/A set) and the method's (start,
    end), each with issue 64's run count."""
    pairs: dict[str, Any] = {}
    for pair, (start, end) in new.items():
        n = runs_needed(pair)
        pairs[pair] = {"ppo": rising(0, 0.4, n), "new": rising(start, end, n)}
        if aa:
            pairs[pair]["ppo-aa"] = rising(0, 0.4, n, spread=0.08)
    return pairs


REPS = 4000
"""Resamples: enough for these far-apart groups, and quick."""


def goal(directory: Path) -> dict[str, Any]:
    pairs = load_pairs([directory])
    measures = method_measures(pairs, "new", Judge(pairs, reps=REPS))
    return transfer_goal(pairs, "new", measures, reps=REPS)


AHEAD3 = {
    "reacher": (0.3, 0.9),
    "walker-hopper": (0.3, 0.9),
    "jaco-fetch": (0.3, 0.9),
    "humanoid-ant": (0.0, 0.4),  # level
}


def test_reached_when_the_area_is_ahead_on_three_and_the_final_behind_on_none(
    tmp_path: Path,
) -> None:
    result = goal(protocol_dir(tmp_path / "p", four_pairs(AHEAD3), budget="paper-45"))
    assert result["verdict"] == "reached", result["why"]
    assert result["auc_ahead"] == ["reacher", "walker-hopper", "jaco-fetch"]
    assert result["unmet"] == [] and result["absent"] == []
    row = {r["pair"]: r for r in result["rows"]}["reacher"]
    # a straight line's normalised area is its midpoint: (0.3 + 0.9) / 2 − (0 + 0.4) / 2
    assert row["auc"]["value"] == pytest.approx(0.4)
    assert row["runs"] == {"new": 45, "ppo": 45} and row["pooled_final"]["runs"] == 90
    md = transfer_goal_markdown("new", result)
    assert "**reached**" in md and md.count("| AUC ahead |") == 3


def test_not_reached_when_the_final_is_behind_on_one_pair(tmp_path: Path) -> None:
    # ahead early (larger area) but ends below PPO: the area alone does not make the goal
    early = dict(AHEAD3, **{"humanoid-ant": (0.8, 0.1)})
    result = goal(protocol_dir(tmp_path / "p", four_pairs(early), budget="paper"))
    assert "humanoid-ant" in result["auc_ahead"]
    assert result["final_behind"] == ["humanoid-ant"] == result["pooled_behind"]
    assert result["verdict"] == "not reached"
    assert "final behind ppo" in transfer_goal_markdown("new", result)


def test_two_pairs_ahead_are_not_enough(tmp_path: Path) -> None:
    two = dict(AHEAD3, **{"jaco-fetch": (0.0, 0.4)})
    result = goal(protocol_dir(tmp_path / "p", four_pairs(two), budget="paper"))
    assert result["verdict"] == "not reached" and len(result["auc_ahead"]) == 2


def test_the_pooled_baseline_is_ppo_and_its_aa_set_by_hand(tmp_path: Path) -> None:
    pairs = load_pairs([protocol_dir(tmp_path / "p", four_pairs(AHEAD3), budget="paper")])
    pooled = pooled_final(pairs, "new", reps=REPS)
    finals = {
        m: [r["score"] for r in pairs["reacher"].methods[m]["runs"]]
        for m in pairs["reacher"].methods
    }
    hand = np.mean(finals["new"]) - np.mean(finals["ppo"] + finals["ppo-aa"])
    assert pooled["reacher"]["value"] == pytest.approx(hand)
    assert POOLED not in pairs["reacher"].methods  # the caller's summaries are left alone
    lo, hi = pooled["reacher"]["ci"]
    assert lo < hand < hi


@pytest.mark.parametrize(
    ("budget", "runs", "marks", "unmet"),
    [
        ("screen-auc", None, {}, "budget 'screen-auc' is not the paper's"),
        ("paper", 15, {}, "reacher: 15 runs, needs 45"),
        ("paper-45", None, {"new": {"exploratory": True}}, "exploratory (not pre-registered)"),
        ("paper-45", None, {"aa": False}, "no ppo-aa runs (no A/A set to pool)"),
    ],
)
def test_not_judged_off_the_paper_budget_with_too_few_runs_or_exploratory(
    tmp_path: Path, budget: str, runs: int | None, marks: dict[str, Any], unmet: str
) -> None:
    pairs = four_pairs(AHEAD3, aa=marks.get("aa", True))
    marks = {m: v for m, v in marks.items() if m != "aa"}
    if runs is not None:
        pairs["reacher"] = {m: c[:runs] for m, c in pairs["reacher"].items()}
    result = goal(protocol_dir(tmp_path / "p", pairs, budget=budget, **marks))
    assert result["verdict"] == "not judged"
    assert any(unmet in u for u in result["unmet"]), result["unmet"]
    assert "standing now: AUC ahead on 3 of 4" in result["why"]


def test_a_pair_not_run_leaves_it_unjudged_unless_already_out_of_reach(tmp_path: Path) -> None:
    three = {k: v for k, v in AHEAD3.items() if k != "jaco-fetch"}
    result = goal(protocol_dir(tmp_path / "a", four_pairs(three), budget="paper"))
    assert result["verdict"] == "not judged" and result["absent"] == ["jaco-fetch"]
    behind = dict(three, **{"reacher": (0.0, 0.1)})  # behind: nothing can mend that
    result = goal(protocol_dir(tmp_path / "b", four_pairs(behind), budget="paper"))
    assert result["verdict"] == "not reached" and "whatever jaco-fetch show" in result["why"]


def test_paper_budgets_are_the_budgets_of_the_papers_length() -> None:
    from pved.config import BUDGETS

    assert set(PAPER_BUDGETS) == {n for n, b in BUDGETS.items() if b.steps_budget == "paper"}


def test_behind_the_pooled_ppo_runs_alone_misses_the_goal(tmp_path: Path) -> None:
    pairs = four_pairs(AHEAD3)
    # PPO's own runs spread wide around 0.4, its A/A set ends at 0.9: the method (0.5) is
    # not behind PPO's set but behind the two pooled
    pairs["humanoid-ant"] = {
        "ppo": rising(0, 0.4, 15, spread=0.3),
        "ppo-aa": rising(0, 0.9, 15),
        "new": rising(0, 0.5, 15),
    }
    result = goal(protocol_dir(tmp_path / "p", pairs, budget="paper"))
    assert result["final_behind"] == [] and result["pooled_behind"] == ["humanoid-ant"]
    assert result["verdict"] == "not reached"


def test_the_area_counts_only_where_it_holds_after_holm(tmp_path: Path) -> None:
    pairs = load_pairs([protocol_dir(tmp_path / "p", four_pairs(AHEAD3), budget="paper")])
    measures = method_measures(pairs, "new", Judge(pairs, reps=REPS))
    # ahead at 5% alone, not once the four pairs' p-values are adjusted
    measures["pairs"]["reacher"]["auc"].update(p=0.02, p_holm=0.06)
    result = transfer_goal(pairs, "new", measures, reps=REPS)
    assert "reacher" not in result["auc_ahead"] and result["verdict"] == "not reached"


def test_the_pooled_interval_follows_the_resampling_seed(tmp_path: Path) -> None:
    pairs = load_pairs([protocol_dir(tmp_path / "p", four_pairs(AHEAD3), budget="paper")])
    a, b = (pooled_final(pairs, "new", reps=REPS, seed=s)["reacher"] for s in (0, 1))
    assert a["value"] == b["value"] and a["ci"] != b["ci"]


def test_the_results_page_table_is_the_scoreboards_goal(tmp_path: Path) -> None:
    """``<!-- pved:table goal-64 METHOD DIR... -->`` prints the goal ``pved scoreboard``
    computes (``transfer_goal`` over the same records and resampling), without its
    heading, and notes the verdict for the seed check."""
    from pved.analysis.result_tables import TABLES, Records

    records = tmp_path / "docs" / "protocol"
    early = dict(AHEAD3, **{"humanoid-ant": (0.8, 0.1)})
    protocol_dir(records / "a", {k: v for k, v in four_pairs(early).items() if k != "reacher"})
    protocol_dir(records / "b", {"reacher": four_pairs(early)["reacher"]}, budget="paper-45")
    rec = Records(tmp_path, reps=REPS, seed=3)
    table = TABLES["goal-64"](rec, "docs/results.md", "new", "a", "b")
    pairs = load_pairs([records / "a", records / "b"])
    measures = method_measures(pairs, "new", Judge(pairs, reps=REPS, seed=3))
    expected = transfer_goal(pairs, "new", measures, reps=REPS, seed=3)
    assert expected["verdict"] == "not reached"  # humanoid-ant ends behind
    assert table == transfer_goal_markdown("new", expected).split("\n", 2)[2]
    assert table.startswith("Needs: ") and "**not reached**" in table
    assert list(rec.verdicts.values()) == ["not reached"]
