"""A pair's "What the subspaces learned" report from a finished ``pved protocol`` directory.

The paper's section IV.C looks at one transferred target beside its source: the t-SNE of
both agents' shared and individual means on the target task, the frames nearest to marked
points of the shared embedding, and (our addition) Theorem 1's bound on the same rollouts.
This script picks what the protocol selected, PVED's beta and model initialisation, and
among PVED's evaluation runs the one with the best final score (a target that learned the
task, as the paper shows), then runs the three verbs on it:

    pved tsne   --model <selected init> --target-policy <that run> --source-policy <its source>
    pved bound  (the same three) > bound.txt
    pved report --pair PAIR PROTOCOL_DIR tsne/ bound.txt --out report.html

    .venv/bin/python scripts/subspaces_report.py reports/walker-hopper-quick

Outputs go to ``PROTOCOL_DIR/subspaces/`` (``make publish`` copies its figures and
numbers, not the HTML, into ``docs/protocol/``).

A protocol restored from its committed summary on another machine has that run without
its policy (``pved archive``). Then the run is made again from its job in the plan, the
model and bank it needs first where they are not there, and its final score is printed
beside the recorded one: the same computation on the same code, so the same run, unless
the machine's arithmetic differs (docs/decisions.md). The restored record is kept until
the new run has finished, and put back if it fails.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import shutil
import sys
from pathlib import Path
from typing import Any

from pved.cli import main as pved
from pved.config import get_preset
from pved.experiments.protocol import ProtocolPlan, _finished_results, indexed_policy
from pved.experiments.runner import Job
from pved.runs import atomic_write_bytes, atomic_write_json, run_path

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
        raise SystemExit(f"no finished PVED evaluation run of {pair} in the summary")
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
    jobs = {job.key: job for job in plan.expand(_finished_results(plan))}
    job = jobs.get(key)
    if job is None or job.run_dir is None:
        sys.exit(f"{protocol}: {key} is not a run of its plan")
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


def run(cmd: list[str], stdout: Path | None = None) -> None:
    """One ``pved`` verb in this process; a failure stops the script with its exit code."""
    print("pved " + " ".join(cmd), flush=True)
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer) if stdout else contextlib.nullcontext():
        code = pved(cmd)
    if code:
        raise SystemExit(code)
    if stdout:
        atomic_write_bytes(stdout, buffer.getvalue().encode())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("protocol", type=Path, help="a finished `pved protocol` output directory")
    parser.add_argument("--pair", help="the pair (default: the directory's only one)")
    parser.add_argument("--episodes", type=int, default=4, help="rollouts per agent")
    parser.add_argument("--videos", action="store_true", help="embed one rollout per method")
    args = parser.parse_args()

    summary_file = args.protocol / "summary.json"
    if not summary_file.is_file():
        sys.exit(f"{args.protocol}: no summary.json (not a finished `pved protocol` output)")
    summary = json.loads(summary_file.read_text())
    pairs = list(summary["pairs"])
    pair: str | None = args.pair or (pairs[0] if len(pairs) == 1 else None)
    if pair is None or pair not in pairs:
        sys.exit(f"{args.protocol} holds pairs {pairs}; name one with --pair")
    chosen = pick_run(summary, pair)
    match = _RUN_KEY.match(chosen["key"])
    if match is None:
        sys.exit(f"unexpected run key {chosen['key']!r}")
    init, src = int(match["init"]), int(match["src"])
    preset = get_preset(pair)
    runs_root = args.protocol / "runs"
    model = run_path(runs_root, pair, "model", "pved", init)
    source, source_seed, _ = indexed_policy(preset.source_agent, preset.target_task, src, runs_root)
    # under DIR/runs, not the absolute path in the summary: a protocol directory copied
    # back from another machine still works
    target = runs_root / chosen["key"]
    if not (target / "result.json").is_file():
        sys.exit(f"{target}: no result.json (the run's files are not in this directory)")
    if not (target / "policy.pt").is_file():
        metric = summary["pairs"][pair]["metric"]
        remake_policy(args.protocol, chosen["key"], metric, float(chosen[metric]))

    out = args.protocol / "subspaces"
    out.mkdir(exist_ok=True)
    common = ["--pair", pair, "--model", str(model), "--target-policy", str(target)]
    common += ["--source-policy", str(source), "--episodes", str(args.episodes)]
    run(["tsne", *common, "--out", str(out / "tsne")])
    run(["bound", *common], stdout=out / "bound.txt")
    report = [
        "report",
        "--pair",
        pair,
        str(args.protocol),
        str(out / "tsne"),
        str(out / "bound.txt"),
    ]
    run([*report, "--out", str(out / "report.html"), *([] if args.videos else ["--no-videos"])])
    atomic_write_json(
        out / "chosen.json",
        {
            "run": chosen["key"],
            "final": chosen[summary["pairs"][pair]["metric"]],
            "metric": summary["pairs"][pair]["metric"],
            "model": str(model),
            "source_policy": str(source),
            "source_seed": source_seed,
            "episodes": args.episodes,
        },
    )


if __name__ == "__main__":
    main()
