"""A pair's "What the subspaces learned" report from a finished ``pved protocol`` directory.

The paper's section IV.C looks at one transferred target beside its source: the t-SNE of
both agents' shared and individual means on the target task, the frames nearest to marked
points of the shared embedding, and (our addition) Theorem 1's bound on the same rollouts.
This analysis picks what the protocol selected, PVED's beta and model initialisation, and
among PVED's evaluation runs the one with the best final score (a target that learned the
task, as the paper shows), then does on it what these three verbs do:

    pved tsne   --model <selected init> --target-policy <that run> --source-policy <its source>
    pved bound  (the same three) > bound.txt
    pved report --pair PAIR PROTOCOL_DIR tsne/ bound.txt --out report.html

    pved analyze subspaces reports/walker-hopper-quick

Outputs go to ``PROTOCOL_DIR/subspaces/`` (:func:`subspaces_report`; ``make publish``
copies its figures and numbers, not the HTML, into ``docs/protocol/``).

A protocol restored from its committed summary on another machine has that run without
its policy (``pved archive``). Then the run is made again from its job in the plan, the
model and bank it needs first where they are not there, and its final score is printed
beside the recorded one: the same computation on the same code, so the same run, unless
the machine's arithmetic differs (docs/decisions.md). The restored record is kept until
the new run has finished, and put back if it fails.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

from pved.analysis.judge import load_summary
from pved.diagnostics.pair_report import build_pair_report
from pved.diagnostics.transferred import analyze_subspaces, bound
from pved.errors import PvedError
from pved.protocol.plan import ProtocolPlan, finished_results, indexed_policy
from pved.protocol.runner import Job
from pved.record_paths import record_path
from pved.runs import atomic_write_bytes, atomic_write_json, run_path
from pved.spec import get_preset

_RUN_KEY = re.compile(
    r"^(?P<pair>[^/]+)/transfer/pved-beta[^/]*-init(?P<init>\d+)-src(?P<src>\d+)/seed\d+$"
)


def pick_run(summary: dict[str, Any], pair: str) -> dict[str, Any]:
    """PVED's evaluation run with the best final score (ties: the first in the summary)."""
    entry = summary["pairs"][pair]
    metric = entry["metric"]
    runs = [
        r for r in entry["methods"].get("pved", {}).get("runs", []) if r.get(metric) is not None
    ]
    if not runs:
        raise PvedError(f"no finished PVED evaluation run of {pair} in the summary")
    return max(runs, key=lambda r: float(r[metric]))


def _make(job: Job, jobs: dict[str, Job]) -> dict[str, Any]:
    """Run ``job`` after whichever of its dependencies have no result on disk."""
    for dep in job.deps:
        dep_job = jobs[dep]
        if dep_job.run_dir is None or not (dep_job.run_dir / "result.json").is_file():
            print(f"making {dep}, which {job.key} needs", flush=True)
            _make(dep_job, jobs)
    result: dict[str, Any] = job.fn(**job.kwargs)
    return result


def remake_policy(protocol: Path, key: str, metric: str, recorded: float) -> None:
    """Make the finished run ``key`` of ``protocol`` again, for the policy its restored
    record lacks (module docstring); prints its final ``metric`` beside ``recorded``."""
    plan = ProtocolPlan.load(protocol)
    jobs = {job.key: job for job in plan.expand(finished_results(plan))}
    job = jobs.get(key)
    if job is None or job.run_dir is None:
        raise PvedError(f"{protocol}: {key} is not a run of its plan")
    print(f"{key}: restored without its policy; making it again", flush=True)
    aside = job.run_dir.with_name(job.run_dir.name + ".restored")
    job.run_dir.rename(aside)
    try:
        result = _make(job, jobs)
    except BaseException:
        shutil.rmtree(job.run_dir, ignore_errors=True)
        aside.rename(job.run_dir)
        raise
    shutil.rmtree(aside)
    print(f"{key}: final {metric} {result[f'final/{metric}']:.4f}, recorded {recorded:.4f}")


def subspaces_report(
    protocol: Path, pair: str | None = None, episodes: int = 4, videos: bool = False
) -> dict[str, Any]:
    """The report of the module docstring for ``pair`` (default: the directory's only one)
    of the finished protocol directory ``protocol``, into ``protocol/subspaces/``:
    ``tsne/``, ``bound.txt``, ``report.html`` (with ``videos``: one rollout per method
    embedded) and ``chosen.json``, whose content is returned. ``episodes``: rollouts per
    agent."""
    summary = load_summary(protocol)
    pairs = list(summary["pairs"])
    name = pair or (pairs[0] if len(pairs) == 1 else None)
    if name is None or name not in pairs:
        raise PvedError(f"{protocol} holds pairs {pairs}; name one with --pair")
    chosen = pick_run(summary, name)
    match = _RUN_KEY.match(chosen["key"])
    if match is None:
        raise PvedError(f"unexpected run key {chosen['key']!r}")
    init, src = int(match["init"]), int(match["src"])
    preset = get_preset(name)
    runs_root = protocol / "runs"
    model = run_path(runs_root, name, "model", "pved", init)
    source, source_seed, _ = indexed_policy(preset.source_agent, preset.target_task, src, runs_root)
    # under DIR/runs, not the absolute path in the summary: a protocol directory copied
    # back from another machine still works
    target = runs_root / chosen["key"]
    metric = summary["pairs"][name]["metric"]
    if not (target / "result.json").is_file():
        raise PvedError(f"{target}: no result.json (the run's files are not in this directory)")
    if not (target / "policy.pt").is_file():
        remake_policy(protocol, chosen["key"], metric, float(chosen[metric]))

    out = protocol / "subspaces"
    out.mkdir(exist_ok=True)
    analyze_subspaces(name, model, target, out / "tsne", source_policy=source, episodes=episodes)
    # the file `pved bound ... > bound.txt` writes: the summary and a newline
    theorem = bound(name, model, target, source_policy=source, episodes=episodes)
    atomic_write_bytes(out / "bound.txt", (theorem["summary"] + "\n").encode())
    build_pair_report(
        name, [protocol, out / "tsne", out / "bound.txt"], out / "report.html", videos=videos
    )
    record = {
        "run": chosen["key"],
        "final": chosen[metric],
        "metric": metric,
        "model": record_path(model),
        "source_policy": record_path(source),
        "source_seed": source_seed,
        "episodes": episodes,
    }
    atomic_write_json(out / "chosen.json", record)
    return record
