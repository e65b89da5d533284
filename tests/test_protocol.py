"""The protocol (paper IV.A) as a job graph, the Ray runner, and ``pved protocol`` end to end."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from helpers import run_cli, stock_reacher_spec
from pved.blas import kernel_env, loaded_kernel, loaded_mkl_branch, loaded_numpy_simd
from pved.config import get_budget
from pved.errors import PvedError
from pved.experiments.stages import train_policy, transfer
from pved.experiments.transfer_spec import transfer_spec
from pved.protocol import watch
from pved.protocol.driver import COPYABLE_STAGES, copy_stage_runs
from pved.protocol.plan import (
    PLAN_FILE,
    ProtocolPlan,
    _best,
    _candidates,
    fixed_selections,
)
from pved.protocol.runner import Job, resolve_backend, run_jobs
from pved.run_layout import transfer_run_method, transfer_run_name
from pved.runs import RESTORED_FROM, atomic_write_json, config_hash, release_claim, write_claim
from pved.spec import get_preset, load_pair

PVED = [sys.executable, "-m", "pved.cli"]


def _fake(score: float, ret: float = 0.0) -> dict[str, float]:
    return {"final/success_rate": score, "final/return_mean": ret}


def _keys(jobs: list[Job]) -> set[str]:
    return {j.key for j in jobs}


def test_plan_selects_beta_then_init_then_evaluates(tmp_path: Path) -> None:
    plan = ProtocolPlan(["reacher"], ["pved", "ppo"], "smoke", tmp_path)
    budget = get_budget("smoke")
    grid = get_preset("reacher").beta_grid[: budget.beta_grid_size]
    assert len(grid) == 2 and len(budget.tuning_seeds) == 2

    jobs = plan.expand({})
    keys = _keys(jobs)
    # nothing to select yet: pairs, model init 0, the bank, beta x tuning-seed runs, and
    # the reference method's evaluation runs
    assert "reacher/pairs" in keys and "reacher/model/pved/init0" in keys
    assert "reacher/bank/src0" in keys
    tuning = [j for j in jobs if j.key.startswith("reacher/transfer/pved-")]
    assert len(tuning) == len(grid) * len(budget.tuning_seeds)
    assert all(j.tags["init"] == 0 and j.tags["source_policy"] == 0 for j in tuning)
    assert not any("init1" in k for k in keys)
    ppo = [j for j in jobs if "/transfer/ppo/" in j.key]
    assert len(ppo) == budget.source_policies * len(budget.evaluation_seeds)
    # the shipped policies are used: nothing to train
    assert not any(k.startswith("policy/") for k in keys)

    # the second beta wins on the tuning seeds
    results: dict[str, Any] = {
        j.key: _fake(0.2) for j in jobs if not j.key.startswith("reacher/transfer")
    }
    for j in tuning:
        results[j.key] = _fake(0.9 if j.tags["beta"] == grid[1] else 0.1)
    jobs = plan.expand(results)
    init1 = [j for j in jobs if "init1" in j.key and "/transfer/" in j.key]
    assert len(init1) == len(budget.tuning_seeds)
    assert all(j.kwargs["beta"] == grid[1] for j in init1)
    assert "reacher/model/pved/init1" in _keys(jobs)
    assert plan.selection["reacher"]["pved"]["beta"] == grid[1]
    assert not plan.evaluation_jobs("reacher", "pved")

    # init 1 does better at that beta: the evaluation runs use it
    for j in init1:
        results[j.key] = _fake(1.0)
    jobs = plan.expand(results)
    assert plan.selection["reacher"]["pved"]["init"] == 1
    evaluation = plan.evaluation_jobs("reacher", "pved")
    assert len(evaluation) == budget.source_policies * len(budget.evaluation_seeds)
    assert _keys(evaluation) <= _keys(jobs)
    assert all(j.kwargs["beta"] == grid[1] and j.tags["init"] == 1 for j in evaluation)
    assert all(j.kwargs["model_path"].parent.name == "seed1" for j in evaluation)
    candidates = plan.selection["reacher"]["pved"]["candidates"]
    assert len(candidates) == len(grid) + 1  # every beta at init 0, then init 1
    # what the selection waits on goes first: stages, then tuning runs, then evaluations
    assert {j.priority for j in jobs if "/transfer/" not in j.key} == {0}
    assert {j.priority for j in tuning + init1} == {1}
    assert {j.priority for j in evaluation + ppo} == {2}
    # the stages are made for the runs on them; of the models, the selected one is kept
    # for the summary, which reads its validation metrics
    end_products = {j.key for j in jobs if j.end_product}
    assert {"reacher/model/pved/init1"} | _keys(tuning + init1 + evaluation + ppo) == end_products


def test_ties_go_to_the_better_return_then_the_grid_order(tmp_path: Path) -> None:
    plan = ProtocolPlan(["reacher"], ["pved"], "smoke", tmp_path)
    grid = get_preset("reacher").beta_grid[:2]
    jobs = plan.expand({})
    results: dict[str, Any] = {j.key: _fake(0.0) for j in jobs}
    for j in jobs:
        if "/transfer/" in j.key:
            results[j.key] = _fake(0.5, ret=-3.0 if j.tags["beta"] == grid[0] else -1.0)
    plan.expand(results)
    assert plan.selection["reacher"]["pved"]["beta"] == grid[1]


def test_scores_within_the_metric_resolution_tie_and_go_to_the_return() -> None:
    from pved.protocol.plan import Candidate, _best

    # walker-hopper: a Hopper that falls at once (x -0.02 m, return 5) against one that
    # stands (x -0.13 m, return 1000), then one that walks (x 9.0 m)
    falls = Candidate(beta=10.0, init=0, scores=(-0.02,) * 3, returns=(5.0,) * 3)
    stands = Candidate(beta=0.1, init=0, scores=(-0.13,) * 3, returns=(1000.0,) * 3)
    walks = Candidate(beta=0.01, init=0, scores=(9.0,) * 3, returns=(900.0,) * 3)
    resolution = get_preset("walker-hopper").metric_resolution
    assert resolution == 0.5
    assert _best([falls, stands]) is falls  # as they are, centimetres decide
    assert _best([falls, stands], resolution) is stands
    assert _best([falls, stands, walks], resolution) is walks
    assert get_preset("reacher").metric_resolution is None


def _tune(
    plan: ProtocolPlan, score_of_beta: Mapping[float, float]
) -> tuple[list[float], dict[str, Any]]:
    """Expand ``plan`` until pved's beta is chosen, each tuning run scoring
    ``score_of_beta[beta]``; returns the betas tried, in order, and the results."""
    results: dict[str, Any] = {}
    tried: list[float] = []
    for _ in range(10):
        jobs = plan.expand(results)
        for j in jobs:
            if j.key in results:
                continue
            if "/transfer/pved-" in j.key:
                if j.tags["init"] != 0:
                    continue
                if j.kwargs["beta"] not in tried:
                    tried.append(j.kwargs["beta"])
                results[j.key] = _fake(score_of_beta[j.kwargs["beta"]])
            elif "/transfer/" not in j.key:
                results[j.key] = _fake(0.0)
        if "beta" in plan.selection["reacher"]["pved"]:
            return tried, results
    raise AssertionError("no beta was chosen")


@pytest.mark.parametrize(
    ("scores", "tried", "chosen"),
    [
        # the grid's largest beta is best: a decade up, then another, then the limit
        ({0.1: 0.5, 0.01: 0.2, 1.0: 0.6, 10.0: 0.7}, [0.1, 0.01, 1.0, 10.0], 10.0),
        # its smallest: down two decades, where the limit stops the search
        ({0.1: 0.1, 0.01: 0.2, 0.001: 0.3, 0.0001: 0.4}, [0.1, 0.01, 0.001, 0.0001], 0.0001),
        # a decade up does worse: the grid's edge is inside what was searched
        ({0.1: 0.5, 0.01: 0.2, 1.0: 0.4}, [0.1, 0.01, 1.0], 0.1),
        # a decade down, then back: 0.01 beats 0.001, and 0.1 is tried no more
        ({0.1: 0.2, 0.01: 0.5, 0.001: 0.3}, [0.1, 0.01, 0.001], 0.01),
        # a complete tie points nowhere (jaco-fetch's shared-only: success 0 and return 0
        # at every beta): a decade past both edges, and again, up to the limit; the grid's
        # order then decides
        (
            dict.fromkeys([0.1, 0.01, 1.0, 0.001, 10.0, 0.0001], 0.0),
            [0.1, 0.01, 1.0, 0.001, 10.0, 0.0001],
            0.1,
        ),
        # ... until one beta does better, past whose edge the search then goes on alone
        (
            {0.1: 0.0, 0.01: 0.0, 1.0: 0.0, 0.001: 0.4, 0.0001: 0.3},
            [0.1, 0.01, 1.0, 0.001, 0.0001],
            0.001,
        ),
    ],
)
def test_beta_search_goes_past_the_grid_while_its_edge_does_best(
    tmp_path: Path, scores: dict[float, float], tried: list[float], chosen: float
) -> None:
    plan = ProtocolPlan(["reacher"], ["pved"], "smoke", tmp_path)
    plan.budget = dataclasses.replace(plan.budget, beta_grid_extensions=2)
    assert get_preset("reacher").beta_grid[:2] == (0.1, 0.01)
    before = plan.expected_steps()
    betas, results = _tune(plan, scores)
    assert betas == tried
    # the live view's total counts the runs past the grid
    per_beta = len(plan.budget.tuning_seeds) * get_preset("reacher").transfer_steps("smoke")
    assert plan.expected_steps() - before == per_beta * (len(tried) - 2)
    state = plan.selection["reacher"]["pved"]
    assert state["beta"] == chosen
    assert state["beta_grid"] == [0.1, 0.01]
    assert state.get("beta_extended", []) == tried[2:]
    # initialisation 1 is tuned at the chosen beta, under the grid's naming
    jobs = plan.expand(results)
    init1 = [j for j in jobs if "/transfer/" in j.key and j.tags["init"] == 1]
    assert init1 and all(j.kwargs["beta"] == chosen for j in init1)
    assert all(f"-beta{chosen:g}-init1-" in j.key for j in init1)


def test_point_code_methods_search_higher_betas() -> None:
    preset = get_preset("walker-hopper")
    for method in ("pved-det-shared", "gupta2017"):
        grid = preset.beta_grid_for(method)
        assert grid[: len(preset.beta_grid)] == preset.beta_grid and max(grid) == 10.0
    assert preset.beta_grid_for("pved") == preset.beta_grid


def test_a_protocol_from_a_narrower_beta_search_is_carried_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pved.protocol.driver as protocol

    monkeypatch.setattr(protocol, "run_jobs", lambda plan, **kwargs: None)
    monkeypatch.setattr(protocol, "summarize", lambda out, report: {})
    methods = ["pved-det-shared", "ppo"]
    plan = ProtocolPlan(["reacher"], methods, "quick", tmp_path)
    current = json.loads(json.dumps(plan.describe()))
    # as an earlier pved wrote it: the common grid for det-shared, no extensions field
    earlier = json.loads(json.dumps(current))
    earlier["beta_grids"]["reacher"]["pved-det-shared"] = [0.1, 0.01, 0.001]
    del earlier["budget"]["beta_grid_extensions"]
    (tmp_path / "protocol.json").write_text(json.dumps({**earlier, "pved_version": "0.0.9"}))
    protocol.run_protocol(["reacher"], budget="quick", methods=methods, out=tmp_path)
    written = json.loads((tmp_path / "protocol.json").read_text())
    assert written["beta_grids"] == current["beta_grids"]
    assert written["earlier_plans"][0]["beta_grids"] == earlier["beta_grids"]
    assert {k: written[k] for k in current} == current  # a second start matches as is
    protocol.run_protocol(["reacher"], budget="quick", methods=methods, out=tmp_path)

    # a grid that lost a value, another budget field, or other methods: refused
    for change in (
        lambda p: p["beta_grids"]["reacher"].__setitem__("pved-det-shared", [0.5]),
        lambda p: p["budget"].__setitem__("model_inits", 2),
        lambda p: p.__setitem__("methods", ["pved-det-shared"]),
    ):
        other = json.loads(json.dumps(earlier))
        change(other)
        (tmp_path / "protocol.json").write_text(json.dumps(other))
        with pytest.raises(PvedError, match="holds a protocol with other settings"):
            protocol.run_protocol(["reacher"], budget="quick", methods=methods, out=tmp_path)


def test_plan_rejects_unknown_names(tmp_path: Path) -> None:
    with pytest.raises(PvedError, match="unknown pair"):
        ProtocolPlan(["nope"], ["pved"], "smoke", tmp_path)
    with pytest.raises(PvedError, match="unknown method"):
        ProtocolPlan(["reacher"], ["pvde"], "smoke", tmp_path)
    with pytest.raises(PvedError, match="unknown budget"):
        ProtocolPlan(["reacher"], ["pved"], "huge", tmp_path)


def test_plan_trains_the_policies_the_package_does_not_ship(tmp_path: Path) -> None:
    plan = ProtocolPlan(["reacher"], ["pved"], "quick", tmp_path)
    keys = _keys(plan.expand({}))
    # seed 0 of the source's Push policy is shipped; seeds 1 and 2 must be trained
    assert "policy/Reacher3-Push/seed1" in keys and "policy/Reacher3-Push/seed2" in keys
    assert "policy/Reacher3-Push/seed0" not in keys
    bank2 = next(j for j in plan.expand({}) if j.key == "reacher/bank/src2")
    assert bank2.deps == ("policy/Reacher3-Push/seed2",)


def test_plan_takes_a_spec_pairs_own_policy_files_and_trains_the_rest(tmp_path: Path) -> None:
    spec = stock_reacher_spec(tmp_path / "spec")
    pair = load_pair(spec).name
    plan = ProtocolPlan([pair], ["pved"], "quick", tmp_path / "p")
    jobs = {j.key: j for j in plan.expand({})}
    # policy 0 of the source on either task is the SB3 file the spec names, not a run
    assert jobs[f"{pair}/pairs"].kwargs["source_policy"] == spec.parent / "stock_reach.zip"
    assert jobs[f"{pair}/bank/src0"].kwargs["source_policy"] == spec.parent / "stock_push.zip"
    assert jobs[f"{pair}/bank/src0"].deps == ()
    # the budget's further source policies are trained, under the pair, by its name
    trained = sorted(k for k in jobs if k.startswith("policy/"))
    assert trained == ["policy/StockReacher2-Push/seed1", "policy/StockReacher2-Push/seed2"]
    assert all(jobs[k].kwargs["pair"] == pair for k in trained)
    assert jobs[trained[0]].run_dir == plan.runs / pair / "policy" / "StockReacher2-Push" / "seed1"


def test_protocol_checkpoint_seconds_reach_every_rl_run_and_no_config(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    planned: list[ProtocolPlan] = []

    def planned_only(plan: ProtocolPlan, **options: Any) -> None:
        planned.append(plan)
        raise PvedError("planned")

    monkeypatch.setattr("pved.protocol.driver.run_jobs", planned_only)
    argv = ["protocol", "--pair", "reacher", "--budget", "quick", "--out", tmp_path / "p"]
    code, _, err = run_cli(capsys, *argv, "--checkpoint-seconds", "5", "--backend", "processes")
    assert code == 2 and "planned" in err
    jobs = planned[0].expand({})
    runs = [j for j in jobs if j.fn in (transfer, train_policy)]
    assert {j.fn for j in runs} == {transfer, train_policy}
    assert all(j.run_options == {"checkpoint_every_s": 5.0} for j in runs)
    # by default a minute, as transfer's; the runs' arguments, and so their configs, alike
    default = ProtocolPlan(["reacher"], ["pved", "ppo"], "quick", tmp_path / "p").expand({})
    assert {j.run_options["checkpoint_every_s"] for j in default if j.run_options} == {60.0}
    assert [j.kwargs for j in default] == [j.kwargs for j in jobs]
    # the runner hands a job's options to its function beside its arguments
    report = run_jobs(
        _FixedPlan([Job("a", _arguments, {"x": 1}, run_options={"y": 2})]),
        workers=1,
        live=False,
        backend="processes",
    )
    assert report.results == {"a": {"x": 1, "y": 2}}


def test_plan_uses_the_shipped_seeds_whichever_they_are(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a seed that missed its bar is not shipped: with Walker2d Curve seeds 1 and 3 shipped,
    # the three source policies are seeds 1 and 3, then a run training seed 0
    import pved.pretrained

    shipped = tmp_path / "pretrained"
    shipped.mkdir()
    for stem in (
        "walker2d_curve_seed1",
        "walker2d_curve_seed3",
        "walker2d_slope_seed0",
        "hopper_slope_seed1",
    ):
        (shipped / f"{stem}.pt").write_bytes(b"")
    monkeypatch.setattr(pved.pretrained, "PRETRAINED_DIR", shipped)
    plan = ProtocolPlan(["walker-hopper"], ["pved"], "quick", tmp_path / "out")
    jobs = {j.key: j for j in plan.expand({})}
    banks = [jobs[f"walker-hopper/bank/src{k}"] for k in range(3)]
    assert [Path(b.kwargs["source_policy"]).name for b in banks[:2]] == [
        "walker2d_curve_seed1.pt",
        "walker2d_curve_seed3.pt",
    ]
    assert banks[2].deps == ("policy/Walker2d-Curve/seed0",)
    # pairing uses the lowest shipped seed of each training-task policy: Hopper's is 1
    pairs = jobs["walker-hopper/pairs"]
    assert Path(pairs.kwargs["target_policy"]).name == "hopper_slope_seed1.pt"
    assert not any(k.startswith(("policy/Hopper", "policy/Walker2d-Slope")) for k in jobs)


# -- the runner ---------------------------------------------------------------------------


def _ok(value: int) -> int:
    return value


def _arguments(**kwargs: Any) -> dict[str, Any]:
    return kwargs


def _always_fails() -> None:
    raise ValueError("this run always fails")


def _fails_once(marker: str) -> str:
    path = Path(marker)
    if not path.exists():
        path.write_text("tried")
        raise RuntimeError("first attempt fails")
    return "second attempt"


class _FixedPlan:
    def __init__(self, jobs: list[Job]):
        self.jobs = jobs

    def expand(self, results: Mapping[str, Any]) -> list[Job]:
        return self.jobs

    def expected_steps(self) -> int:
        return 0


def _dies_once(marker: str) -> str:
    path = Path(marker)
    if not path.exists():
        path.write_text("died")
        os._exit(1)  # the worker process itself dies (as when killed or out of memory)
    return "second life"


def _deaf_to_sigterm(marker: str) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    Path(marker).write_text("deaf")
    time.sleep(120)


def _blas_paths_of_worker() -> tuple[str | None, str | None, str | None]:
    return loaded_kernel(), loaded_mkl_branch(), loaded_numpy_simd()


def _ship_this_module_to(backend: str) -> None:
    """Ray's workers import functions by module, and this test module is not importable
    there: send its functions by value."""
    if backend == "ray":
        from ray import cloudpickle

        cloudpickle.register_pickle_by_value(sys.modules[__name__])


@pytest.mark.parametrize(("driver", "worker"), [(0, 15), (15, 15), (17, 17), (19, 19)])
def test_a_worker_is_at_least_as_nice_as_its_driver(driver: int, worker: int) -> None:
    # a fresh interpreter: niceness only goes up, and this test's own must not change
    code = (
        "import os\n"
        f"os.nice({driver} - os.nice(0))\n"
        "from pved.protocol.runner import _init_process_worker\n"
        "_init_process_worker()\n"
        "print(os.nice(0))\n"
    )
    if os.nice(0) > driver:
        pytest.skip(f"this test process already runs at niceness {os.nice(0)}")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env())
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) == worker


@pytest.mark.parametrize("backend", ["ray", "processes"])
def test_runner_retries_then_reports_failures_and_blocked_jobs(
    tmp_path: Path, backend: str
) -> None:
    _ship_this_module_to(backend)
    jobs = [
        Job("a", _ok, {"value": 3}),
        Job("b", _always_fails),
        Job("c", _ok, {"value": 4}, deps=("b",)),
        Job("d", _fails_once, {"marker": str(tmp_path / "marker")}),
        Job("e", _ok, {"value": 5}, deps=("a",)),
    ]
    report = run_jobs(
        _FixedPlan(jobs),
        workers=2,
        retries=2,
        log_dir=tmp_path / "logs",
        live=False,
        backend=backend,
    )
    assert report.results == {"a": 3, "d": "second attempt", "e": 5}
    assert list(report.failed) == ["b"] and "this run always fails" in report.failed["b"]
    assert "\n" not in report.failed["b"]
    assert report.attempts["b"] == 3 and report.attempts["d"] == 2
    assert report.blocked == ["c"]
    assert "this run always fails" in (tmp_path / "logs" / "b.txt").read_text()


def _record(log: str, key: str) -> str:
    with open(log, "a") as fh:
        fh.write(key + "\n")
    return key


@pytest.mark.parametrize("backend", ["ray", "processes"])
def test_runner_runs_no_more_than_its_workers_in_priority_order(
    tmp_path: Path, backend: str
) -> None:
    # one worker: the order the jobs ran in is the order they were submitted in, so a
    # runner that queued every ready job at once would run them in the plan's order
    _ship_this_module_to(backend)
    log = str(tmp_path / "order.txt")
    jobs = [
        Job("evaluation", _record, {"log": log, "key": "evaluation"}, priority=2),
        Job("tuning", _record, {"log": log, "key": "tuning"}, priority=1),
        Job("stage", _record, {"log": log, "key": "stage"}, priority=0),
        Job("after-stage", _record, {"log": log, "key": "after-stage"}, deps=("stage",)),
    ]
    report = run_jobs(_FixedPlan(jobs), workers=1, live=False, backend=backend)
    assert not report.failed
    # the job that became ready after the first one finished still went ahead (priority 0)
    assert Path(log).read_text().split() == ["stage", "after-stage", "tuning", "evaluation"]


def test_live_view_rate_leaves_out_the_steps_of_earlier_calls(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import io

    from pved.protocol import runner

    clock = iter([0.0, 10.0, 20.0])
    monkeypatch.setattr(runner.time, "monotonic", lambda: next(clock))
    view = runner.LiveView(tmp_path / "status.json", stream=io.StringIO())  # clock 0
    # 10 s in, a restart has found 1M steps of finished runs on disk: no rate yet
    first = view.update(1, 1, 0, 5, 1_000_000, 3_000_000, earlier_steps=1_000_000)
    assert first["steps_per_s"] == 0.0 and first["eta_s"] is None
    # 10 s later this call has trained 5,000 steps: 500 steps/s, 1,995,000 steps to go
    second = view.update(1, 1, 0, 5, 1_005_000, 3_000_000, earlier_steps=1_000_000)
    assert second["steps_per_s"] == pytest.approx(5_000 / 20)
    assert second["eta_s"] == pytest.approx(1_995_000 / 250)


def test_live_view_eta_past_a_day_keeps_its_hours(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import io

    from pved.protocol import runner

    clock = iter([0.0, 0.0, 100.0])
    monkeypatch.setattr(runner.time, "monotonic", lambda: next(clock))
    stream = io.StringIO()
    view = runner.LiveView(tmp_path / "status.json", stream=stream)
    view.update(0, 2, 0, 9, 0, 1)  # clock 0: the rate's starting point
    # 1,000 steps/s with 112,540,000 steps to go: 31 h 15 min 40 s, not 07:15:40
    status = view.update(0, 2, 0, 9, 100_000, 112_640_000, force=True)
    assert status["eta_s"] == pytest.approx(112_540)
    assert stream.getvalue().rstrip().endswith("ETA 31:15:40")
    assert runner.LiveView is watch.LiveView and watch.duration_text(59.6) == "00:01:00"


def _ran_at(log: str) -> float:
    Path(log).write_text(repr(time.time()))
    return time.time()


def test_runner_leaves_a_claimed_run_to_its_batch_then_makes_it(tmp_path: Path) -> None:
    import threading

    _ship_this_module_to("processes")
    claimed, expired = tmp_path / "claimed" / "seed0", tmp_path / "expired" / "seed0"
    write_claim(claimed, "a batch", time.time() + 600.0)  # far beyond the test's length
    write_claim(expired, "a batch", time.time() - 1.0)
    released: list[float] = []

    def batch_comes_back() -> None:
        # a second after the other run is done (both would have started together, were
        # the claim ignored), when only the claimed run is left
        deadline = time.monotonic() + 120
        while not (tmp_path / "expired.txt").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)
        released.append(time.time())
        release_claim(claimed)

    jobs = [
        Job("claimed", _ran_at, {"log": str(tmp_path / "claimed.txt")}, run_dir=claimed),
        Job("expired", _ran_at, {"log": str(tmp_path / "expired.txt")}, run_dir=expired),
    ]
    # the runner must wait for the claimed run rather than end without it
    batch = threading.Thread(target=batch_comes_back, daemon=True)
    batch.start()
    t0 = time.monotonic()
    report = run_jobs(_FixedPlan(jobs), workers=2, live=False, backend="processes", poll_s=0.1)
    batch.join(timeout=130)
    assert set(report.results) == {"claimed", "expired"}
    assert released and float((tmp_path / "claimed.txt").read_text()) >= released[0]
    assert time.monotonic() - t0 < 300  # by the release, not the claim's expiry


def test_live_view_counts_the_runs_away_in_a_batch(tmp_path: Path) -> None:
    import io

    from pved.protocol import runner

    stream = io.StringIO()
    view = runner.LiveView(tmp_path / "status.json", stream=stream)
    status = view.update(1, 0, 0, 3, 10, 40, force=True, away=2)
    assert status["away"] == 2 and "3 waiting (2 away in a batch)" in stream.getvalue()


def _starts_over(run_dir: str) -> str:
    # what Run.start does to a run left under another config: its records are deleted
    metrics = Path(run_dir) / "metrics.jsonl"
    metrics.unlink()
    (Path(run_dir) / "result.json").unlink()
    metrics.write_text(json.dumps({"step": 300}) + "\n")
    time.sleep(2.0)  # in flight long enough to be seen at step 300
    (Path(run_dir) / "result.json").write_text("{}")
    return "done"


def test_runner_does_not_count_a_run_that_starts_over_as_earlier_work(tmp_path: Path) -> None:
    _ship_this_module_to("processes")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    # a finished run of another config (the restart after a config change)
    (run_dir / "metrics.jsonl").write_text(json.dumps({"step": 10_000}) + "\n")
    (run_dir / "result.json").write_text('{"config_hash": "old"}')
    job = Job("run", _starts_over, {"run_dir": str(run_dir)}, steps=10_000, run_dir=run_dir)
    status = tmp_path / "status.json"
    report = run_jobs(
        _FixedPlan([job]), workers=1, status_path=status, backend="processes", poll_s=0.1
    )
    written = json.loads(status.read_text())
    # the 10,000 steps it had logged before were thrown away, not reused or resumed from
    assert written["env_steps"] == 10_000 and written["env_steps_earlier"] <= 300
    assert report.reused == []


def test_runner_counts_runs_finished_earlier_apart(tmp_path: Path) -> None:
    _ship_this_module_to("processes")
    done, fresh = tmp_path / "done", tmp_path / "fresh"
    done.mkdir()
    (done / "result.json").write_text("{}")
    (done / "metrics.jsonl").write_text(json.dumps({"step": 1000}) + "\n")
    jobs = [
        Job("done", _ok, {"value": 1}, steps=1000, run_dir=done),
        Job("fresh", _ok, {"value": 2}, steps=500, run_dir=fresh),
    ]
    status = tmp_path / "status.json"
    report = run_jobs(_FixedPlan(jobs), workers=1, status_path=status, backend="processes")
    assert report.reused == ["done"]
    written = json.loads(status.read_text())
    assert (written["env_steps"], written["env_steps_earlier"]) == (1500, 1000)


def test_runner_takes_a_finished_run_whose_inputs_nothing_else_needs(tmp_path: Path) -> None:
    # a protocol restored on a new machine: two models were not kept, and of the runs
    # on them, "tuned-a" and "tuned-b" (model-0) and "tuned-c" (model-1) are done; a
    # third model was kept, but not the pairs it was trained on
    _ship_this_module_to("processes")
    log = str(tmp_path / "ran.txt")

    def job(key: str, deps: tuple[str, ...] = (), end_product: bool = True) -> Job:
        kwargs = {"log": log, "key": key}
        return Job(key, _record, kwargs, deps, run_dir=tmp_path / key, end_product=end_product)

    for key in ("tuned-a", "tuned-b", "tuned-c", "model-2"):
        (tmp_path / key).mkdir()
        (tmp_path / key / "result.json").write_text(json.dumps({"made": key}))
    # restored from another machine's summary: never checked, even where it could be
    (tmp_path / "tuned-d").mkdir()
    (tmp_path / "tuned-d" / "result.json").write_text(json.dumps({RESTORED_FROM: "there"}))
    jobs = [
        job("model-0", end_product=False),
        job("tuned-a", ("model-0",)),
        job("tuned-b", ("model-0",)),
        job("model-1", end_product=False),
        job("tuned-c", ("model-1",)),
        job("tuned-d", ("model-1",)),
        job("evaluation", ("model-1",)),
        job("pairs", end_product=False),
        job("model-2", ("pairs",), end_product=False),
        job("evaluation-2", ("model-2",)),
    ]
    report = run_jobs(_FixedPlan(jobs), workers=1, live=False, backend="processes")
    assert not report.failed
    # model-0 is not remade only to confirm its runs; model-1 is made for the evaluation
    # run, and the run on it found done is checked against it; model-2 is taken as kept,
    # and its pairs are not made again
    ran = sorted(Path(log).read_text().split())
    assert ran == ["evaluation", "evaluation-2", "model-1", "tuned-c"]
    assert report.results["tuned-a"] == {"made": "tuned-a"} and "model-0" not in report.results
    assert sorted(report.reused) == ["model-2", "tuned-a", "tuned-b", "tuned-c", "tuned-d"]


class _SelectingPlan:
    """A restored tuning run, done on disk, on a model that becomes the selected one (an
    end product) once the run's result is known."""

    def __init__(self, root: Path, log: str):
        self.root, self.log = root, log

    def expand(self, results: Mapping[str, Any]) -> list[Job]:
        def job(key: str, deps: tuple[str, ...] = (), end_product: bool = True) -> Job:
            kwargs = {"log": self.log, "key": key}
            return Job(key, _record, kwargs, deps, run_dir=self.root / key, end_product=end_product)

        return [job("model", end_product="tuned" in results), job("tuned", ("model",))]

    def expected_steps(self) -> int:
        return 0


