"""Run-directory contract: config hash, skip-if-done, resume, atomic result."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pved.blas import loaded_kernel, loaded_mkl_branch, loaded_numpy_simd
from pved.errors import PvedError
from pved.provenance import git_dirty, pinned_fingerprint
from pved.runs import (
    Run,
    _read_git_commit,
    atomic_write_json,
    claim_file,
    claim_holder,
    config_hash,
    git_commit,
    last_logged_step,
    release_claim,
    run_path,
    safe_torch_load,
    write_claim,
)


def test_config_hash_ignores_key_order_and_sees_values() -> None:
    assert config_hash({"a": 1, "b": [1, 2]}) == config_hash({"b": [1, 2], "a": 1})
    assert config_hash({"a": 1}) != config_hash({"a": 2})


def test_run_lifecycle_skip_if_done_and_config_change(tmp_path: Path) -> None:
    path = run_path(tmp_path, "reacher", "model", "pved", 3)
    assert path == tmp_path / "reacher" / "model" / "pved" / "seed3"
    run = Run(path, {"lr": 1e-4}, tensorboard=False)
    assert not run.is_done()
    run.start()
    run.log(1, loss=2.0)
    run.log(2, loss=float("nan"))
    assert [r["loss"] for r in run.read_metrics()] == [2.0, None]
    run.save_checkpoint(10, {"w": torch.ones(2), "step": 10})
    run.save_checkpoint(20, {"w": torch.zeros(2), "step": 20})
    run.save_checkpoint(30, {"w": torch.zeros(2), "step": 30})
    assert len(list(run.checkpoint_dir.glob("*.pt"))) == 2  # only the newest kept
    latest = run.latest_checkpoint()
    assert latest is not None and latest["step"] == 30
    run.finish({"score": 1.5})
    assert Run(path, {"lr": 1e-4}).is_done()
    config = json.loads((path / "config.json").read_text())
    assert config["config_hash"] == run.hash and "pved_version" in config
    # the BLAS kernel it ran under, which decides a run's last digits
    assert config["blas_kernel"] == loaded_kernel() and config["blas_kernel"]
    assert config["mkl_branch"] == loaded_mkl_branch() and config["mkl_branch"]
    assert config["numpy_simd"] == loaded_numpy_simd() and config["numpy_simd"]
    # another config: not done, and its start clears the old run's checkpoints
    other = Run(path, {"lr": 3e-4}, tensorboard=False)
    assert not other.is_done()
    other.start()
    assert other.latest_checkpoint() is None
    assert not other.result_path.exists()


def test_tensorboard_events_written(tmp_path: Path) -> None:
    run = Run(tmp_path / "r", {"x": 1})
    run.start()
    run.log(5, reward=1.0)
    run.finish({})
    assert list((tmp_path / "r").glob("events.out.tfevents.*"))


def test_atomic_write_leaves_no_temp_files(tmp_path: Path) -> None:
    atomic_write_json(tmp_path / "a.json", {"k": 1})
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_corrupt_checkpoint_is_a_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint at all")
    with pytest.raises(PvedError, match="cannot load"):
        safe_torch_load(bad)
    with pytest.raises(PvedError, match="not found"):
        safe_torch_load(tmp_path / "missing.pt")


def test_atomic_writes_are_readable_by_others(tmp_path: Path) -> None:
    import os
    import stat

    from pved.runs import atomic_torch_save, atomic_write_bytes

    old = os.umask(0o022)
    try:
        atomic_write_bytes(tmp_path / "a.json", b"{}")
        atomic_torch_save(tmp_path / "b.pt", {"x": 1})
    finally:
        os.umask(old)
    for name in ("a.json", "b.pt"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644


def test_file_digest_names_a_pytorch_files_state_not_its_bytes(tmp_path: Path) -> None:
    from pved.runs import atomic_torch_save, file_digest

    name = "pved"
    state = {"weights": torch.arange(6.0).reshape(2, 3), "name": name, "meta": {"model": name}}
    atomic_torch_save(tmp_path / "a.pt", state)
    # the same state saved again, its equal strings now distinct objects (pickled unlike)
    atomic_torch_save(tmp_path / "b.pt", {**state, "meta": {"model": "".join(["pv", "ed"])}})
    a, b = (tmp_path / "a.pt").read_bytes(), (tmp_path / "b.pt").read_bytes()
    assert a != b  # torch.save's random id, temporary names, pickle memo
    assert file_digest(tmp_path / "a.pt") == file_digest(tmp_path / "b.pt")
    for changed in (
        {**state, "weights": state["weights"] + 1e-6},
        {**state, "weights": state["weights"].reshape(3, 2)},
        {**state, "weights": state["weights"].double()},
        {**state, "meta": {"model": "pved-vae"}},
    ):
        atomic_torch_save(tmp_path / "c.pt", changed)
        assert file_digest(tmp_path / "c.pt") != file_digest(tmp_path / "a.pt")
    # anything else, a numpy archive included, by its bytes
    np.savez(tmp_path / "d.npz", x=np.ones(3))
    expected = hashlib.sha256((tmp_path / "d.npz").read_bytes()).hexdigest()[:16]
    assert file_digest(tmp_path / "d.npz") == expected


def test_a_claim_holds_until_it_expires_and_a_damaged_one_holds_nothing(tmp_path: Path) -> None:
    run_dir = tmp_path / "transfer" / "pved" / "seed0"
    write_claim(run_dir, "batch-a", until=100.0)
    assert not run_dir.exists() and claim_file(run_dir).parent == run_dir.parent
    assert claim_holder(run_dir, now=99.0) == "batch-a"
    assert claim_holder(run_dir, now=100.0) is None
    # only its holder's release (or any, with no holder named) removes it
    assert not release_claim(run_dir, "batch-b") and claim_file(run_dir).exists()
    assert release_claim(run_dir, "batch-a") and not claim_file(run_dir).exists()
    assert not release_claim(run_dir)
    for damaged in ("{", '{"holder": 3, "until": 1e12}', '{"holder": "x"}', "[]"):
        claim_file(run_dir).write_text(damaged)
        assert claim_holder(run_dir, now=0.0) is None


def test_a_resumed_run_keeps_the_provenance_of_its_earlier_starts(tmp_path: Path) -> None:
    # a run started before the MKL pin (no mkl_branch field) on another machine,
    # then resumed here twice: each earlier start stays on record, oldest first
    run = Run(tmp_path / "r", {"lr": 1e-4}, tensorboard=False)
    run.path.mkdir(parents=True)
    earlier = {"config_hash": run.hash, "pved_version": "0.1.0", "git_commit": "abc",
               "blas_kernel": "SkylakeX"}  # fmt: skip
    atomic_write_json(run.path / "config.json", {"config": {"lr": 1e-4}, **earlier})
    run.start()
    run.start()  # the same start (a stage and its trainer both call it): not a new one
    Run(run.path, {"lr": 1e-4}, tensorboard=False).start()
    config = json.loads((run.path / "config.json").read_text())
    assert config["previous_starts"][0] == {
        "pved_version": "0.1.0",
        "git_commit": "abc",
        "blas_kernel": "SkylakeX",
        "mkl_branch": None,
        "numpy_simd": None,
        "git_dirty": None,
        "stack": None,
        "fingerprint": None,
    }
    assert config["previous_starts"][1]["mkl_branch"] == loaded_mkl_branch()
    assert config["previous_starts"][1]["fingerprint"] == pinned_fingerprint()
    assert len(config["previous_starts"]) == 2
    assert config["blas_kernel"] == loaded_kernel()
    # another config's start is a new run, with no history
    Run(run.path, {"lr": 3e-4}, tensorboard=False).start()
    assert "previous_starts" not in json.loads((run.path / "config.json").read_text())


def test_a_run_records_the_commit_its_process_imported(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a pool worker outlives commits made while it runs: what it ran is what it imported
    assert git_commit() == _read_git_commit()  # the test's checkout has not moved since
    monkeypatch.setattr("pved.runs._read_git_commit", lambda: "a commit made since")
    run = Run(tmp_path / "r", {"x": 1}, tensorboard=False)
    run.start()
    recorded = json.loads((run.path / "config.json").read_text())["git_commit"]
    assert recorded == git_commit() != "a commit made since"


def test_a_run_records_its_tree_stack_and_fingerprint_outside_the_hash(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = Run(tmp_path / "r", {"x": 1}, tensorboard=False)
    run.start()
    run.finish({"score": 1.0})
    record = json.loads((run.path / "config.json").read_text())
    assert record["git_dirty"] == git_dirty()
    assert record["git_dirty"] in ((True, False) if git_commit() else (None,))  # a checkout?
    pinned = pinned_fingerprint()
    assert record["fingerprint"] == pinned is not None
    assert set(record["stack"]) == {"python", "numpy", "mujoco", "torch", "torch_cpu"}
    assert record["stack"]["numpy"] == np.__version__
    assert record["config_hash"] == config_hash({"x": 1}) == run.hash
    # code under another fingerprint, a dirty tree: the finished run is still the one asked
    monkeypatch.setattr("pved.provenance._PINNED_AT_IMPORT", "another")
    monkeypatch.setattr("pved.provenance._DIRTY_AT_IMPORT", True)
    again = Run(run.path, {"x": 1}, tensorboard=False)
    assert again.hash == run.hash and again.is_done()
    again.start()  # a resumed start keeps the earlier one's fingerprint on record
    record = json.loads((run.path / "config.json").read_text())
    assert record["fingerprint"] == "another" and record["git_dirty"] is True
    assert record["previous_starts"][0]["fingerprint"] == pinned


def test_last_logged_step_reads_the_last_whole_record(tmp_path: Path) -> None:
    assert last_logged_step(tmp_path) == 0  # no metrics.jsonl yet
    metrics = tmp_path / "metrics.jsonl"
    records = [json.dumps({"step": step, "loss": 0.5, "pad": "x" * 300}) for step in range(40)]
    metrics.write_text("\n".join(records) + "\n")  # longer than the 4 KiB tail it reads
    assert last_logged_step(tmp_path) == 39
    with metrics.open("a") as fh:
        fh.write('{"step": 40, "lo')  # a line being written
    assert last_logged_step(tmp_path) == 39
