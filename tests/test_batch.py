"""`pved batch`: a protocol's transfer runs exported, run elsewhere, packed and imported.

One Reacher protocol at the smoke budget gets its pairs, seed-0 model and bank made
here (the stages a batch does not carry); its runs then go through a batch as they would
to a machine that cannot reach the protocol, and must come back as the protocol's own.
"""

from __future__ import annotations

import json
import shutil
import tarfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers import reacher_smoke_protocol, run_cli
from pved import __version__
from pved.errors import PvedError
from pved.experiments.stages import transfer
from pved.experiments.transfer_spec import transfer_spec
from pved.protocol.batch import (
    BATCH_FILE,
    LOG_FILE,
    export_batch,
    import_batch,
    release_batch,
)
from pved.protocol.plan import PLAN_FILE, ProtocolPlan, finished_results
from pved.runs import Run, atomic_write_json, claim_holder, write_claim


def _jobs_by_key(out: Path) -> dict[str, dict[str, object]]:
    plan = ProtocolPlan.load(out)
    return {j.key: dict(j.kwargs) for j in plan.expand(finished_results(plan))}


@pytest.fixture(scope="module")
def protocol(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return reacher_smoke_protocol(tmp_path_factory.mktemp("proto"))


@pytest.fixture(autouse=True)
def _no_claims_left_behind(protocol: Path) -> Iterator[None]:
    # the protocol is shared by this module's tests: one test's exports must not hold
    # runs back from the next
    yield
    release_batch(protocol)


@pytest.mark.slow
def test_runs_made_in_a_batch_are_the_protocols_own(
    protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    batch = tmp_path / "batch"
    code, out, err = run_cli(capsys, "batch", "export", "--protocol", protocol, "--batch", batch,
                          "--limit", "3")  # fmt: skip
    assert code == 0, err
    exported = json.loads((batch / BATCH_FILE).read_text())
    keys = [j["key"] for j in exported["jobs"]]
    # the tuning runs first, as the protocol orders them
    assert len(keys) == 3 and all("/transfer/pved-beta" in k for k in keys)
    # the inputs travel with the batch, and no path points back at this machine
    assert (batch / "runs/reacher/model/pved/seed0/model.pt").exists()
    assert (batch / "runs/reacher/bank/Reacher3-Push/seed0/bank.npz").exists()
    assert str(protocol) not in (batch / BATCH_FILE).read_text()

    packed = tmp_path / "packed"
    code, out, err = run_cli(capsys, "batch", "run", "--batch", batch, "--workers", "2",
                          "--pack", packed)  # fmt: skip
    assert code == 0, err
    log = json.loads((batch / LOG_FILE).read_text())
    assert [log["jobs"][k]["state"] for k in keys] == ["finished"] * 3
    tars = sorted(packed.glob("runs*.tar.gz"))
    assert tars and (packed / LOG_FILE).exists()
    with tarfile.open(tars[0]) as tar:
        assert not any("model.pt" in n or "bank.npz" in n for n in tar.getnames())

    # a batch directory whose first run is still going: --finished-only leaves it there
    partial = tmp_path / "partial"
    shutil.copytree(batch, partial)
    first = partial / "runs" / exported["jobs"][0]["run_dir"]
    (first / "result.json").unlink()
    (first / "checkpoints").mkdir(exist_ok=True)
    shutil.copy(first / "policy.pt", first / "checkpoints" / "step000000004096.pt")
    elsewhere = tmp_path / "elsewhere"
    shutil.copytree(protocol, elsewhere)
    outcome = import_batch(elsewhere, [partial], finished_only=True)
    assert outcome["empty"] == keys[:1] and sorted(outcome["finished"]) == sorted(keys[1:])
    outcome = import_batch(elsewhere, [partial])
    assert outcome["partial"] == keys[:1]
    moved = elsewhere / "runs" / exported["jobs"][0]["run_dir"]
    assert not (moved / "result.json").exists() and (moved / "checkpoints").is_dir()

    code, out, err = run_cli(capsys, "batch", "import", "--protocol", protocol, *tars)
    assert code == 0, err
    assert out.startswith("3 finished, 0 partial, 0 exists")
    jobs = _jobs_by_key(protocol)
    for key in keys:
        spec = transfer_spec(**{k: v for k, v in jobs[key].items() if k != "progress"})
        # done under the config the protocol gives the run here: it will not be redone
        assert Run(spec.run_dir, spec.config).is_done()
        result = json.loads((spec.run_dir / "result.json").read_text())
        assert Path(result["policy"]) == spec.run_dir / "policy.pt"
        assert transfer(**jobs[key]) == result  # returns at once: nothing retrained
    assert set(keys) <= set(finished_results(ProtocolPlan.load(protocol)))

    # a second import keeps what is here, and the next export leaves the imported out
    results = sorted((protocol / "runs/reacher/transfer").glob("*/seed*/result.json"))
    before = {p: p.stat().st_mtime_ns for p in results}
    assert sorted(import_batch(protocol, tars)["exists"]) == sorted(keys)
    assert before == {p: p.stat().st_mtime_ns for p in results}
    again = export_batch(protocol, tmp_path / "batch2", claim_minutes=0)
    assert again and not set(again) & set(keys)
    # --skip leaves the front of that order to a protocol running here
    assert export_batch(protocol, tmp_path / "batch3", skip=1, limit=1) == again[1:2]

    # a run directory under another run's name is refused on its config hash
    mismatch_key = next(k for k in again if "/transfer/pved-beta" in k)
    wrong = json.loads((tmp_path / "batch2" / BATCH_FILE).read_text())
    rel = next(j["run_dir"] for j in wrong["jobs"] if j["key"] == mismatch_key)
    done_dir = transfer_spec(**{k: v for k, v in jobs[keys[0]].items() if k != "progress"}).run_dir
    shutil.copytree(done_dir, tmp_path / "batch2" / "runs" / rel)
    outcome = import_batch(protocol, [tmp_path / "batch2"])
    assert outcome["mismatch"] == [mismatch_key] and outcome["finished"] == []
    assert not (protocol / "runs" / rel).exists()


@pytest.mark.slow
def test_a_batch_stops_at_its_deadline(
    protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    batch = tmp_path / "batch"
    keys = export_batch(protocol, batch, limit=2)
    # a first run far too long to finish, so the deadline (not a fast machine) ends it
    data = json.loads((batch / BATCH_FILE).read_text())
    data["jobs"][0]["kwargs"]["steps"] = 10**9
    (batch / BATCH_FILE).write_text(json.dumps(data))
    code, _, err = run_cli(capsys, "batch", "run", "--batch", batch, "--workers", "1",
                          "--deadline-s", "1")  # fmt: skip
    assert code == 0, err
    log = json.loads((batch / LOG_FILE).read_text())
    first, second = (log["jobs"][k] for k in keys)
    assert first["killed_at_deadline"] is True and second["state"] == "not started"
    # how far it got in a second depends on the machine: nothing, or a checkpoint
    assert first["state"] in ("nothing", "partial")
    assert log["elapsed_s"] < 30
    # either way nothing comes in as finished; a checkpoint of a run whose config
    # differs from the protocol's (its steps were changed above) is refused on its hash
    outcome = import_batch(protocol, [batch])
    assert outcome["finished"] == outcome["partial"] == []
    assert outcome["mismatch"] == ([keys[0]] if first["state"] == "partial" else [])
    code, _, err = run_cli(capsys, "batch", "pack", "--batch", batch, "--to", tmp_path / "p")
    packed = list((tmp_path / "p").glob("*.tar.gz"))
    # a run cut before its first checkpoint has nothing to bring back, so nothing is packed
    assert code == 0 and bool(packed) == (first["state"] == "partial")


@pytest.mark.slow
def test_a_failed_run_is_reported_and_the_rest_go_on(
    protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    batch = tmp_path / "batch"
    keys = export_batch(protocol, batch, limit=2)
    data = json.loads((batch / BATCH_FILE).read_text())
    data["jobs"][0]["kwargs"]["method"] = "no-such-model"
    (batch / BATCH_FILE).write_text(json.dumps(data))
    code, _, err = run_cli(capsys, "batch", "run", "--batch", batch, "--workers", "2",
                        "--pack", tmp_path / "p")  # fmt: skip
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"1 of 2 runs failed; {keys[0]}" in err and "no-such-model" in err
    log = json.loads((batch / LOG_FILE).read_text())["jobs"]
    assert "no-such-model" in log[keys[0]]["error"] and log[keys[1]]["state"] == "finished"
    assert list((tmp_path / "p").glob("runs*.tar.gz"))  # what finished is packed anyway


@pytest.mark.slow
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["import", "--protocol", "{proto}", "{junk}"], "is not a readable tar file"),
        (["import", "--protocol", "{proto}", "{evil}"], "not a batch's run"),
        (["run", "--batch", "{proto}"], "is not a batch directory"),
        (["export", "--protocol", "{tmp}", "--batch", "{tmp}/b"], "is not a protocol directory"),
        (["export", "--protocol", "{proto}", "--batch", "{proto}"], "exists"),
        (
            ["export", "--protocol", "{proto}", "--batch", "{tmp}/b", "--claim-minutes", "-1"],
            "--claim-minutes must be a finite number >= 0",
        ),
        (
            ["export", "--protocol", "{proto}", "--batch", "{tmp}/b", "--max-input-mib", "0"],
            "--max-input-mib must be a finite number > 0",
        ),
        (["release", "--protocol", "{tmp}"], "is not a protocol directory"),
    ],
)
def test_batch_bad_input_is_one_line(
    protocol: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    message: str,
) -> None:
    junk = tmp_path / "junk.tar.gz"
    junk.write_bytes(b"not a tar file at all")
    evil = tmp_path / "evil.tar.gz"
    (tmp_path / "x").write_text("x")
    with tarfile.open(evil, "w:gz") as tar:
        tar.add(tmp_path / "x", arcname="../outside")
    paths = {"proto": protocol, "junk": junk, "evil": evil, "tmp": tmp_path}
    code, _, err = run_cli(capsys, "batch", *(a.format(**paths) for a in argv))
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path.parent / "outside").exists()