def test_runner_makes_a_stage_the_plan_marks_an_end_product_later(tmp_path: Path) -> None:
    _ship_this_module_to("processes")
    log = str(tmp_path / "ran.txt")
    (tmp_path / "tuned").mkdir()
    (tmp_path / "tuned" / "result.json").write_text("{}")
    report = run_jobs(_SelectingPlan(tmp_path, log), workers=1, live=False, backend="processes")
    assert not report.failed
    # the model is made once selected; the tuning run it was selected by had been taken
    # as done before, and stays so
    assert Path(log).read_text().split() == ["model"]
    assert report.reused == ["tuned"]


@pytest.mark.parametrize("backend", ["ray", "processes"])
def test_runner_retries_a_job_whose_worker_died(tmp_path: Path, backend: str) -> None:
    # alone in flight: on the process pool a dead worker fails every job the pool held
    _ship_this_module_to(backend)
    jobs = [
        Job("f", _dies_once, {"marker": str(tmp_path / "died")}),
        Job("g", _ok, {"value": 6}, deps=("f",)),
    ]
    report = run_jobs(_FixedPlan(jobs), workers=2, retries=1, live=False, backend=backend)
    assert report.results == {"f": "second life", "g": 6}
    assert report.attempts == {"f": 2, "g": 1} and not report.failed


