"""The power statement (issue 64): δ against a hand computation, PPO's spread read from
a committed record, and the CLI."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from pved.analysis.judge import load_pairs, run_scores
from pved.analysis.power import detectable, power_rows, reference_spread
from pved.errors import PvedError

SCREEN = Path(__file__).resolve().parents[1] / "docs/protocol/reacher-screen"


def test_detectable_is_the_normal_approximation_by_hand() -> None:
    # z(0.975) = 1.959964, z(0.8) = 0.841621: (1.959964 + 0.841621) · 0.5 · √(2/15)
    assert detectable(0.5, 15) == pytest.approx(2.801585 * 0.5 * math.sqrt(2 / 15), rel=1e-6)
    # four times the runs halve it; a stricter level or more power widen it
    assert detectable(0.3, 60) == pytest.approx(detectable(0.3, 15) / 2)
    assert detectable(0.3, 15, alpha=0.0125) > detectable(0.3, 15)
    assert detectable(0.3, 15, power=0.9) > detectable(0.3, 15)
    with pytest.raises(PvedError, match="bad arguments"):
        detectable(0.3, 0)


def test_ppos_spread_is_taken_over_its_runs_and_the_aa_set() -> None:
    pairs = load_pairs([SCREEN])
    finals = np.concatenate([run_scores(pairs, "reacher", m, "final") for m in ("ppo", "ppo-aa")])
    sd, count = reference_spread(pairs, "reacher", "final")
    assert count == len(finals) == 30 and sd == pytest.approx(float(np.std(finals, ddof=1)))
    rows = power_rows(pairs, (15, 45))
    assert [(r["score"], r["reference_runs"]) for r in rows] == [("final", 30), ("auc", 30)]
    for row in rows:
        assert row["detectable"][45] < row["detectable"][15] < row["detectable_holm"][15]
        assert row["detectable_worst"][15] == pytest.approx(detectable(0.5, 15))


def test_power_verb(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(capsys, "power", SCREEN, "--runs", 15)
    assert code == 0 and "| reacher (success_rate) | final | 30 |" in out
    code, _, err = run_cli(capsys, "power", SCREEN, "--runs", 0)
    assert code != 0 and "--runs" in err
