"""``make demo`` (``pved demo``): the Reacher pipeline end to end on a tiny budget, and
its budget checked before any stage runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from helpers import run_cli
from pved.experiments.demo import DemoConfig, run_demo, transfer_verdict


def test_demo_runs_every_stage_into_a_report(tmp_path: Path) -> None:
    cfg = DemoConfig(
        seeds=(20000,),
        pair_episodes=16,
        model_epochs=1,
        bank_episodes=8,
        transfer_steps=2048,
        eval_every=2048,
        eval_episodes=8,
        final_eval_episodes=8,
        jobs=2,
    )
    out = run_demo(tmp_path / "runs", tmp_path / "report", cfg)
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [(r["method"], r["seeds"], r["steps"]) for r in rows] == [
        ("pved-align", [20000], 2048),
        ("pved", [20000], 2048),
        ("ppo", [20000], 2048),
    ]
    assert (out / "curves_success_rate.png").stat().st_size > 0
    assert json.loads((out / "demo_config.json").read_text())["transfer_steps"] == 2048
    for method in cfg.methods:
        run = tmp_path / "runs/reacher/transfer" / method / "seed20000"
        assert json.loads((run / "result.json").read_text())["steps"] == 2048
    # pved-align ran at the β the demo names for it, pved at the pair's default
    configs = {
        m: json.loads((tmp_path / f"runs/reacher/transfer/{m}/seed20000/config.json").read_text())
        for m in ("pved-align", "pved")
    }
    assert configs["pved-align"]["config"]["beta"] == dict(cfg.betas)["pved-align"] == 1.0
    assert configs["pved"]["config"]["beta"] != 1.0
    # it ends by saying, for each shaped method, whether the transfer shows
    text = (out / "results.md").read_text()
    comparisons = json.loads((out / "comparisons.json").read_text())
    assert list(comparisons) == ["pved-align", "pved"]
    assert "## Does the transfer show?" in text
    for method, comparison in comparisons.items():
        assert f"### {method} against ppo" in text and f"{method} − ppo" in text
        assert transfer_verdict(comparison) in text
    assert text.rstrip().endswith(transfer_verdict(comparisons["pved"]))


def _comparison(final: tuple[float, float], early: tuple[float, float]) -> dict:
    def diff(ci: tuple[float, float]) -> dict:
        return {"diff": sum(ci) / 2, "diff_ci": list(ci), "p": 0.5}

    return {"groups": {"pved": {}, "ppo": {}}, "diff": {"final": diff(final), "early": diff(early)}}


@pytest.mark.parametrize(
    ("final", "early", "start"),
    [
        ((0.01, 0.2), (-0.1, 0.1), "Transfer shows at this budget: pved is ahead of ppo"),
        ((-0.1, 0.1), (0.02, 0.3), "Transfer shows at this budget"),
        ((-0.3, -0.01), (-0.1, 0.1), "Transfer does not pay here: pved is behind ppo"),
        ((-0.1, 0.2), (-0.1, 0.1), "Transfer does not show at this budget"),
    ],
)
def test_the_demo_verdict_follows_the_intervals(
    final: tuple[float, float], early: tuple[float, float], start: str
) -> None:
    assert transfer_verdict(_comparison(final, early)).startswith(start)


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--steps", "-1"], "--steps must be an integer >= 1, got -1"),
        (["--jobs", "0"], "--jobs must be an integer >= 1, got 0"),
        (["--seeds", "-5"], "--seeds must be an integer in [0, 4294967295], got -5"),
    ],
)
def test_a_bad_demo_budget_is_refused_before_any_stage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], match: str
) -> None:
    runs = tmp_path / "runs"
    code, _, err = run_cli(capsys, "demo", "--runs", runs, "--out", tmp_path / "out", *argv)
    assert code == 2 and err.strip().count("\n") == 0 and match in err, err
    assert not runs.exists()  # nothing made before the refusal
