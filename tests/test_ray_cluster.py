"""`pved protocol --pair SPEC.toml` on a real Ray cluster of two nodes, one of which is
lost part-way (issue 67): a pair pved has never seen (stock Reacher-v5 with SB3 policies
-> Reacher3), its runs checkpointed after every update (``--checkpoint-seconds 0``), the
worker node removed while it runs a transfer run. The protocol must finish with every
run made once (no step logged twice) and the summary of an undisturbed protocol.

Minutes of two cores, so not part of ``make test``: ``make test-ray`` runs it (and CI,
``.ci/run``); elsewhere it is skipped unless ``PVED_RAY_CLUSTER_TESTS=1``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from helpers import stock_reacher_spec
from pved.protocol.driver import summarize
from pved.protocol.plan import ProtocolPlan, finished_results
from pved.spec import SPEC_FILES_ENV, load_pair

pytestmark = pytest.mark.skipif(
    os.environ.get("PVED_RAY_CLUSTER_TESTS") != "1",
    reason="a Ray cluster of two nodes for minutes: make test-ray (PVED_RAY_CLUSTER_TESTS=1)",
)
ray_cluster_utils = pytest.importorskip("ray.cluster_utils")

PAIR = "stock-reacher"


@pytest.fixture
def cluster(monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """A head and a worker node of one CPU each, in a Ray temp directory of their own (a
    short path: Ray's sockets live there), so that this cluster is neither found nor
    found by another Ray on the machine (``ray.init()`` looks for the latest cluster in
    the default one)."""
    temp = tempfile.mkdtemp(prefix="pvedray")
    monkeypatch.setenv("RAY_TMPDIR", temp)
    # the nodes inherit this process's environment: without the spec files in it, the
    # workers find the spec pair only if the driver hands them the variable
    monkeypatch.delenv(SPEC_FILES_ENV, raising=False)
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        monkeypatch.setenv(name, "1")
    cluster = ray_cluster_utils.Cluster(
        initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False}
    )
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        yield cluster
    finally:
        cluster.shutdown()
        shutil.rmtree(temp, ignore_errors=True)


def _in_flight(transfers: Path) -> list[Path]:
    """Transfer runs started (a checkpoint made) and not finished."""
    return [
        run
        for run in transfers.glob("*/seed*")
        if list(run.glob("checkpoints/*")) and not (run / "result.json").exists()
    ]


def _steps_logged_once(metrics: Path) -> None:
    """Each scalar of ``metrics.jsonl`` at strictly increasing steps: a run resumed after
    its node died logged nothing twice."""
    last: dict[str, int] = {}
    for line in metrics.read_text().splitlines():
        record = json.loads(line)
        for key in record:
            if key != "step":
                assert record["step"] > last.get(key, -1), (metrics, key, record["step"])
                last[key] = record["step"]


def _finals(protocol: Path) -> dict[str, dict[str, float]]:
    """Every transfer run's final evaluation (success rate, return, ...), by run."""
    return {
        str(result.parent.relative_to(protocol)): {
            k: v for k, v in json.loads(result.read_text()).items() if k.startswith("final/")
        }
        for result in (protocol / "runs" / PAIR / "transfer").glob("*/seed*/result.json")
    }


def test_a_spec_pair_protocol_survives_losing_a_node(cluster: Any, tmp_path: Path) -> None:
    spec = stock_reacher_spec(tmp_path / "spec", smoke_steps=2048)
    out = tmp_path / "proto"
    cmd = [sys.executable, "-m", "pved", "protocol", "--pair", str(spec), "--budget", "smoke",
           "--methods", "pved", "ppo", "--out", str(out), "--address", cluster.address,
           "--checkpoint-seconds", "0"]  # fmt: skip
    log = (tmp_path / "driver.log").open("w")
    driver = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
    transfers = out / "runs" / PAIR / "transfer"
    t0 = time.monotonic()
    try:
        # both nodes busy with a transfer run, each past a checkpoint: one is the worker's
        while len(_in_flight(transfers)) < 2:
            assert driver.poll() is None, (tmp_path / "driver.log").read_text()
            assert time.monotonic() - t0 < 300, "no two transfer runs at once"
            time.sleep(0.2)
        (worker,) = cluster.worker_nodes
        cluster.remove_node(worker)
        assert driver.wait(timeout=400) == 0, (tmp_path / "driver.log").read_text()[-3000:]
    finally:
        if driver.poll() is None:
            driver.kill()
        log.close()

    summary = json.loads((out / "summary.json").read_text())
    assert summary["failed"] == {} and summary["blocked"] == []
    # the runs the lost node held failed once, then ran again on the head
    lost = sorted(p.stem for p in (out / "failures").glob("*.txt"))
    assert any("_transfer_" in key for key in lost), lost
    for metrics in (out / "runs").rglob("metrics.jsonl"):
        _steps_logged_once(metrics)
    methods = summary["pairs"][PAIR]["methods"]
    for method in ("pved", "ppo"):
        assert methods[method]["runs_finished"] == methods[method]["runs_planned"] == 2

    # The undisturbed reference, cheaply: the runs the node loss did not touch are their
    # own reference, so only those it interrupted are made again, in one process from
    # start to end, in a copy of the protocol; its summary must be the disturbed one's.
    reference = tmp_path / "reference"
    shutil.copytree(out, reference, ignore=shutil.ignore_patterns("summary.*", "failures"))
    load_pair(spec)  # this process too knows the pair by name (its env is restored after)
    plan = ProtocolPlan.load(reference)
    remade = 0
    for job in plan.expand(finished_results(plan)):
        if job.key.replace("/", "_") in lost and job.run_dir is not None:
            shutil.rmtree(job.run_dir)
            job.fn(**job.kwargs)
            remade += 1
    assert remade == len(lost)
    undisturbed = json.loads(json.dumps(summarize(reference)))
    assert _finals(reference) == _finals(out) and len(_finals(out)) == 10
    assert undisturbed["selection"] == summary["selection"]
    for method in ("pved", "ppo"):
        assert undisturbed["pairs"][PAIR]["methods"][method]["final"] == methods[method]["final"]
