"""Records name no directory of the machine that wrote them (docs/decisions/at-scale.md,
"Paths in records are relative"): the committed ones under ``docs/`` and the package's
data, and what the protocol's writers put in a fresh summary, selection, plan and run
record."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pved import __version__
from pved.config import get_budget
from pved.protocol.archive import SUMMARY_FILE, save_summary
from pved.protocol.driver import summarize
from pved.protocol.plan import PLAN_FILE, ProtocolPlan, fixed_selections
from pved.record_paths import record_path, resolve_record_path
from pved.runs import atomic_write_json

ROOT = Path(__file__).resolve().parents[1]
TEXT = ("*.md", "*.json", "*.jsonl", "*.toml", "*.csv", "*.txt", "*.html", "*.svg", "*.yml")
#: an absolute path (two parts at least: ``/a/b``) where a path starts (after a space,
#: quote, bracket, ``=`` or ``,``); the kernel's ``/proc``, ``/sys`` and ``/dev`` are the
#: same on every machine, and ``~/...`` or ``$TMPDIR/...`` name no machine's directory
ABSOLUTE = re.compile(
    r"(?:^|(?<=[\s\"'`(\[=,]))/(?!(?:proc|sys|dev)/)[\w.+~-]+/[^\s\"'`)\],]*", re.MULTILINE
)


def _absolute_paths(files: list[Path]) -> list[str]:
    found = []
    for path in files:
        text = path.read_text(errors="replace")
        for match in ABSOLUTE.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            found.append(f"{path.relative_to(ROOT)}:{line}: {match.group()[:80]}")
    return found


def test_no_absolute_path_in_the_committed_records_or_the_package_data() -> None:
    docs = [p for pattern in TEXT for p in (ROOT / "docs").rglob(pattern)]
    package = [p for pattern in TEXT for p in (ROOT / "src" / "pved").rglob(pattern)]
    assert len(docs) > 100 and any(p.suffix == ".json" for p in package)
    found = _absolute_paths(docs + package)
    assert not found, f"{len(found)} absolute paths, e.g.\n" + "\n".join(found[:10])


def test_the_pattern_finds_the_forms_records_had(tmp_path: Path) -> None:
    hits = [
        '"result": "/work/main/reports/reacher-quick/runs/r/result.json"',
        "- made in /root/x/reports/reacher-quick-align (quick budget",
        "(`/root/pved-runs/queue.sh`)",
        "--runs /tmp/ha --pair humanoid-ant",
        "        /home/u/x/pairs.npz",
    ]
    misses = [
        "see https://example.org/a/b and runs/reacher/transfer/ppo/seed2000",
        "reads /proc/cpuinfo; steps/s and a/b/c",
        "a run in ~/pved-runs/late, or --runs $TMPDIR/ha",
    ]
    for text in hits + misses:
        assert bool(ABSOLUTE.search(text)) == (text in hits), text


def test_a_record_path_is_relative_to_its_base_else_to_the_current_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    repo = tmp_path / "repo"
    protocol = repo / "reports" / "p"
    protocol.mkdir(parents=True)
    monkeypatch.chdir(repo)
    run = protocol / "runs" / "reacher" / "transfer" / "ppo" / "seed2000" / "result.json"
    assert record_path(run, protocol) == "runs/reacher/transfer/ppo/seed2000/result.json"
    assert record_path(str(run), "reports/p") == "runs/reacher/transfer/ppo/seed2000/result.json"
    assert record_path(repo / "reports" / "q") == "reports/q"  # another protocol
    assert record_path("reports/q", protocol) == "reports/q"  # given relative: as given
    assert record_path(tmp_path / "elsewhere" / "x", protocol) == "../elsewhere/x"
    # reports/ a link to a larger disk: still named by the link
    (tmp_path / "big").mkdir()
    (repo / "data").symlink_to(tmp_path / "big")
    assert record_path("data/q") == "data/q"
    # read back: relative to the record's base; an older record's absolute path as it is
    assert resolve_record_path("runs/r/result.json", protocol) == protocol / "runs/r/result.json"
    assert resolve_record_path(str(run), tmp_path / "moved") == run


def _screen(where: Path) -> Path:
    """A protocol directory that chose β 0.1 and init 0 for pved on reacher at ``quick``."""
    where.mkdir(parents=True)
    budget = dataclasses.asdict(get_budget("quick"))
    (where / PLAN_FILE).write_text(json.dumps({"budget": budget}))
    selection = {"reacher": {"pved": {"beta": 0.1, "init": 0, "candidates": []}}}
    (where / "selection.json").write_text(json.dumps(selection))
    return where


def _finish_evaluation_runs(plan: ProtocolPlan) -> list[Path]:
    """Every evaluation run of the plan, faked: its config, evaluation rows, and a result
    that names its policy by the absolute path a run writes."""
    run_dirs = []
    plan.expand({})  # the selection made elsewhere: its evaluation runs are known at once
    for method in plan.methods:
        for i, job in enumerate(plan.evaluation_jobs("reacher", method)):
            assert job.run_dir is not None
            job.run_dir.mkdir(parents=True)
            config = {"config": dict(job.required_config or {}), "config_hash": f"h{i}"}
            atomic_write_json(job.run_dir / "config.json", config)
            rows = [{"step": s, "eval/success_rate": 0.1 * i, "eval/return_mean": -1.0}
                    for s in (4096, 8192)]  # fmt: skip
            lines = "".join(json.dumps(r) + "\n" for r in rows)
            (job.run_dir / "metrics.jsonl").write_text(lines)
            result: dict[str, Any] = {
                "final/success_rate": 0.1 * i,
                "final/return_mean": -1.0,
                "config_hash": f"h{i}",
                "policy": str(job.run_dir / "policy.pt"),
            }
            atomic_write_json(job.run_dir / "result.json", result)
            run_dirs.append(job.run_dir)
    return run_dirs


def test_a_fresh_protocol_record_holds_only_relative_paths(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pved.analysis.curves as curves

    def interval(scores: Any, **_: Any) -> dict[str, Any]:  # the paths are judged here, not the CIs
        mean = float(np.mean(scores))
        return {"mean": mean, "mean_ci": [mean, mean], "iqm": mean, "iqm_ci": [mean, mean]}

    monkeypatch.setattr(curves, "bootstrap_summary", interval)
    monkeypatch.setattr(curves, "plot_panels", lambda panels, path: path)  # nor the figures
    monkeypatch.chdir(tmp_path)
    screen = _screen(tmp_path / "reports" / "screen")
    out = tmp_path / "reports" / "p"
    # the screen named by its absolute path, as a plan written before this rule has it
    fixed = fixed_selections(screen, ["reacher"], ["pved", "ppo"], "smoke")
    plan = ProtocolPlan(["reacher"], ["pved", "ppo"], "smoke", out, fixed)
    described = plan.describe()
    described["selection_from"]["reacher"]["pved"]["protocol"] = str(screen)
    atomic_write_json(out / PLAN_FILE, {**described, "pved_version": __version__})
    runs = _finish_evaluation_runs(ProtocolPlan.load(out))
    assert len(runs) == 4  # two evaluation seeds, one source, two methods

    summary = summarize(out)
    save_summary(out, tmp_path / "docs" / "p")
    written = [out / n for n in ("summary.json", "selection.json", "summary.md")]
    written += [tmp_path / "docs" / "p" / n for n in (PLAN_FILE, SUMMARY_FILE)]
    assert not _absolute_paths_of(written)
    results = [r["result"] for m in summary["pairs"]["reacher"]["methods"].values()
               for r in m["runs"]]  # fmt: skip
    assert sorted(results) == sorted(str((r / "result.json").relative_to(out)) for r in runs)
    assert summary["selection"]["reacher"]["pved"]["selected_in"]["protocol"] == "reports/screen"
    assert "- made in reports/screen (quick budget" in (out / "summary.md").read_text()
    record = json.loads((tmp_path / "docs" / "p" / SUMMARY_FILE).read_text())
    assert {e["result"]["policy"] for e in record.values()} == {
        str((r / "policy.pt").relative_to(out)) for r in runs
    }


def _absolute_paths_of(files: list[Path]) -> list[str]:
    return [f"{p.name}: {m.group()}" for p in files for m in ABSOLUTE.finditer(p.read_text())]


def test_a_plan_written_with_absolute_paths_is_the_same_plan_on_restart(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pved.protocol.driver as protocol

    monkeypatch.setattr(protocol, "run_jobs", lambda plan, **kwargs: None)
    monkeypatch.setattr(protocol, "summarize", lambda out, report: {})
    monkeypatch.chdir(tmp_path)
    screen = _screen(tmp_path / "reports" / "screen")
    out = tmp_path / "reports" / "p"
    fixed = fixed_selections("reports/screen", ["reacher"], ["pved", "ppo"], "smoke")
    plan = ProtocolPlan(["reacher"], ["pved", "ppo"], "smoke", out, fixed)
    described = json.loads(json.dumps(plan.describe()))
    assert described["selection_from"]["reacher"]["pved"]["protocol"] == "reports/screen"
    earlier = json.loads(json.dumps(described))
    earlier["selection_from"]["reacher"]["pved"]["protocol"] = str(screen)
    out.mkdir(parents=True)
    atomic_write_json(out / PLAN_FILE, {**earlier, "pved_version": "0.0.9"})
    protocol.run_protocol(["reacher"], budget="smoke", methods=["pved", "ppo"], out=out,
                          selection_from=screen)  # fmt: skip
    plan = json.loads((out / PLAN_FILE).read_text())
    assert plan == {**described, "pved_version": "0.0.9"}  # rewritten relative, kept


def test_a_summary_run_result_is_read_relative_to_its_protocol_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from pved.analysis.run_curves import metrics_file

    key = "reacher/transfer/ppo/seed20000"
    for where in (tmp_path / "reports" / "p", tmp_path):  # the protocol's run, and a decoy
        (where / "runs" / key).mkdir(parents=True)
        (where / "runs" / key / "metrics.jsonl").write_text("{}\n")
    monkeypatch.chdir(tmp_path)  # where `pved transfer` leaves runs/ of its own
    protocol = Path("reports/p")
    run = {"key": "elsewhere", "result": f"runs/{key}/result.json"}
    assert metrics_file(protocol, run) == protocol / "runs" / key / "metrics.jsonl"
    older = {"key": "elsewhere", "result": str(tmp_path / "reports/p/runs" / key / "result.json")}
    assert (
        metrics_file(tmp_path / "moved", older)
        == tmp_path / "reports/p/runs" / key / "metrics.jsonl"
    )
