"""Taylor & Stone's transfer measures (AUC, jumpstart, steps to PPO's final, final) of a
method against PPO, the A/A noise floor beside each verdict, and the curves they are read
from: a run's metrics.jsonl or a published protocol's committed record."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from helpers import protocol_dir
from pved.analysis.judge import Judge, load_pairs
from pved.analysis.run_curves import RECORD_FILE, auc, run_curve, steps_to_threshold

STEPS = [0, 1000, 2000, 3000, 4000]


def test_auc_is_the_curves_mean_height_and_steps_to_threshold_per_run() -> None:
    steps = np.asarray(STEPS)
    # a straight line from 0 to 1: half its span's height, on the metric's scale
    assert auc(steps, np.linspace(0.0, 1.0, 5)) == pytest.approx(0.5)
    assert auc(steps * 10, np.full(5, 0.3)) == pytest.approx(0.3)  # span-free
    # uneven steps weigh each segment by its length
    assert auc(np.asarray([0, 1, 3]), np.asarray([0.0, 1.0, 1.0])) == pytest.approx(2.5 / 3)
    assert auc(np.asarray([5]), np.asarray([0.4])) == pytest.approx(0.4)
    values = np.asarray([0.0, 0.2, 0.5, 0.4, 0.6])
    assert steps_to_threshold(steps, values, 0.45) == 2000
    # never reached: one evaluation interval past the last step, the earliest it could
    assert steps_to_threshold(steps, values, 0.9) == 5000


def summary_dir(root: Path, curves: dict[str, list[list[float]]], record: bool) -> Path:
    """A published-looking protocol directory: summary.json with no run directories, and
    (``record``) the committed record holding each run's curve."""
    root.mkdir(parents=True)
    methods: dict[str, Any] = {}
    runs_record: dict[str, Any] = {}
    for method, runs in curves.items():
        entries = []
        for i, curve in enumerate(runs):
            key = f"reacher/transfer/{method}/seed{i}"
            entries.append({"key": key, "seed": i, "success_rate": curve[-1]})
            rows = [{"step": s, "eval/success_rate": v} for s, v in zip(STEPS, curve, strict=True)]
            runs_record[key] = {"config": {}, "result": {}, "curve": rows}
        methods[method] = {"runs": entries}
    summary = {
        "budget": "quick",
        "pairs": {"reacher": {"metric": "success_rate", "methods": methods}},
    }
    (root / "summary.json").write_text(json.dumps(summary))
    if record:
        (root / RECORD_FILE).write_text(json.dumps(runs_record))
    return root


def test_a_published_record_gives_the_curves_and_without_it_there_are_none(
    tmp_path: Path,
) -> None:
    curves = {
        "ppo": [[0.0, 0.1, 0.2, 0.3, 0.4], [0.0, 0.2, 0.2, 0.4, 0.4]],
        "new": [[0.1, 0.4, 0.5, 0.6, 0.6], [0.1, 0.3, 0.5, 0.5, 0.7]],
    }
    with_record = load_pairs([summary_dir(tmp_path / "a", curves, record=True)])
    steps, values = run_curve(
        with_record["reacher"].directory,
        "success_rate",
        with_record["reacher"].methods["new"]["runs"][0],
    )
    assert steps.tolist() == STEPS and values.tolist() == curves["new"][0]
    part = Judge(with_record).faster_early("reacher", "new", "ppo")
    assert part["difference"]["value"] == pytest.approx(np.mean([0.25, 0.2]) - np.mean([0.05, 0.1]))
    without = load_pairs([summary_dir(tmp_path / "b", curves, record=False)])
    part = Judge(without).faster_early("reacher", "new", "ppo")
    assert part["verdict"] == "undecided" and part["reason"].startswith("no curves of run")


def rising(start: float, end: float, n: int = 6, spread: float = 0.02) -> list[list[float]]:
    """``n`` runs rising linearly from ``start`` to ``end``, each offset a little."""
    return [list(np.linspace(start, end, len(STEPS)) + o) for o in np.linspace(-spread, spread, n)]


