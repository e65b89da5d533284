"""The power statement (issue 64): δ against a hand computation, PPO's spread read from
a committed record, the two-level simulation against the independence formula it
replaces, and the CLI (tiny simulation counts: seconds)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from helpers import run_cli
from pved.analysis.judge import load_pairs, run_scores
from pved.analysis.power import (
    Pilot,
    detectable,
    pilot,
    power_rows,
    reference_spread,
    two_level_detectable,
    two_level_power,
)
from pved.errors import PvedError

SCREEN = Path(__file__).resolve().parents[1] / "docs/protocol/reacher-screen"
AUC_BAR = SCREEN.with_name("reacher-screen-auc-bar")
TINY = {"datasets": 100, "reps": 400}


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


def test_three_sources_that_differ_do_not_decide_what_independent_runs_would() -> None:
    # three source policies whose means differ a lot: the judge's bootstrap draws the
    # sources first, so its interval's low end sits near the worst source
    p = Pilot(between=0.3, within=0.1, ppo=0.1)
    old_table = detectable(p.ppo, 45)  # what the table printed: PPO's σ, runs independent
    pooled = detectable(math.hypot(p.between, p.within), 45)  # even with the method's σ
    power_old, power_pooled = two_level_power(p, 3, 15, [old_table, pooled], **TINY)
    assert power_old < 0.4 and power_pooled < 0.65  # the formula claims 0.8 for both
    three = two_level_detectable(p, 3, 15, **TINY)
    assert three > 1.5 * pooled
    assert two_level_detectable(p, 9, 5, **TINY) < three  # more sources, same 45 runs
    with pytest.raises(PvedError, match="bad design"):
        two_level_power(p, 1, 45, [0.1])


def test_a_records_pilot_and_its_rows() -> None:
    pairs = load_pairs([AUC_BAR])
    p = pilot(pairs, "reacher", "pved-prior", "auc")
    # the reviewer's per-source areas; the between-source SD is the ANOVA estimate
    assert [round(m, 3) for m in p.source_means] == [0.432, 0.083, 0.415]
    assert (p.sources, p.seeds) == (3, 5)
    assert p.between**2 == pytest.approx(np.var(p.source_means, ddof=1) - p.within**2 / 5)
    assert p.ppo == reference_spread(pairs, "reacher", "auc")[0]
    rows = power_rows(pairs, 45, (3, 9), ["pved-prior"], **TINY)
    assert [(r["method"], r["score"]) for r in rows] == [
        ("pved-prior", "final"),
        ("pved-prior", "auc"),
    ]
    for row in rows:
        # the old table's δ (independent runs) is below what the two-level test finds
        assert row["two_level"][3][0] > row["independent"][0]
        assert row["two_level"][3][1] > row["two_level"][3][0]  # Holm's α/4 needs more
        assert 0 <= row["false_ahead"][3] <= 1
    with pytest.raises(PvedError, match="not split evenly"):
        power_rows(pairs, 45, (4,), ["pved-prior"])
    with pytest.raises(PvedError, match="not a shaped method"):
        pilot(pairs, "reacher", "ppo", "auc")


def test_power_verb(capsys: pytest.CaptureFixture[str]) -> None:
    tiny = ["--datasets", 5, "--reps", 100]
    code, out, _ = run_cli(
        capsys, "power", AUC_BAR, "--methods", "pved-prior", "--runs", 15, "--sources", 3, *tiny
    )
    assert (
        code == 0
        and "| reacher (success_rate) | pved-prior | area | 0.432 / 0.083 / 0.415 |" in out
    )
    assert "δ, 3 sources × 5 seeds" in out
    code, _, err = run_cli(capsys, "power", AUC_BAR, "--sources", 4, *tiny)
    assert code != 0 and "--sources" in err