@pytest.mark.slow
def test_one_batch_serves_several_protocols(protocol: Path, tmp_path: Path) -> None:
    # a second pair whose PPO runs can start at once (no model, no bank)
    walker = tmp_path / "walker"
    plan = ProtocolPlan(["walker-hopper"], ["ppo"], "smoke", walker)
    atomic_write_json(walker / PLAN_FILE, {**plan.describe(), "pved_version": __version__})
    keys = export_batch([protocol, walker], tmp_path / "both", limit=2, claim_minutes=0)
    # two of each, alternating, each protocol's in its own order
    assert [k.split("/")[0] for k in keys] == ["reacher", "walker-hopper"] * 2
    for source, name, part in ((protocol, "reacher-only", 0), (walker, "walker-only", 1)):
        assert keys[part::2] == export_batch(source, tmp_path / name, limit=2, claim_minutes=0)
    exported = json.loads((tmp_path / "both" / BATCH_FILE).read_text())
    assert len(exported["protocols"]) == 2
    assert (tmp_path / "both/runs/reacher/model/pved/seed0/model.pt").exists()
    # each protocol imports its own runs and counts the other's apart, not as unknown
    other = tmp_path / "both/runs" / exported["jobs"][1]["run_dir"]
    other.mkdir(parents=True)
    (other / "config.json").write_text("{}")
    outcome = import_batch(protocol, [tmp_path / "both"])
    assert outcome["other"] == [exported["jobs"][1]["run_dir"]] and not outcome["unknown"]
    # two protocols of one pair would share run names: refused, nothing written
    again = tmp_path / "again"
    plan = ProtocolPlan(["walker-hopper"], ["ppo"], "smoke", again)
    atomic_write_json(again / PLAN_FILE, {**plan.describe(), "pved_version": __version__})
    with pytest.raises(PvedError, match="same name"):
        export_batch([walker, again], tmp_path / "clash")
    assert not (tmp_path / "clash").exists()