def test_measures_match_a_hand_computation_with_holm_over_pairs_and_the_aa_check(
    tmp_path: Path,
) -> None:
    from pved.analysis.transfer_measures import INSIDE_AA, NO_AA, method_measures

    pairs = {
        # far ahead of PPO, and a tiny difference well inside PPO-vs-PPO's
        "reacher": {
            "ppo": rising(0, 0.4),
            "ppo-aa": rising(0, 0.4, spread=0.1),
            "new": rising(0.2, 0.9),
        },
        "jaco-fetch": {
            "ppo": rising(0, 0.4),
            "ppo-aa": rising(0, 0.4, spread=0.1),
            "new": rising(0, 0.401),
        },
        "walker-hopper": {"ppo": rising(0, 0.4), "new": rising(0, 0.8)},  # no A/A set
    }
    result = method_measures(load_pairs([protocol_dir(tmp_path / "p", pairs)]), "new")
    assert list(result["pairs"]) == ["reacher", "walker-hopper", "jaco-fetch"]  # Fig. 3's order
    reacher = result["pairs"]["reacher"]
    # a straight line's normalised area is its midpoint: (0.2 + 0.9) / 2 − (0 + 0.4) / 2
    assert reacher["auc"]["value"] == pytest.approx(0.55 - 0.2)
    assert reacher["jumpstart"]["value"] == pytest.approx(0.2)
    assert reacher["final"]["value"] == pytest.approx(0.5)
    # steps to PPO's final (0.4, its last points' mean), by hand per run; PPO's runs
    # below it at the end count one evaluation past the last step
    threshold = 0.4
    new_steps = [
        next(s for s, v in zip(STEPS, c, strict=True) if v >= threshold)
        for c in pairs["reacher"]["new"]
    ]
    ppo_steps = [
        next((s for s, v in zip(STEPS, c, strict=True) if v >= threshold), 5000)
        for c in pairs["reacher"]["ppo"]
    ]
    assert reacher["reach"]["value"] == pytest.approx(np.mean(new_steps) - np.mean(ppo_steps))
    assert reacher["reach"]["reached"] == 6 and reacher["reach"]["threshold"] == pytest.approx(
        threshold
    )
    for measure in ("auc", "final"):
        cells = [result["pairs"][p][measure] for p in result["pairs"]]
        assert all(c["p_holm"] >= c["p"] for c in cells)
        assert max(c["p_holm"] for c in cells) == pytest.approx(max(c["p"] for c in cells))
    assert reacher["final"]["inside_aa"] is False and reacher["final"]["aa"]["noise"] > 0
    jaco = result["pairs"]["jaco-fetch"]["final"]
    assert jaco["inside_aa"] is True and abs(jaco["value"]) <= jaco["aa"]["noise"]
    lo, hi = jaco["aa"]["ci"]
    assert jaco["aa"]["noise"] == pytest.approx(max(abs(lo), abs(hi)))
    walker = result["pairs"]["walker-hopper"]["final"]
    assert walker["aa"] == NO_AA and walker["inside_aa"] is None
    from pved.analysis.transfer_measures import measures_markdown

    md = measures_markdown(result)
    assert f"**{INSIDE_AA}**" in md and NO_AA in md and "(6 of 6 reach it)" in md


def test_scoreboard_and_claims_print_the_aa_check_and_the_exploratory_label(tmp_path: Path) -> None:
    from pved.analysis.claims import claims_markdown, judge_claims
    from pved.analysis.scoreboard import scoreboard, scoreboard_markdown

    pairs = {
        "reacher": {
            "ppo": rising(0, 0.4),
            "ppo-aa": rising(0, 0.4, spread=0.1),
            "new": rising(0, 0.401),
            "pved": rising(0, 0.401),
        },
        "jaco-fetch": {"ppo": rising(0, 0.4), "new": rising(0, 0.9)},
    }
    directory = protocol_dir(tmp_path / "p", pairs, new={"exploratory": True})
    result = scoreboard("new", [directory])
    rows = {r["pair"]: r for r in result["rows"]}
    assert rows["reacher"]["inside_aa"] is True and rows["jaco-fetch"]["aa"] == "no A/A set"
    assert rows["reacher"]["exploratory"] is True
    md = scoreboard_markdown(result)
    assert md.count("**exploratory**") == 3  # each row, and the measures' title
    assert "; **inside A/A noise** |" in md and "| no A/A set |" in md
    assert "AUC (normalised)" in md
    claims = judge_claims([directory])
    assert [t["method"] for t in claims["transfer_measures"]] == ["new", "pved"]
    (beats,) = [
        p for p in claims["claims"][0]["parts"] if p["pair"] == "reacher" and "difference" in p
    ]
    assert beats["inside_aa"] is True and beats["aa"]["noise"] >= abs(beats["difference"]["value"])
    md = claims_markdown(claims)
    assert "**exploratory** on reacher, jaco-fetch" in md
    assert "undecided (0.001); inside A/A noise" in md and "; A/A: no A/A set" not in md


