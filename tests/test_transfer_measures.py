"""Taylor & Stone's transfer measures (AUC, jumpstart, steps to PPO's final, final) of a
method against PPO, the A/A noise floor beside each verdict, and the curves they are read
from: a run's metrics.jsonl or a published protocol's committed record."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

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