@pytest.mark.parametrize("pool_thread_slow_to_record", [False, True])
def test_process_runner_leaves_no_worker_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, pool_thread_slow_to_record: bool
) -> None:
    # a pool worker still alive when run_jobs returns would be joined at interpreter exit
    # (multiprocessing's rule for non-daemon children): a finished test run that never
    # exits. The replaced pool's workers count too. Only this call's children count: a
    # process another test left behind (still dying) is not run_jobs's.
    import multiprocessing
    import threading

    if pool_thread_slow_to_record:
        # Two threads wait on each worker: run_jobs' shutdown and the pool's own. The one
        # that reaps it records its exit code a moment later; until then the other finds
        # no such child and multiprocessing counts the worker alive (CI saw one "started"
        # after run_jobs returned). Here the pools' threads are slow to record it.
        real_waitpid = os.waitpid

        def waitpid_slow_off_the_main_thread(pid: int, options: int) -> tuple[int, int]:
            reaped = real_waitpid(pid, options)
            if reaped[0] == pid and threading.current_thread() is not threading.main_thread():
                time.sleep(0.5)
            return reaped

        monkeypatch.setattr(os, "waitpid", waitpid_slow_off_the_main_thread)
    _ship_this_module_to("processes")
    before = set(multiprocessing.active_children())
    jobs = [
        Job("f", _dies_once, {"marker": str(tmp_path / "died")}),
        Job("g", _ok, {"value": 6}, deps=("f",)),
        Job("h", _ok, {"value": 7}),
    ]
    report = run_jobs(_FixedPlan(jobs), workers=2, retries=1, live=False, backend="processes")
    assert not report.failed
    assert set(multiprocessing.active_children()) - before == set()