def test_compare_gives_the_measures_and_the_aa_check_with_aa_runs(tmp_path: Path) -> None:
    from pved.analysis.compare import compare_runs, format_comparison
    from test_compare import make_run

    a = [make_run(tmp_path / "a", s, [0.0, 0.6, 1.0, 0.8, 0.9], 0.9) for s in (1, 2)]
    b = [
        make_run(tmp_path / "b", 1, [0.0, 0.0, 0.2, 0.4, 0.5], 0.5),
        make_run(tmp_path / "b", 2, [0.0, 0.0, 0.0, 0.2, 0.3], 0.3),
    ]
    result = compare_runs(a, b, ("new", "old"))
    m = result["measures"]
    # normalised AUC by hand (steps 0..1000 by 250): trapezoids / 1000
    auc_a = (0.3 + 0.8 + 0.9 + 0.85) * 250 / 1000
    auc_b = np.mean([(0 + 0.1 + 0.3 + 0.45) * 250 / 1000, (0 + 0 + 0.1 + 0.25) * 250 / 1000])
    assert m["auc"]["diff"] == pytest.approx(auc_a - auc_b)
    assert m["jumpstart"]["diff"] == pytest.approx(0.0)
    # old's final mean point 0.4: new reaches it at 250; old's runs at 750 and never (1250)
    assert m["reach"]["diff"] == pytest.approx(250 - (750 + 1250) / 2)
    assert result["aa"] == "no A/A set" and result["diff"]["final"]["inside_aa"] is None
    assert "A/A: no A/A set" in format_comparison(result)
    # a second set of old's kind: the difference new − old lies well outside its noise
    aa = [make_run(tmp_path / "aa", s, [0.0, 0.0, 0.1, 0.3, 0.4], 0.4) for s in (3, 4)]
    result = compare_runs(a, b, ("new", "old"), aa=aa)
    assert set(result["aa"]) == {"final", "early", "drop", "auc", "jumpstart", "reach"}
    assert result["aa"]["final"]["diff"] == pytest.approx(0.0)
    assert result["diff"]["final"]["inside_aa"] is False
    assert result["measures"]["jumpstart"]["inside_aa"] is True  # 0 against 0
    assert "- jumpstart: +0.000 [+0.000, +0.000]: new − old is inside A/A noise" in (
        format_comparison(result)
    )


@pytest.mark.parametrize("budget", ["smoke", "quick", "paper", "paper-45", "paper-wide"])
def test_the_aa_set_is_ppo_on_seeds_no_other_method_uses(tmp_path: Path, budget: str) -> None:
    from pved.config import get_budget
    from pved.protocol.plan import ProtocolPlan

    plan = ProtocolPlan(["reacher"], ["pved", "ppo", "ppo-aa", "oracle"], budget, tmp_path)
    jobs = [j for j in plan.expand({}) if "/transfer/" in j.key]
    by_method: dict[str, list[Any]] = {}
    for job in jobs:
        by_method.setdefault(job.kwargs["method"], []).append(job)
    b = get_budget(budget)
    aa_seeds = {j.kwargs["seed"] for j in by_method["ppo-aa"]}
    assert len(aa_seeds) == len(by_method["ppo"]) == b.source_policies * len(b.evaluation_seeds)
    others = {j.kwargs["seed"] for m, js in by_method.items() if m != "ppo-aa" for j in js}
    # the shaped methods' evaluation seeds (not planned before their selection) and tuning
    assert not aa_seeds & (others | set(b.evaluation_seeds) | set(b.tuning_seeds))
    # the same run as ppo's in every other respect
    ppo, aa = by_method["ppo"][0].kwargs, by_method["ppo-aa"][0].kwargs
    same = {k for k in ppo if k not in ("method", "seed", "run_name")}
    assert {k: aa[k] for k in same} == {k: ppo[k] for k in same}
    assert plan.evaluation_jobs("reacher", "ppo-aa")[0].key == by_method["ppo-aa"][0].key
