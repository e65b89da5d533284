"""`pved analyze source-reading` on a hand-made protocol directory whose numbers are known."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

BETA = 0.01


def _run_dir(root: Path, key: str, shaping: list[float], env: list[float]) -> None:
    """A run directory whose metrics.jsonl has evaluation rows and these rollout rows."""
    run = root / "runs" / key
    run.mkdir(parents=True)
    rows = [{"step": 0, "eval/x_position_mean": 0.0}]
    rows += [
        {"step": 100 * (i + 1), "rollout/reward_shaping": s, "rollout/env_reward": e}
        for i, (s, e) in enumerate(zip(shaping, env, strict=True))
    ]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def _protocol(root: Path) -> None:
    """Method `pved` at β 0.01, two evaluation runs on each of sources 0 and 1; 20 rollout
    rows a run, so the last tenth is its last two."""
    runs = []
    for source, (x_a, x_b) in enumerate([(1.0, 3.0), (10.0, 20.0)]):
        for seed, x in ((20000, x_a), (40000, x_b)):
            key = f"ant/transfer/pved-beta0.01-init0-src{source}/seed{seed}"
            # early rows far off; the last two: term -0.01*(2+source) and -0.01*(4+source)
            # against env reward 1 and 3, so D averages 3+source and the share is
            # mean term / mean env = 0.01*(3+source) / 2
            shaping = [-9.0] * 18 + [-BETA * (2 + source), -BETA * (4 + source)]
            env = [5.0] * 18 + [1.0, 3.0]
            _run_dir(root, key, shaping, env)
            runs.append({"key": key, "seed": seed, "source_policy": source, "x_position_mean": x})
    summary = {
        "pairs": {
            "ant": {
                "metric": "x_position_mean",
                "methods": {
                    "pved": {"beta": BETA, "init": 0, "runs": runs},
                    "ppo": {"runs": []},  # no term: left out
                },
            }
        },
        "selection": {
            "ant": {
                "pved": {
                    "candidates": [
                        {"beta": 0.1, "init": 0, "scores": [0.0, 0.0]},
                        {"beta": BETA, "init": 0, "scores": [3.0, 5.0]},
                    ]
                }
            }
        },
    }
    (root / "summary.json").write_text(json.dumps(summary))


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "pved", "analyze", "source-reading", *args],
        capture_output=True,
        text=True,
    )


def test_source_reading_matches_a_hand_computation(tmp_path: Path) -> None:
    _protocol(tmp_path)
    done = _run(str(tmp_path))
    assert done.returncode == 0, done.stderr
    result = json.loads((tmp_path / "subspaces" / "source_reading.json").read_text())
    entry = result["pairs"]["ant"]
    assert set(entry) == {"pved"}
    by_source = entry["pved"]["by_source"]
    for source, final in (("0", 2.0), ("1", 15.0)):
        s = int(source)
        assert by_source[source]["runs"] == 2 and by_source[source]["runs_with_rollouts"] == 2
        assert by_source[source]["final_mean"] == pytest.approx(final)
        assert by_source[source]["d_tail"] == pytest.approx(3 + s)
        assert by_source[source]["term_share_of_env_reward"] == pytest.approx(BETA * (3 + s) / 2)
    check = entry["pved"]["tuning_against_source0_evaluation"]
    # tuning [3, 5] against source 0's evaluation [1, 3]: 5 beats both, 3 beats 1 and
    # ties 3 (half a win)
    assert check["tuning_wins"] == 3.5 and check["pairings"] == 4
    assert check["tuning_mean"] == pytest.approx(4.0)
    assert check["evaluation_mean"] == pytest.approx(2.0)
    assert 0 < check["p_two_sided"] <= 1
    assert "| ant | pved | 0.01 | 2.00 / 15.00 | 3 / 4 |" in done.stdout


def test_source_reading_without_rollout_rows_gives_no_distance(tmp_path: Path) -> None:
    """A run restored from an archive keeps only its evaluation rows."""
    _protocol(tmp_path)
    for metrics in (tmp_path / "runs").rglob("metrics.jsonl"):
        rows = [json.loads(x) for x in metrics.read_text().splitlines()]
        kept = [r for r in rows if "rollout/reward_shaping" not in r]
        metrics.write_text("".join(json.dumps(r) + "\n" for r in kept))
    done = _run(str(tmp_path))
    assert done.returncode == 0, done.stderr
    written = json.loads((tmp_path / "subspaces" / "source_reading.json").read_text())
    entry = written["pairs"]["ant"]["pved"]
    assert entry["by_source"]["0"]["runs_with_rollouts"] == 0
    assert "d_tail" not in entry["by_source"]["0"]
    assert "| – / – |" in done.stdout


@pytest.mark.parametrize(
    "broken", ["no summary", "missing run", "corrupt metrics", "no chosen candidate"]
)
def test_source_reading_refuses_bad_input_in_one_line(tmp_path: Path, broken: str) -> None:
    _protocol(tmp_path)
    if broken == "no summary":
        (tmp_path / "summary.json").unlink()
    elif broken == "missing run":
        shutil.rmtree(tmp_path / "runs" / "ant" / "transfer" / "pved-beta0.01-init0-src1")
    elif broken == "corrupt metrics":
        next((tmp_path / "runs").rglob("metrics.jsonl")).write_text("{not json\n")
    else:
        summary = json.loads((tmp_path / "summary.json").read_text())
        summary["selection"]["ant"]["pved"]["candidates"].pop()
        (tmp_path / "summary.json").write_text(json.dumps(summary))
    done = _run(str(tmp_path))
    assert done.returncode == 2 and done.stderr.startswith("pved: error:")
    assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "subspaces" / "source_reading.json").exists()