def test_process_runner_kills_a_worker_deaf_to_sigterm(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # shutdown asks a worker to end (SIGTERM), and one that does not within the grace
    # period is killed: left alive it would keep the interpreter from exiting
    from pved.protocol import runner

    monkeypatch.setattr(runner, "WORKER_STOP_GRACE_S", 1.0)
    executor = runner._ProcessExecutor(1)
    marker = tmp_path / "deaf"
    executor.submit(_deaf_to_sigterm, {"marker": str(marker)})
    workers: list[Any] = []
    try:
        deadline = time.monotonic() + 120
        while not marker.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert marker.exists(), "the worker never started the job"
        workers = runner._pool_workers(executor.pool)
        executor.shutdown()
        assert workers and not any(worker.is_alive() for worker in workers)
        assert workers[0].exitcode == -signal.SIGKILL  # it ignored SIGTERM
    finally:
        for worker in workers or runner._pool_workers(executor.pool):
            if worker.is_alive():
                worker.kill()
                worker.join()


@pytest.mark.parametrize("backend", ["ray", "processes"])
def test_runner_workers_run_one_blas_kernel_and_mkl_branch_everywhere(
    backend: str,
) -> None:
    # OpenBLAS picks its kernel by CPU (SkylakeX on this project's machine, Haswell on
    # the one before): unpinned, a model retrained on another machine differs. The
    # workers run the kernel this process pinned on importing pved, as this one does.
    # Likewise torch's MKL, whose branch decides the QR behind the policies' orthogonal
    # initialisation, and numpy's SIMD group, whose exp and log the models' likelihoods use.
    if not kernel_env():
        pytest.skip("this CPU cannot run the portable kernel, so none is pinned")
    # PORTABLE_KERNEL, PORTABLE_MKL_BRANCH and numpy's AVX2 group, unless set by the caller
    expected = (os.environ["OPENBLAS_CORETYPE"], os.environ["MKL_CBWR"], loaded_numpy_simd())
    assert _blas_paths_of_worker() == expected  # the test process (conftest imports pved)
    _ship_this_module_to(backend)
    jobs = [Job("k", _blas_paths_of_worker, {})]
    report = run_jobs(_FixedPlan(jobs), workers=1, live=False, backend=backend)
    assert report.results == {"k": expected}


def test_runner_backend_errors_are_one_line() -> None:
    with pytest.raises(PvedError, match="unknown backend 'dask'"):
        resolve_backend("dask")
    with pytest.raises(PvedError, match="needs backend 'ray'"):
        resolve_backend("processes", "127.0.0.1:6379")
    assert resolve_backend("auto") == "ray"  # installed here
    assert resolve_backend("processes") == "processes"


# -- end to end -----------------------------------------------------------------------------


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", MUJOCO_GL="osmesa", PYOPENGL_PLATFORM="osmesa")
    return env


@pytest.mark.slow
def test_protocol_smoke_survives_kill_and_resumes(tmp_path: Path) -> None:
    """`pved protocol --budget smoke` on the Reacher pair with two methods: killed with
    SIGKILL once the first transfer run has finished, then run again to the end."""
    out = tmp_path / "proto"
    cmd = [
        *PVED,
        "protocol",
        "--pair",
        "reacher",
        "--budget",
        "smoke",
        "--methods",
        "pved",
        "ppo",
        "--out",
        str(out),
        "--workers",
        "2",
    ]
    t0 = time.monotonic()
    proc = subprocess.Popen(
        cmd,
        env=_env(),
        cwd=tmp_path,
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    transfers = out / "runs" / "reacher" / "transfer"
    while time.monotonic() - t0 < 300 and not list(transfers.glob("*/seed*/result.json")):
        assert proc.poll() is None, proc.stdout.read().decode() if proc.stdout else ""
        time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    finished_before = {
        p.parent: (p.stat().st_mtime_ns, p.read_bytes())
        for p in transfers.glob("*/seed*/result.json")
    }
    assert finished_before
    assert not (out / "summary.json").exists()

    done = subprocess.run(cmd, env=_env(), cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "summary.md" in done.stdout
    assert "runs:" in done.stderr  # the live view
    summary = json.loads((out / "summary.json").read_text())
    assert summary["failed"] == {} and summary["blocked"] == []
    assert summary["reused"] >= len(finished_before)
    methods = summary["pairs"]["reacher"]["methods"]
    budget = get_budget("smoke")
    for method in ("pved", "ppo"):
        entry = methods[method]
        assert entry["runs_finished"] == entry["runs_planned"] == len(budget.evaluation_seeds)
        final = entry["final"]
        assert final["mean_ci"][0] <= final["mean"] <= final["mean_ci"][1]
        # a step count to PPO's final, or the note that PPO ended where it started
        assert "steps_to_ppo_final" in entry or entry["ppo_improved"] is False
        # runs cut short by the kill were redone, not logged twice: one point per step
        assert entry["curve_steps"] == sorted(set(entry["curve_steps"]))
    selection = json.loads((out / "selection.json").read_text())["reacher"]["pved"]
    assert selection["beta"] in get_preset("reacher").beta_grid
    assert len(selection["candidates"]) == budget.beta_grid_size + budget.model_inits - 1
    for name in ("curves.png", "curves-reacher.png", "summary.md", "status.json"):
        assert (out / name).stat().st_size > 0
    assert "| pved |" in (out / "summary.md").read_text()
    # the shaping term's size against the env's reward, for shaped methods only
    scale = methods["pved"]["reward_scale"]
    assert scale["runs"] == len(budget.evaluation_seeds) and scale["shaping_first"] < 0
    assert "reward_scale" not in methods["ppo"]
    # the selected model's collapse check is carried into the summary (none for PPO)
    assert isinstance(methods["pved"]["shared_collapsed"], bool)
    assert "shared_collapsed" not in methods["ppo"]
    flagged = any(m.get("shared_collapsed") for m in methods.values())
    assert ("(collapsed)" in (out / "summary.md").read_text()) == flagged
    # finished runs are not redone: their results are the very same files
    for run_dir, (mtime, content) in finished_before.items():
        result = run_dir / "result.json"
        assert result.stat().st_mtime_ns == mtime and result.read_bytes() == content

    # `pved plot` redraws from the run files alone
    (out / "curves.png").unlink()
    (out / "summary.json").unlink()
    # a model trained before result.json recorded its collapse check is judged from its
    # final validation metrics
    init = selection["init"]
    model_result_path = out / "runs" / "reacher" / "model" / "pved" / f"seed{init}" / "result.json"
    model_result = json.loads(model_result_path.read_text())
    recorded = model_result.pop("shared_collapsed")
    model_result_path.write_text(json.dumps(model_result))
    plotted = subprocess.run(
        [*PVED, "plot", str(out), "--out", str(tmp_path / "all.png")],
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert plotted.returncode == 0, plotted.stderr
    assert (out / "curves.png").exists() and (tmp_path / "all.png").exists()
    again = json.loads((out / "summary.json").read_text())
    assert again["pairs"]["reacher"]["methods"]["pved"]["final"] == methods["pved"]["final"]
    assert again["pairs"]["reacher"]["methods"]["pved"]["shared_collapsed"] is recorded

    # the pair report of this protocol: one rendered rollout per method, embedded
    from pved.diagnostics.pair_report import build_pair_report

    report = build_pair_report("reacher", [out], tmp_path / "report.html").read_text()
    for method in ("pved", "ppo"):
        assert (out / "videos" / f"{method}.gif").stat().st_size > 0
        assert f"{method}: its first evaluation run" in report
    assert report.count('src="data:image/gif;base64,') == 2

    # "what the subspaces learned" of PVED's best evaluation run (`make subspaces`)
    sub = _analyze("subspaces", str(out), "--episodes", "2")
    assert sub.returncode == 0, sub.stderr[-3000:]
    chosen = json.loads((out / "subspaces" / "chosen.json").read_text())
    pved_runs = methods["pved"]["runs"]
    assert chosen["final"] == max(r["success_rate"] for r in pved_runs)
    assert chosen["run"] in {r["key"] for r in pved_runs}
    assert f"seed{selection['init']}" == Path(chosen["model"]).name
    assert "Theorem 1" in (out / "subspaces" / "bound.txt").read_text()
    for name in ("tsne_shared.png", "tsne_individual.png", "numbers.json"):
        assert (out / "subspaces" / "tsne" / name).stat().st_size > 0
    assert "Theorem 1" in (out / "subspaces" / "report.html").read_text()

    # the scale of Eq. 10's distance on the training pairs, matched and shuffled
    scaled = _analyze("shaping-scale", str(out), "--rows", "500")
    assert scaled.returncode == 0, scaled.stderr[-3000:]
    scales = json.loads((out / "subspaces" / "shaping_scale.json").read_text())["pairs"]
    assert set(scales["reacher"]) == {"pved"}  # plain PPO has no model
    scale = scales["reacher"]["pved"]
    assert scale["init"] == selection["init"]
    assert 0 <= scale["matched"]["q50"] <= scale["matched"]["q95"]
    assert {"action_swapped", "state_swapped", "other_episode_same_step"} <= set(scale)
    assert 0 <= scale["own_lower_share"] <= 1 and scale["other_episode_rows"] > 0
    if not methods["pved"]["shared_collapsed"]:
        # a model that learned anything puts a step nearer its own pair than a stranger
        assert scale["matched"]["q50"] < scale["shuffled"]["q50"]
    # D at each evaluation run's last rollout is its logged shaping term over -beta
    ends = scale["end_of_runs"]
    assert {p["run"] for p in ends["runs"]} == {r["key"] for r in pved_runs}
    for point in ends["runs"]:
        rows = [json.loads(x) for x in (out / "runs" / point["run"] / "metrics.jsonl").open()]
        last = [r["rollout/reward_shaping"] for r in rows if "rollout/reward_shaping" in r][-1]
        assert point["d_end"] == pytest.approx(-last / selection["beta"])
    if ends["spearman_rho"] is not None:
        lo, hi = ends["spearman_rho_ci"]
        assert -1 <= lo <= hi <= 1
    # the beta search's distances: a row per beta tried with init 0, the medians over the
    # tuning seeds of D at the first and the last rollout
    search = scale["by_beta"]
    tried = sorted(c["beta"] for c in selection["candidates"] if c["init"] == 0)
    assert [row["beta"] for row in search["betas"]] == tried
    for row in search["betas"]:
        run = out / "runs" / "reacher" / "transfer" / f"pved-beta{row['beta']:g}-init0-src0"
        last = []
        for seed in budget.tuning_seeds:
            rows = [json.loads(x) for x in (run / f"seed{seed}" / "metrics.jsonl").open()]
            shaping = [r["rollout/reward_shaping"] for r in rows if "rollout/reward_shaping" in r]
            last.append(-shaping[-1] / row["beta"])
        assert row["runs"] == len(budget.tuning_seeds)
        assert row["d_last"] == pytest.approx(float(np.median(last)))
    # the first rollout comes before any update, so its D is the same at every beta
    first = [row["d_first"] for row in search["betas"]]
    assert first == pytest.approx([first[0]] * len(first))

    # does the pairing relate the agents, and do the codes: refitting the selected PVED
    # at its own alpha3 must give back the very same model
    alpha3 = json.loads(
        (out / "runs" / "reacher" / "model" / "pved" / f"seed{init}" / "config.json").read_text()
    )["config"]["model_config"]["alpha3"]
    measured = _analyze(
        "pairing-signal",
        str(out),
        *("--rows", "2000", "--code-rows", "500", "--alpha3", f"{alpha3:g}", "0"),
    )
    assert measured.returncode == 0, measured.stderr[-3000:]
    pairing = json.loads((out / "subspaces" / "pairing_signal.json").read_text())["pairs"]
    r2 = pairing["reacher"]["pairing_r2"]
    assert abs(r2["source_to_shuffled_target"]) < 0.05 < r2["source_to_target"] < 1
    codes = pairing["reacher"]["models"]
    selected = codes[f"pved (init {init})"]
    assert codes[f"pved (init {init}), α3 = {alpha3:g}"] == selected
    assert selected["matched"] == scale["matched"]  # the same rows as shaping_scale's
    assert codes[f"pved (init {init}), α3 = 0"] != selected
    # the source bank on the target task, which the transfer runs draw their term from
    assert selected["kl_prior_bank"] > 0 and selected["bank_vs_target"]["q50"] >= 0
    # the same measures of a dataset and a model on their own (e.g. another alignment's)
    model_path = out / "runs" / "reacher" / "model" / "pved" / f"seed{init}" / "model.pt"
    alone = _analyze(
        "pairing-signal",
        "--datasets",
        str(next((out / "runs" / "reacher" / "pairs").glob("*/seed0/pairs.npz"))),
        *("--rows", "2000", "--code-rows", "500", "--model", str(model_path)),
    )
    assert alone.returncode == 0, alone.stderr[-3000:]
    assert f"| {r2['source_to_target']:.3f} | {r2['target_to_source']:.3f} |" in alone.stdout
    matched = selected["matched"]
    assert f"| {matched['q50']:.3g} / {matched['mean']:.3g} |" in alone.stdout

    # another budget's protocol of the pair may start from this one's earlier stages
    # (`--stages-from`): the plan's own stage functions take the copies as done
    later = tmp_path / "later"
    made = [
        run.parent
        for stage in COPYABLE_STAGES
        for run in (out / "runs" / "reacher" / stage).glob("*/seed*/result.json")
    ]
    assert copy_stage_runs(out, later, ["reacher"]).copied == len(made) > 0
    assert copy_stage_runs(out, later, ["reacher"]).copied == 0  # nothing is copied twice
    assert not (later / "runs" / "reacher" / "transfer").exists()
    copied_model = later / "runs" / "reacher" / "model" / "pved" / "seed0"
    assert json.loads((copied_model / "result.json").read_text())["model"] == str(
        copied_model / "model.pt"
    )  # the copy's own model, not the other protocol's
    copied_pairs = next((later / "runs" / "reacher" / "pairs").glob("*/seed0"))
    assert json.loads((copied_pairs / "result.json").read_text())["dataset"] == str(
        copied_pairs / "pairs.npz"
    )
    stage_jobs = [
        job
        for job in ProtocolPlan(["reacher"], ["pved", "ppo"], "smoke", later).expand({})
        if "/transfer/" not in job.key
    ]
    assert {job.run_dir for job in stage_jobs} <= {
        later / "runs" / r.relative_to(out / "runs") for r in made
    }
    for job in stage_jobs:
        assert job.run_dir is not None
        result = job.run_dir / "result.json"
        written = result.stat().st_mtime_ns
        job.fn(**job.kwargs)
        assert result.stat().st_mtime_ns == written, job.key  # not made again

    # a plan of the same steps per transfer run also takes the finished transfer runs,
    # and its own transfer jobs find them done
    # (of the methods it has: here plain PPO's, not PVED's)
    same_steps = tmp_path / "same-steps"
    plan = ProtocolPlan(["reacher"], ["ppo"], "smoke", same_steps)
    atomic_write_json(same_steps / PLAN_FILE, plan.describe())
    ppo_made = list((out / "runs" / "reacher" / "transfer" / "ppo").glob("seed*/result.json"))
    assert copy_stage_runs(out, same_steps, ["reacher"]).copied == len(made) + len(ppo_made)
    assert [p.name for p in (same_steps / "runs" / "reacher" / "transfer").iterdir()] == ["ppo"]
    ppo_jobs = [j for j in plan.expand({}) if "/transfer/ppo/" in j.key]
    assert ppo_jobs
    for job in ppo_jobs:
        assert job.run_dir is not None
        result = job.run_dir / "result.json"
        written = result.stat().st_mtime_ns
        assert job.fn(**job.kwargs)["policy"] == str(job.run_dir / "policy.pt")
        assert result.stat().st_mtime_ns == written, job.key  # not made again

    # the same directory with other settings is refused, in one line
    other_cmd = [*PVED, "protocol", "--pair", "reacher", "--methods", "ppo", "--out", str(out)]
    other = subprocess.run(other_cmd, env=_env(), capture_output=True, text=True)
    assert other.returncode == 2
    assert other.stderr.strip().count("\n") == 0 and "other settings" in other.stderr


@pytest.mark.parametrize(
    ("name", "method"),
    [
        ("pved-beta0.001-init0-src0", "pved"),
        ("pved-vae-beta1e-05-init2-src1", "pved-vae"),
        ("gupta2017-beta10-init1-src2", "gupta2017"),
        ("ppo", "ppo"),
        ("oracle", "oracle"),
    ],
)
def test_a_transfer_run_name_gives_back_its_method(name: str, method: str) -> None:
    assert transfer_run_method(name) == method
    if name != method:
        beta = float(name.split("-beta")[1].split("-init")[0])
        init, source = (int(x) for x in name.split("-init")[1].split("-src"))
        assert transfer_run_name(method, beta, init, source) == name


def test_the_paper_wide_budget_is_the_paper_protocol_with_more_evaluation_runs(
    tmp_path: Path,
) -> None:
    paper = ProtocolPlan(["walker-hopper"], ["ppo"], "paper", tmp_path / "paper")
    wide = ProtocolPlan(["walker-hopper"], ["ppo"], "paper-wide", tmp_path / "wide")
    assert wide.describe()["transfer_steps"] == paper.describe()["transfer_steps"]
    assert "steps_of" not in paper.describe()["budget"]  # older plans still match

    def runs(plan: ProtocolPlan) -> dict[str, str]:
        specs = {}
        for job in plan.expand({}):
            args = {k: v for k, v in job.kwargs.items() if k not in ("runs_root", "progress")}
            specs[job.key] = config_hash(transfer_spec(**args).config)
        return specs

    paper_runs, wide_runs = runs(paper), runs(wide)
    # each paper run is in the wide plan under the same name and config: copied, not redone
    assert paper_runs.items() <= wide_runs.items()
    assert len(paper_runs) == 15 and len(wide_runs) == 81
    # issue 64's 45 runs a method lie between the two: copied from either
    mid = runs(ProtocolPlan(["walker-hopper"], ["ppo"], "paper-45", tmp_path / "45"))
    assert paper_runs.items() <= mid.items() <= wide_runs.items() and len(mid) == 45


def test_the_screen_budget_never_runs_a_seed_the_other_budgets_judge(tmp_path: Path) -> None:
    quick = ProtocolPlan(["reacher"], ["ppo"], "quick", tmp_path / "quick")
    screen = ProtocolPlan(["reacher"], ["ppo"], "screen", tmp_path / "screen")
    assert screen.describe()["transfer_steps"] == quick.describe()["transfer_steps"]
    assert get_budget("screen").tuning_seeds == get_budget("quick").tuning_seeds

    def seeds(budget: str) -> set[int]:
        plan = ProtocolPlan(["reacher"], ["ppo"], budget, tmp_path / budget)
        # a reference runs evaluation seed s as s, s+1, s+2; a shaped method as s, 3 times
        return {int(j.kwargs["seed"]) for j in plan.expand({})}

    judged_budgets = ("quick", "paper", "paper-45", "paper-wide")
    judged = set().union(*(seeds(b) for b in judged_budgets))
    judged |= {int(s) for b in judged_budgets for s in get_budget(b).evaluation_seeds}
    screened = seeds("screen")
    assert len(screened) == 15 and not screened & judged


def test_a_selection_made_elsewhere_is_evaluated_without_tuning(tmp_path: Path) -> None:
    screen = Path(__file__).resolve().parents[1] / "docs/protocol/reacher-quick-align"
    fixed = fixed_selections(screen, ["reacher"], ["pved-align", "ppo"], "paper")
    chosen = fixed["reacher"]["pved-align"]
    assert (chosen["beta"], chosen["init"], chosen["budget"]) == (1.0, 0, "quick")
    plan = ProtocolPlan(["reacher"], ["pved-align", "ppo"], "paper", tmp_path, fixed)
    jobs = plan.expand({})
    budget = get_budget("paper")
    shaped = [j for j in jobs if "/transfer/pved-align" in j.key]
    # no tuning run: the 15 evaluation runs at the screen's beta and init, at once
    assert len(shaped) == budget.source_policies * len(budget.evaluation_seeds)
    assert not set(budget.tuning_seeds) & {j.kwargs["seed"] for j in shaped}
    assert all(j.kwargs["beta"] == 1.0 and j.tags["init"] == 0 for j in shaped)
    assert _keys(plan.evaluation_jobs("reacher", "pved-align")) == _keys(shaped)
    assert "reacher/model/pved/init0" in {j.key for j in jobs if j.end_product}
    assert plan.selection["reacher"]["pved-align"]["selected_in"]["budget"] == "quick"
    # the plan file records it, and a protocol reloaded from it plans the same runs
    (tmp_path / PLAN_FILE).write_text(json.dumps(plan.describe()))
    assert _keys(ProtocolPlan.load(tmp_path).expand({})) == _keys(jobs)
    expected = plan.expected_steps()
    tuned = ProtocolPlan(["reacher"], ["pved-align", "ppo"], "paper", tmp_path / "t")
    assert expected < tuned.expected_steps()
    # the paper protocol's own plan is unchanged without it
    assert "selection_from" not in tuned.describe()


def test_a_selection_that_saw_an_evaluation_seed_is_refused(tmp_path: Path) -> None:
    screen = tmp_path / "screen"
    screen.mkdir()
    budget = dataclasses.asdict(get_budget("quick"))
    budget["tuning_seeds"] = [get_budget("paper").evaluation_seeds[0]]
    (screen / PLAN_FILE).write_text(json.dumps({"budget": budget}))
    (screen / "selection.json").write_text(
        json.dumps({"reacher": {"pved": {"beta": 0.1, "init": 0, "candidates": []}}})
    )
    with pytest.raises(PvedError, match=r"tuned on seeds .* that the paper budget evaluates on"):
        fixed_selections(screen, ["reacher"], ["pved"], "paper")
    budget["tuning_seeds"] = [2000]
    (screen / PLAN_FILE).write_text(json.dumps({"budget": budget}))
    with pytest.raises(PvedError, match="no finished selection of pved-align on reacher"):
        fixed_selections(screen, ["reacher"], ["pved-align"], "paper")
    assert fixed_selections(screen, ["reacher"], ["pved", "ppo"], "paper")["reacher"]["pved"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--pair", "nope"], "unknown pair"),
        (["--pair", "reacher", "--selection-from", "nowhere"], "not a protocol directory"),
        (["--pair", "reacher", "--methods", "pved", "magic"], "unknown method"),
        (["--pair", "reacher", "--budget", "huge"], "unknown budget"),
        (["--pair", "reacher", "--stages-from", "nowhere"], "not a protocol directory"),
        # each of several sources is checked before anything is copied or written
        (
            [
                "--pair",
                "reacher",
                "--stages-from",
                str(Path(__file__).resolve().parents[1] / "docs/protocol/reacher-quick"),
                "nowhere",
            ],
            "--stages-from nowhere is not a protocol directory",
        ),
    ],
)
def test_protocol_bad_input_is_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    res = subprocess.run(
        [*PVED, "protocol", *args, "--out", str(tmp_path / "o")],
        env=_env(),
        capture_output=True,
        text=True,
    )
    assert res.returncode == 2
    assert res.stderr.startswith("pved: error:") and message in res.stderr
    assert res.stderr.strip().count("\n") == 0
    assert not (tmp_path / "o").exists()


def test_plot_of_a_directory_that_is_no_protocol(tmp_path: Path) -> None:
    res = subprocess.run([*PVED, "plot", str(tmp_path)], env=_env(), capture_output=True, text=True)
    assert res.returncode == 2 and "not a protocol directory" in res.stderr


def _analyze(analysis: str, *args: str) -> subprocess.CompletedProcess[str]:
    """Run ``pved analyze <analysis>`` with ``args`` as a user would, output captured."""
    return subprocess.run(
        [*PVED, "analyze", analysis, *args], env=_env(), capture_output=True, text=True
    )


def test_ridge_r2_is_the_share_of_variance_one_side_predicts_on_held_out_episodes() -> None:
    import numpy as np

    from pved.diagnostics.pairing_signal import ridge_r2

    rng = np.random.default_rng(0)
    x = rng.normal(size=(20_000, 3))
    episode = np.repeat(np.arange(200), 100)
    # y0 = x0 + noise of the same variance: half of it predictable; y1 constant, ignored
    y = np.stack([x[:, 0] + rng.normal(size=len(x)), np.full(len(x), 3.0)], 1)
    assert ridge_r2(x, y, episode) == pytest.approx(0.5, abs=0.03)
    assert ridge_r2(x, x[:, :2] @ np.array([[1.0, 2.0], [-1.0, 0.5]]), episode) > 0.97
    # unrelated rows: nothing to predict, and the fit on the other episodes does not leak
    assert abs(ridge_r2(x, rng.normal(size=(len(x), 2)), episode)) < 0.03


def test_pairing_signal_refuses_a_corrupt_dataset_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "pairs.npz"
    bad.write_bytes(b"not a dataset")
    res = _analyze("pairing-signal", "--datasets", str(bad))
    assert res.returncode == 2 and res.stdout == ""  # no half-printed table
    assert res.stderr.strip().count("\n") == 0 and "corrupt" in res.stderr
    usage = _analyze("pairing-signal", "--model", str(bad))  # --model needs --datasets
    assert usage.returncode == 2 and "--datasets" in usage.stderr
    assert usage.stderr.strip().count("\n") == 0


def test_repairing_by_phase_finds_the_partner_a_lag_took_away() -> None:
    from pved.diagnostics import pairing_signal
    from pved.pairing.dataset import PairedDataset

    rng = np.random.default_rng(0)
    episodes, length, stride = 60, 200, 10
    t = np.tile(np.arange(length), episodes)
    episode = np.repeat(np.arange(episodes), length)
    # both agents stride every 10 rows, but each episode's source runs a few rows ahead
    # or behind, so its time partner is at a random moment of the stride
    lag = rng.integers(-5, 6, size=episodes)[episode]
    angle_t, angle_s = 2 * np.pi * t / stride, 2 * np.pi * (t + lag) / stride
    # the gait moves several coordinates together, so it is each agent's first component
    # of the standardised state, as on the locomotion pairs
    obs_t = np.stack([np.cos(angle_t), np.cos(angle_t + 0.3), np.sin(angle_t)], 1)
    obs_s = np.stack([np.cos(angle_s + k) for k in (0.0, 0.2, 0.4, 1.6)], 1)
    order = rng.permutation(len(t))  # stored out of time order: the analysis must sort
    dataset = PairedDataset(
        obs_source=obs_s[order],
        act_source=rng.normal(size=(len(t), 2))[order],
        obs_target=obs_t[order],
        act_target=np.cos(angle_t - 0.5)[order, None],
        episode=episode[order],
        t_source=t[order],
        t_target=t[order],
        task={},
        header={
            "robot_state_indices_source": [0, 1, 2, 3],
            "robot_state_indices_target": [0, 1, 2],
        },
    )
    x_s, x_t = dataset.model_inputs()

    def r2(source_rows: np.ndarray | None = None) -> float:
        paired = x_s if source_rows is None else x_s[source_rows]
        return pairing_signal.pairing_r2(paired, x_t, dataset.episode, len(t), 0)[
            "source_to_target"
        ]

    as_paired = r2()
    by_phase = pairing_signal.repaired_source_rows(dataset, "phase", 0)
    at_random = pairing_signal.repaired_source_rows(dataset, "random in window", 0)
    assert as_paired < 0.3 and r2(by_phase) > 0.8 and r2(at_random) < 0.3
    for rows in (by_phase, at_random):  # a partner never leaves its episode or window
        assert (dataset.episode[rows] == dataset.episode).all()
        assert np.abs(dataset.t_source[rows] - dataset.t_target).max() <= 10
    direction = pairing_signal.repaired_source_rows(dataset, "random-direction phase", 0)
    assert (dataset.episode[direction] == dataset.episode).all()
    with pytest.raises(PvedError, match="unknown re-pairing"):
        pairing_signal.repaired_source_rows(dataset, "dtw", 0)


class _PartCodes:
    """A stand-in model whose D reads one part of the target step: its first
    ``state_dim`` columns (a state code) or the rest (an action code)."""

    def __init__(self, part: slice) -> None:
        self.part = part

    def shaping(self, x_s: torch.Tensor, x_t: torch.Tensor) -> torch.Tensor:
        return ((x_s[:, self.part] - x_t[:, self.part]) ** 2).sum(1)


def test_swapping_a_part_of_the_target_step_moves_d_only_if_the_code_reads_it() -> None:
    import numpy as np

    from pved.diagnostics.shaping_audit import matched_and_shuffled
    from pved.diagnostics.shaping_scale import target_part_swapped

    rng = np.random.default_rng(0)
    x_t = rng.normal(size=(400, 5)).astype(np.float32)  # 3 state columns, 2 action
    x_s = x_t + 0.01 * rng.normal(size=x_t.shape).astype(np.float32)
    for part, unmoved, moved in (
        (slice(0, 3), "action", "state"),
        (slice(3, 5), "state", "action"),
    ):
        model = _PartCodes(part)
        swapped = target_part_swapped(model, x_s, x_t, 3, rows=300, seed=1)
        both = matched_and_shuffled(model, x_s, x_t, rows=300, seed=1)
        # the same rows as matched_and_shuffled's: the part the code ignores changes nothing
        assert swapped[f"{unmoved}_swapped"] == both["matched"]
        assert swapped[f"{moved}_swapped"] == both["shuffled"]
        assert both["shuffled"]["q50"] > 100 * both["matched"]["q50"]
    with pytest.raises(ValueError, match="does not split"):
        target_part_swapped(_PartCodes(slice(0, 3)), x_s, x_t, 5, rows=10, seed=0)


def test_another_episodes_source_step_is_farther_only_if_the_code_reads_the_episode() -> None:
    import numpy as np

    from pved.diagnostics.shaping_scale import other_episode_same_step

    rng = np.random.default_rng(0)
    episode, step = np.repeat(np.arange(40), 10), np.tile(np.arange(10), 40)
    # column 0 is the step, the same in every episode; columns 1-4 are the episode's own
    x_t = np.column_stack([step, rng.normal(size=(400, 4))]).astype(np.float32)
    x_s = x_t + 0.01 * rng.normal(size=x_t.shape).astype(np.float32)
    where = other_episode_same_step(_PartCodes(slice(1, 5)), x_s, x_t, episode, step, 300, 2)
    assert where["own_lower_share"] == 1.0 and where["other_episode_rows"] == 300
    assert where["other_episode_same_step"]["q50"] > 100 * 0.01**2
    # a code that reads only when: another episode's step is as near as its own
    when = other_episode_same_step(_PartCodes(slice(0, 1)), x_s, x_t, episode, step, 300, 2)
    assert 0.35 < when["own_lower_share"] < 0.65
    with pytest.raises(ValueError, match="no row has a partner"):
        other_episode_same_step(
            _PartCodes(slice(0, 1)), x_s, x_t, np.zeros(400, dtype=int), step, 10, 0
        )


def test_spearman_by_seed_counts_degenerate_resamples_as_no_association() -> None:
    import numpy as np

    from pved.diagnostics.shaping_scale import spearman_by_seed

    # five seeds, three runs each; only seed 3's runs score, and they end nearest
    seeds = [s for s in range(5) for _ in range(3)]
    d_end = np.array([5.0, 6, 7, 5, 6, 7, 5, 6, 7, 1, 2, 3, 5, 6, 7])
    score = np.array([0.0] * 9 + [1.0, 1.0, 1.0] + [0.0] * 3)
    rho, ci = spearman_by_seed(d_end, score, seeds)
    assert rho is not None and rho < -0.5
    # a resample without seed 3 has no scoring run: rho 0 there, so 0 is inside
    assert ci is not None and ci[0] < rho and ci[1] == pytest.approx(0.0)
    # every run alike: no rho to give
    assert spearman_by_seed(d_end, np.zeros(15), seeds) == (None, None)
    # seeds that each score alike and end alike: an exact, stable association
    rho, ci = spearman_by_seed(np.arange(15.0), -np.arange(15.0), seeds)
    assert rho == pytest.approx(-1.0) and ci == pytest.approx([-1.0, -1.0])


def test_a_shaped_run_made_before_the_eq10_fixes_is_made_again(tmp_path: Path) -> None:
    # Restored or copied runs cannot be checked by their config hash (their model and bank
    # are gone), so a shaped run is taken only where its config says Eq. 10 was computed
    # as it is now (bank time base, mean action, unclipped scaled reward): else it is made again.
    from pved.experiments.transfer_spec import eq10_config
    from pved.protocol.plan import finished_results
    from pved.protocol.runner import read_job_result

    plan = ProtocolPlan(["reacher"], ["pved", "ppo"], "smoke", tmp_path)
    jobs = plan.expand({})
    shaped = next(j for j in jobs if j.key.startswith("reacher/transfer/pved-"))
    ppo = next(j for j in jobs if "/transfer/ppo/" in j.key)
    assert (
        shaped.required_config == eq10_config(get_preset("reacher").pairing.align)
        and not ppo.required_config
    )
    old_config = {"stage": "transfer", "method": "pved", "beta": 0.1}
    for job, config in ((shaped, old_config), (ppo, {"stage": "transfer", "method": "ppo"})):
        assert job.run_dir is not None
        job.run_dir.mkdir(parents=True)
        (job.run_dir / "config.json").write_text(json.dumps({"config": config}))
        (job.run_dir / "result.json").write_text(json.dumps(_fake(0.5)))
    assert read_job_result(shaped.run_dir, shaped.required_config) is None
    assert read_job_result(ppo.run_dir, ppo.required_config) == _fake(0.5)
    finished = finished_results(plan)
    assert ppo.key in finished and shaped.key not in finished
    # the same run with today's entries counts
    assert shaped.run_dir is not None
    new_config = {**old_config, **eq10_config(get_preset("reacher").pairing.align)}
    (shaped.run_dir / "config.json").write_text(json.dumps({"config": new_config}))
    assert read_job_result(shaped.run_dir, shaped.required_config) == _fake(0.5)
    assert shaped.key in finished_results(plan)


def test_screen_auc_chooses_by_the_area_where_screen_chooses_by_the_final(tmp_path: Path) -> None:
    # two betas: 0.1 learns early and ends at 0.98, 10 learns late and ends at 1.0
    curves = {0.1: [0.0, 1.0, 1.0, 0.98], 10.0: [0.0, 0.0, 0.0, 1.0]}
    groups: dict[tuple[float, int], list[Job]] = {}
    results: dict[str, Any] = {}
    for beta, values in curves.items():
        jobs = []
        for seed in (2000, 4000, 6000):
            key = f"reacher/transfer/b{beta}/seed{seed}"
            run_dir = tmp_path / key
            run_dir.mkdir(parents=True)
            lines = [
                json.dumps({"step": 100 * i, "eval/success_rate": v}) for i, v in enumerate(values)
            ]
            (run_dir / "metrics.jsonl").write_text("\n".join(lines) + "\n")
            results[key] = {"final/success_rate": values[-1], "final/return_mean": -3.0}
            jobs.append(Job(key=key, fn=transfer, run_dir=run_dir))
        groups[(beta, 0)] = jobs
    by_final = _candidates(groups, results, "success_rate")
    by_area = _candidates(groups, results, "success_rate", "auc")
    assert _best(by_final).beta == 10.0 and _best(by_area).beta == 0.1
    assert by_area[0].scores == (pytest.approx((0.5 + 1.0 + 0.99) / 3),) * 3
    assert get_budget("screen-auc").select_by == "auc" and get_budget("screen").select_by == "final"
    # the same runs: screen-auc's seeds and steps are screen's
    for field in ("tuning_seeds", "evaluation_seeds", "steps_budget", "source_policies"):
        assert getattr(get_budget("screen-auc"), field) == getattr(get_budget("screen"), field)
    with pytest.raises(PvedError, match="select_by"):
        dataclasses.replace(get_budget("screen"), select_by="median")
    # a tuning run without its curve cannot be scored by its area: said, not guessed
    (groups[(0.1, 0)][0].run_dir / "metrics.jsonl").unlink()
    with pytest.raises(PvedError, match="no learning curve"):
        _candidates(groups, results, "success_rate", "auc")


def test_a_trained_source_that_fails_its_own_task_is_passed_over(tmp_path: Path) -> None:
    # reacher ships one Push policy (seed 0); sources 1 and 2 are trained, seeds 1 and 2
    plan = ProtocolPlan(["reacher"], ["pved"], "quick", tmp_path / "out")

    def bank_source(jobs: list[Job]) -> tuple[str, ...]:
        return next(j for j in jobs if j.key == "reacher/bank/src2").deps

    def finish(seed: int, rate: float) -> None:
        run = plan.runs / f"reacher/policy/Reacher3-Push/seed{seed}"
        run.mkdir(parents=True, exist_ok=True)
        atomic_write_json(run / "result.json", {"eval/success_rate": rate})

    assert bank_source(plan.expand({})) == ("policy/Reacher3-Push/seed2",)
    finish(2, 1.0)  # a policy that does its task stays
    assert bank_source(plan.expand({})) == ("policy/Reacher3-Push/seed2",)
    finish(2, 0.0)  # one that never succeeds gives its place to the next seed
    jobs = plan.expand({})
    assert bank_source(jobs) == ("policy/Reacher3-Push/seed3",)
    bank = next(j for j in jobs if j.key == "reacher/bank/src2")
    assert Path(bank.kwargs["source_policy"]).parent.name == "seed3"
    finish(1, 0.2)  # source 1 too: sources 1 and 2 are now seeds 3 and 4
    jobs = plan.expand({})
    assert [next(j for j in jobs if j.key == f"reacher/bank/src{k}").deps for k in (1, 2)] == [
        ("policy/Reacher3-Push/seed3",),
        ("policy/Reacher3-Push/seed4",),
    ]
    for seed in range(3, 9):  # at most five passed over, then the next seed as it is
        finish(seed, 0.0)
    assert bank_source(plan.expand({})) == ("policy/Reacher3-Push/seed7",)
