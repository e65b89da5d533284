"""`pved archive`: a protocol's finished runs saved small enough to commit, and restored
on another machine as done.

One Reacher smoke protocol (pved, ppo) gets its pairs, bank, seed-0 model and two
transfer runs (one PVED tuning run, one PPO run) made by the plan's own jobs; the
archive must keep what later stages and the summaries read and nothing bulky, and a
protocol restored from it must take those runs as done."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from helpers import reacher_smoke_protocol, run_cli
from pved import __version__
from pved.analysis.curves import read_eval_points
from pved.errors import PvedError
from pved.experiments.stages import transfer
from pved.experiments.transfer_spec import transfer_spec
from pved.protocol.archive import SUMMARY_FILE, restore_archive, save_archive, save_summary
from pved.protocol.plan import PLAN_FILE, ProtocolPlan, finished_results
from pved.runs import RESTORED_FROM, Run, atomic_write_json


def _protocol_with_two_runs(out: Path) -> Path:
    out = reacher_smoke_protocol(out)
    plan = ProtocolPlan.load(out)
    jobs = {j.key: j for j in plan.expand(finished_results(plan))}
    tuning = next(k for k in jobs if "/transfer/pved-beta" in k)
    baseline = next(k for k in jobs if "/transfer/ppo/" in k)
    for key in (tuning, baseline):
        jobs[key].fn(**jobs[key].kwargs)
    return out


@pytest.fixture(scope="module")
def protocol(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _protocol_with_two_runs(tmp_path_factory.mktemp("proto"))


def _transfer_kwargs(out: Path) -> dict[str, dict[str, object]]:
    plan = ProtocolPlan.load(out)
    return {
        j.key: {k: v for k, v in j.kwargs.items() if k != "progress"}
        for j in plan.expand(finished_results(plan))
        if j.fn is transfer
    }


def _restore_by_cli(
    capsys: pytest.CaptureFixture[str], source: Path, protocol: Path, counts: str
) -> dict[str, object]:
    """`pved archive restore` from ``source`` into ``protocol``, which must print
    ``counts``; the finished results the protocol then reads."""
    code, out, err = run_cli(capsys, "archive", "restore", "--archive", source,
                          "--protocol", protocol)  # fmt: skip
    assert code == 0, err
    assert out.strip().endswith(counts)
    return finished_results(ProtocolPlan.load(protocol))


@pytest.mark.slow
def test_an_archive_keeps_what_later_stages_read_and_restores_as_done(
    protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    archive = tmp_path / "archive"
    code, out, err = run_cli(capsys, "archive", "save", "--protocol", protocol,
                             "--archive", archive)  # fmt: skip
    assert code == 0, err
    assert out.strip().endswith("3 written, 0 unchanged")  # model, tuning run, PPO run
    files = {str(p.relative_to(archive)) for p in archive.rglob("*") if p.is_file()}
    assert PLAN_FILE in files
    assert "runs/reacher/model/pved/seed0/model.pt" in files
    # nothing bulky or half-made: no dataset, bank, checkpoint or TensorBoard file
    assert not any(
        f.endswith((".npz", ".tfevents")) or "checkpoints" in f or "tfevents" in f for f in files
    )
    pved_runs = [f for f in files if "/transfer/pved-beta" in f]
    ppo_runs = [f for f in files if "/transfer/ppo/" in f]
    assert any(f.endswith("/policy.pt") for f in pved_runs)  # the subspaces report reads it
    assert not any(f.endswith("/policy.pt") for f in ppo_runs)
    # the curves are kept whole, the PPO loss rows are not
    source_runs = protocol / "runs"
    for rel in (f for f in files if "/transfer/" in f and f.endswith("metrics.jsonl")):
        kept = (archive / rel).read_text().splitlines()
        made = (source_runs / Path(rel).relative_to("runs")).read_text().splitlines()
        assert kept == [line for line in made if '"eval/' in line] and len(kept) < len(made)

    # saving again changes nothing
    before = {p: p.stat().st_mtime_ns for p in archive.rglob("*") if p.is_file()}
    assert save_archive(protocol, archive) == {"written": 0, "unchanged": 3}
    assert before == {p: p.stat().st_mtime_ns for p in archive.rglob("*") if p.is_file()}

    # another machine: restored, the three runs are finished; the pairs and bank are not
    elsewhere = tmp_path / "elsewhere"
    restored = _restore_by_cli(capsys, archive, elsewhere, "3 restored, 0 exists")
    original = finished_results(ProtocolPlan.load(protocol))
    assert set(restored) == set(original) - {"reacher/pairs", "reacher/bank/src0"}
    plan = ProtocolPlan.load(elsewhere)
    jobs = {j.key: j for j in plan.expand(restored)}
    # the protocol there rebuilds the bank, bit for bit, so the restored runs stay done
    jobs["reacher/bank/src0"].fn(**jobs["reacher/bank/src0"].kwargs)
    for key, kwargs in _transfer_kwargs(elsewhere).items():
        if key not in restored:
            continue
        spec = transfer_spec(**kwargs)
        assert Run(spec.run_dir, spec.config).is_done(), key
        result = json.loads((spec.run_dir / "result.json").read_text())
        if "/transfer/pved-beta" in key:
            assert Path(result["policy"]) == spec.run_dir / "policy.pt"
        else:  # its policy stayed behind: no path to another machine's disk
            assert "policy" not in result
    # restoring again keeps what is there
    assert restore_archive(archive, elsewhere) == {"restored": 0, "exists": 3}


@pytest.mark.slow
def test_a_summary_restores_the_transfer_runs_and_the_protocol_remakes_the_rest(
    protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a machine that lost the protocol directory but kept the repository's summary (made
    # here, not copied: a model names its dataset's path, part of the runs' config hashes)
    lost = _protocol_with_two_runs(tmp_path / "lost")
    made_runs = tmp_path / "made-runs"
    shutil.copytree(lost / "runs", made_runs)
    summary = tmp_path / "summary"
    code, out, err = run_cli(capsys, "archive", "summary", "--protocol", lost,
                          "--archive", summary)  # fmt: skip
    assert code == 0, err
    assert out.strip().endswith("2 runs, 1 written")  # the tuning run and the PPO run
    text = (summary / SUMMARY_FILE).read_text()
    assert save_summary(lost, summary) == {"runs": 2, "written": 0}
    assert (summary / SUMMARY_FILE).read_text() == text
    runs = json.loads(text)
    assert list(runs) == sorted(runs) and all("/transfer/" in rel for rel in runs)
    shutil.rmtree(lost)

    restored = _restore_by_cli(capsys, summary, lost, "2 restored, 0 exists")
    original = finished_results(ProtocolPlan.load(protocol))
    assert set(restored) == {key for key in original if "/transfer/" in key}
    for rel in runs:  # the learning curves read back as they were made
        made = read_eval_points(made_runs / rel / "metrics.jsonl", "eval/return_mean")
        back = read_eval_points(lost / "runs" / rel / "metrics.jsonl", "eval/return_mean")
        assert [list(a) for a in made] == [list(b) for b in back] and len(made[0]) > 1
    # the plan there remakes its pairs, bank and model bit for bit: the runs stay done
    plan = ProtocolPlan.load(lost)
    jobs = {j.key: j for j in plan.expand(restored)}
    for key in ("reacher/pairs", "reacher/bank/src0", "reacher/model/pved/init0"):
        jobs[key].fn(**jobs[key].kwargs)
    for key, kwargs in _transfer_kwargs(lost).items():
        if key in restored:
            spec = transfer_spec(**kwargs)
            assert Run(spec.run_dir, spec.config).is_done(), key
            result = json.loads((spec.run_dir / "result.json").read_text())
            assert "policy" not in result and result[RESTORED_FROM] == str(summary)
    # summarised again there, the record does not say where this machine got it from
    save_summary(lost, tmp_path / "again-summary")
    assert RESTORED_FROM not in (tmp_path / "again-summary" / SUMMARY_FILE).read_text()
    # archived again there: the restored PVED run comes without a policy, as it was
    # restored, and the archive restores it as done on a third machine
    again = tmp_path / "again"
    assert save_archive(lost, again)["written"] == 3  # the model and the two runs
    tuning = next(rel for rel in runs if "/transfer/pved-beta" in rel)
    assert not (again / "runs" / tuning / "policy.pt").exists()
    third = _restore_by_cli(capsys, again, tmp_path / "third", "3 restored, 0 exists")
    assert set(restored) <= set(third)
    # a run whose result names a policy that is gone is damaged, not slimmed
    result_file = lost / "runs" / tuning / "result.json"
    named = {**json.loads(result_file.read_text()), "policy": str(result_file.parent / "policy.pt")}
    atomic_write_json(result_file, named)
    with pytest.raises(PvedError, match="cannot be archived"):
        save_archive(lost, tmp_path / "damaged")

    # an archive and its summary together: the archived run, with its policy, wins
    both = tmp_path / "both"
    save_archive(protocol, both)
    save_summary(protocol, both)
    assert restore_archive(both, tmp_path / "p") == {"restored": 3, "exists": 0}
    assert (tmp_path / "p/runs" / tuning / "policy.pt").is_file()


@pytest.mark.slow
def test_archive_bad_input_is_one_line(
    protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    archive = tmp_path / "archive"
    save_archive(protocol, archive)
    # not an archive
    code, _, err = run_cli(capsys, "archive", "restore", "--archive", tmp_path,
                        "--protocol", tmp_path / "p")  # fmt: skip
    assert code == 2 and "not a protocol archive" in err and err.count("\n") == 1
    # a protocol directory of another plan
    other = tmp_path / "other"
    plan = ProtocolPlan(["reacher"], ["ppo"], "smoke", other)
    atomic_write_json(other / PLAN_FILE, {**plan.describe(), "pved_version": __version__})
    code, _, err = run_cli(capsys, "archive", "restore", "--archive", archive, "--protocol", other)
    assert code == 2 and "another protocol" in err and err.count("\n") == 1
    # an archived run whose result is not its config's, and one without its model
    model_dir = archive / "runs/reacher/model/pved/seed0"
    result = json.loads((model_dir / "result.json").read_text())
    atomic_write_json(model_dir / "result.json", {**result, "config_hash": "0" * 16})
    with pytest.raises(PvedError, match="disagree"):
        restore_archive(archive, tmp_path / "p2")
    atomic_write_json(model_dir / "result.json", result)
    (model_dir / "model.pt").unlink()
    with pytest.raises(PvedError, match=r"lacks its model\.pt"):
        restore_archive(archive, tmp_path / "p3")
    # checked before anything is copied: a bad archive restores nothing
    assert not (tmp_path / "p2").exists() and not (tmp_path / "p3").exists()

    # a summary whose run is not a transfer run's, is of another pair, or has lost its
    # config; a summary that is not JSON
    summary = tmp_path / "summary"
    save_summary(protocol, summary)
    runs = json.loads((summary / SUMMARY_FILE).read_text())
    rel, entry = next(iter(runs.items()))
    for bad, message in (
        ({"../../outside": entry}, "not a transfer run's path"),
        ({rel.replace("reacher/", "walker-hopper/"): entry}, "is not of this plan"),
        ({rel: {**entry, "config": None}}, "lacks its result, config or curve"),
        ({rel: {**entry, "result": {**entry["result"], "config_hash": "0"}}}, "disagree"),
    ):
        atomic_write_json(summary / SUMMARY_FILE, bad)
        code, _, err = run_cli(capsys, "archive", "restore", "--archive", summary,
                            "--protocol", tmp_path / "p4")  # fmt: skip
        assert code == 2 and message in err and err.count("\n") == 1, err
    (summary / SUMMARY_FILE).write_text("{not json")
    with pytest.raises(PvedError, match="is not readable"):
        restore_archive(summary, tmp_path / "p4")
    assert not (tmp_path / "p4").exists()


@pytest.mark.slow
def test_a_published_protocol_comes_back_finished(
    protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # `make publish` put the finished protocol's summary beside its committed record; a
    # machine without the runs gets them back with it, so `pved claims` reads the runs
    # (curves and all), not the published summary alone
    published = tmp_path / "published"
    save_summary(protocol, published)
    plan = ProtocolPlan.load(protocol)
    summary = {"budget": plan.budget.name, "pairs": {"reacher": {}}, "failed": []}
    atomic_write_json(published / "summary.json", summary)
    atomic_write_json(published / "selection.json", {"reacher": {}})
    (published / "summary.md").write_text("# Protocol summary\n")
    back = tmp_path / "back"
    _restore_by_cli(capsys, published, back, "2 restored, 0 exists, 3 summary files")
    for name in ("summary.json", "selection.json", "summary.md"):
        assert (back / name).read_bytes() == (published / name).read_bytes()
    # restored again: the runs and files there are kept
    (back / "summary.md").write_text("edited here\n")
    _restore_by_cli(capsys, published, back, "0 restored, 2 exists")
    assert (back / "summary.md").read_text() == "edited here\n"
    # a record without a published summary restores runs only
    record = tmp_path / "record"
    save_summary(protocol, record)
    _restore_by_cli(capsys, record, tmp_path / "runs-only", "2 restored, 0 exists")
    assert not (tmp_path / "runs-only" / "summary.json").exists()
    # a summary of another protocol is refused before anything is restored
    atomic_write_json(published / "summary.json", {**summary, "pairs": {"walker-hopper": {}}})
    with pytest.raises(PvedError, match="summarises another protocol"):
        restore_archive(published, tmp_path / "elsewhere")
    assert not (tmp_path / "elsewhere").exists()
    (published / "summary.json").write_text("{not json")
    with pytest.raises(PvedError, match="is not a protocol summary"):
        restore_archive(published, tmp_path / "elsewhere")


def test_the_summary_says_when_a_source_fails_its_own_task(tmp_path: Path) -> None:
    from pved.protocol.driver import summarize

    out = reacher_smoke_protocol(tmp_path / "proto")
    banked = summarize(out)["pairs"]["reacher"]["source_success"]
    bank_result = out / "runs/reacher/bank/Reacher3-Push/seed0/result.json"
    assert banked == {"0": json.loads(bank_result.read_text())["success_rate"]}
    # a source whose bank succeeds less than the bar is named as one that fails its own task
    for rate, said in ((0.4, "0: 0.40 (fails its own task)."), (0.6, "0: 0.60.")):
        atomic_write_json(
            bank_result, {**json.loads(bank_result.read_text()), "success_rate": rate}
        )
        summarize(out)
        assert f"(their banks): {said}" in (out / "summary.md").read_text()
