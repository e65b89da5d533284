"""Which code made the runs a record compares (pved.provenance): a protocol's summary
counts its runs' numeric fingerprints, and ``pved compare`` and ``pved claims`` warn when
two compared groups were not all made under one known fingerprint."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest

from helpers import run_cli
from pved import __version__
from pved.analysis import curves
from pved.analysis.claims import claims_markdown, judge_claims
from pved.analysis.compare import compare_runs, format_comparison
from pved.protocol.driver import summarize
from pved.protocol.plan import PLAN_FILE, ProtocolPlan
from pved.provenance import UNKNOWN
from pved.runs import atomic_write_json
from test_claims import flat, make_protocol
from test_compare import make_run

CURVE = [0.0, 0.2, 0.4, 0.6, 0.8]


def _with_fingerprint(run_dir: Path, fingerprint: str | None) -> Path:
    """The run's config.json as a run made under ``fingerprint`` writes it (None: a run
    made before fingerprints)."""
    record = json.loads((run_dir / "config.json").read_text())
    if fingerprint is not None:
        record["fingerprint"] = fingerprint
    (run_dir / "config.json").write_text(json.dumps(record))
    return run_dir


def test_a_protocol_summary_counts_the_fingerprints_of_its_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # fewer resamples: the intervals are not what is tested here
    quick = functools.partial(curves.bootstrap_summary, reps=50)
    monkeypatch.setattr(curves, "bootstrap_summary", quick)
    out = tmp_path / "p"
    plan = ProtocolPlan(["reacher"], ["ppo", "oracle"], "smoke", out)
    atomic_write_json(out / PLAN_FILE, {**plan.describe(), "pved_version": __version__})
    made_under = {"ppo": ["f1", "f1"], "oracle": ["f1", None]}
    plan.expand({})
    for method, fingerprints in made_under.items():
        for i, (job, fp) in enumerate(
            zip(plan.evaluation_jobs("reacher", method), fingerprints, strict=True)
        ):
            assert job.run_dir is not None
            job.run_dir.mkdir(parents=True)
            record = {"config": {}, "config_hash": f"h{i}", **({"fingerprint": fp} if fp else {})}
            atomic_write_json(job.run_dir / "config.json", record)
            rows = [{"step": s, "eval/success_rate": 0.5} for s in (4096, 8192)]
            (job.run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
            result = {"final/success_rate": 0.5, "final/return_mean": -1.0, "config_hash": f"h{i}"}
            atomic_write_json(job.run_dir / "result.json", result)
    summary = summarize(out)
    methods = summary["pairs"]["reacher"]["methods"]
    assert methods["ppo"]["fingerprints"] == {"f1": 2}
    assert methods["oracle"]["fingerprints"] == {"f1": 1, UNKNOWN: 1}
    assert summary["fingerprints"] == {"f1": 3, UNKNOWN: 1}
    assert json.loads((out / "summary.json").read_text())["fingerprints"] == {"f1": 3, UNKNOWN: 1}
    md = (out / "summary.md").read_text()
    assert "Numeric fingerprints the runs were made under: f1 (3 runs), unknown (1 runs)" in md


def test_compare_warns_when_the_groups_were_made_by_other_code(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a = [_with_fingerprint(make_run(tmp_path / "a", s, CURVE, 0.8), "f1") for s in (1, 2)]
    b = [_with_fingerprint(make_run(tmp_path / "b", s, CURVE, 0.6), "f1") for s in (1, 2)]
    same = compare_runs(a, b)
    assert same["fingerprint_warning"] is None and same["groups"]["A"]["fingerprints"] == {"f1": 2}
    assert "Warning" not in format_comparison(same)
    _with_fingerprint(b[1], "f2")
    other = compare_runs(a, b)
    assert other["groups"]["B"]["fingerprints"] == {"f1": 1, "f2": 1}
    assert other["fingerprint_warning"] == (
        "not made under one known numeric fingerprint: f1 (2) against f1 (1), f2 (1)"
    )
    assert "Warning: A and B were not made under one known numeric fingerprint" in (
        format_comparison(other)
    )
    # a run made before fingerprints is unknown: the CLI says so, and its JSON too
    old = make_run(tmp_path / "old", 3, CURVE, 0.6)
    code, out, _ = run_cli(capsys, "compare", "--a", *a, "--b", old, "--json", tmp_path / "c.json")
    assert code == 0 and f"against {UNKNOWN} (1)" in out
    assert f"{UNKNOWN} (1)" in json.loads((tmp_path / "c.json").read_text())["fingerprint_warning"]


def test_claims_warn_on_parts_whose_methods_were_made_by_other_code(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = make_protocol(
        tmp_path / "p",
        {
            "reacher": {"pved": flat(0.8), "ppo": flat(0.3), "gupta2017": flat(0.5)},
            "jaco-fetch": {"pved": flat(0.8), "ppo": flat(0.3)},
        },
    )
    summary = json.loads((root / "summary.json").read_text())
    reacher = summary["pairs"]["reacher"]["methods"]
    reacher["pved"]["fingerprints"] = {"f1": 5}
    reacher["ppo"]["fingerprints"] = {"f1": 5}
    reacher["gupta2017"]["fingerprints"] = {"f2": 5}
    (root / "summary.json").write_text(json.dumps(summary))  # jaco-fetch's: before them
    result = judge_claims([root])
    parts = {(p["pair"], p["part"]): p for c in result["claims"] for p in c["parts"]}
    assert "fingerprint_warning" not in parts[("reacher", "pved beats ppo")]
    assert (
        "f1 (5) against f2 (5)" in parts[("reacher", "pved beats gupta2017")]["fingerprint_warning"]
    )
    assert f"{UNKNOWN} (5)" in parts[("jaco-fetch", "pved beats ppo")]["fingerprint_warning"]
    assert result["fingerprints"]["jaco-fetch"]["pved"] == {UNKNOWN: 5}
    warnings = result["fingerprint_warnings"]
    assert any(w.startswith("reacher: pved and gupta2017 were not made") for w in warnings)
    assert any(w.startswith("jaco-fetch: pved and ppo") for w in warnings)
    assert not any(w.startswith("reacher: pved and ppo") for w in warnings)
    assert "- Warning: reacher: pved and gupta2017" in claims_markdown(result)
    code, out, _ = run_cli(capsys, "claims", root)
    assert code == 0 and "Warning: jaco-fetch: pved and ppo were not made" in out


def test_a_run_resumed_under_another_fingerprint_is_of_neither(tmp_path: Path) -> None:
    from pved.provenance import fingerprint_of_run, run_fingerprint
    from pved.runs import Run

    run = Run(tmp_path / "run", {"c": 1})
    run.start()
    record = json.loads((run.path / "config.json").read_text())
    now = record["fingerprint"]
    assert fingerprint_of_run(run.path) == now  # started once
    Run(tmp_path / "run", {"c": 1}).start()  # resumed under the same code: still one
    assert fingerprint_of_run(run.path) == now
    # resumed under the same code after a start under another, or before fingerprints
    again = json.loads((run.path / "config.json").read_text())
    again["previous_starts"][0]["fingerprint"] = "0ld0ld0ld0ld"
    assert run_fingerprint(again) == f"mixed: 0ld0ld0ld0ld + {now}"
    again["previous_starts"][0]["fingerprint"] = None
    assert run_fingerprint(again) == f"mixed: {UNKNOWN} + {now}"