@pytest.mark.slow
def test_export_passes_over_runs_whose_inputs_do_not_fit(protocol: Path, tmp_path: Path) -> None:
    # a transport with a size limit (the device machine's 64 MiB) takes the runs whose
    # models and banks fit; PPO's runs need none
    every = export_batch(protocol, tmp_path / "all", claim_minutes=0)
    carried = json.loads((tmp_path / "all" / BATCH_FILE).read_text())["inputs"]
    assert len(carried) == 2  # the seed-0 model and bank
    sizes = sum((tmp_path / "all" / "runs" / rel).stat().st_size for rel in carried)
    ppo = [k for k in every if "/transfer/ppo/" in k]
    assert ppo and len(ppo) < len(every)

    small = export_batch(protocol, tmp_path / "small", limit=2, max_input_bytes=sizes - 1)
    assert small == ppo[:2]
    assert json.loads((tmp_path / "small" / BATCH_FILE).read_text())["inputs"] == {}
    # the runs passed over are not claimed: the next export, with room, takes them
    fits = export_batch(protocol, tmp_path / "fits", max_input_bytes=sizes, claim_minutes=0)
    assert fits == [k for k in every if k not in small]


@pytest.mark.slow
def test_exported_runs_are_claimed_until_sent_back_or_released(
    protocol: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = ProtocolPlan.load(protocol)
    run_dirs = {
        j.key: j.run_dir for j in plan.expand(finished_results(plan)) if j.run_dir is not None
    }
    first = export_batch(protocol, tmp_path / "b1", limit=2)
    holder = str((tmp_path / "b1").resolve())
    assert [claim_holder(run_dirs[k]) for k in first] == [holder, holder]
    # the next export leaves them to the first batch; without a claim nothing is held
    second = export_batch(protocol, tmp_path / "b2", limit=2, claim_minutes=0)
    assert second and not set(first) & set(second)
    assert all(claim_holder(run_dirs[k]) is None for k in second)
    # an expired claim holds nothing back
    write_claim(run_dirs[second[0]], "gone", time.time() - 1)
    assert export_batch(protocol, tmp_path / "b3", limit=1, claim_minutes=0) == second[:1]

    # the other machine started the first run only, and it made nothing: importing it
    # ends that claim, the run it never started stays claimed
    exported = json.loads((tmp_path / "b1" / BATCH_FILE).read_text())
    started = tmp_path / "b1" / "runs" / exported["jobs"][0]["run_dir"]
    started.mkdir(parents=True)
    (started / "config.json").write_text("{}")
    assert import_batch(protocol, [tmp_path / "b1"])["empty"] == first[:1]
    assert claim_holder(run_dirs[first[0]]) is None
    assert claim_holder(run_dirs[first[1]]) == holder
    # another batch's release leaves it; its own ends it
    code, out, err = run_cli(capsys, "batch", "release", "--protocol", protocol,
                          "--batch", tmp_path / "b2")  # fmt: skip
    assert code == 0 and out.strip() == "0 runs released", err
    code, out, err = run_cli(capsys, "batch", "release", "--protocol", protocol,
                          "--batch", tmp_path / "b1")  # fmt: skip
    assert code == 0 and out.strip() == "1 runs released", err
    assert claim_holder(run_dirs[first[1]]) is None
