"""A protocol's finished runs, slimmed to what a later machine needs to carry it on.

A protocol at the ``quick`` budget takes days of one core, more than one working session
on a machine whose disk may not outlive it. ``pved archive save`` copies what its
finished runs established into a small directory kept beside the repository (run
directories, models and policies are not committed; ``make archive`` uses
``archive/<pair>-<budget>/``); ``pved archive
restore`` puts it back into a protocol directory, where ``pved protocol`` takes those runs
as done and goes on with the rest.

What is kept, per finished run (a run directory with ``result.json``):

- every run: ``result.json``, ``config.json``;
- policy and model runs: ``metrics.jsonl`` in full and the artefact the later stages
  read (``policy.pt``, ``model.pt``): the transfer runs still to come need them, and their
  digests are part of those runs' config hashes;
- transfer runs: the evaluation rows of ``metrics.jsonl`` (the learning curves that
  ``summary.json``, ``pved plot`` and ``pved claims`` read; the PPO loss rows stay in the
  run's TensorBoard file), and ``policy.pt`` for PVED's own runs, which ``make
  subspaces`` analyses (a run restored from a summary has none to keep).

Left out: checkpoints and TensorBoard files, unfinished runs, and the pairing datasets and
source banks (tens to hundreds of MB a pair): the protocol rebuilds those from the shipped
policies when a restored plan needs them.

What is committed is smaller still: ``pved archive summary`` writes the protocol's
``protocol.json`` and one file, ``finished-transfer-runs.json``, that maps each finished
transfer run (by its path under ``runs/``) to its ``result``, ``config`` and evaluation
``curve`` (``make archive`` keeps it in ``docs/protocol/<pair>-<budget>/``). ``restore``
reads either kind of directory; from a summary the runs come back without their
policies, and the protocol makes again only what the runs still to come need. A
summary directory of a finished protocol also holds what ``make publish`` copied there
(``summary.json``, ``summary.md``, ``selection.json``); those come back too, so the
restored protocol reads as finished and ``pved claims`` judges it from its runs, learning
curves included (from the published summary alone it cannot judge what the curves
decide: the early-speed and stability parts).
"""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pved.checks import check_writable
from pved.errors import PvedError
from pved.experiments.stages import train_model, train_policy, transfer
from pved.protocol.plan import PLAN_FILE, ProtocolPlan, finished_results, relative_plan
from pved.record_paths import record_path
from pved.runs import RESTORED_FROM, atomic_write_bytes, atomic_write_json, repoint_result

RUNS = "runs"
#: the stages whose finished runs are archived, and the artefact each one's result names
ARTEFACTS = {train_policy: "policy.pt", train_model: "model.pt"}
#: transfer runs of this method keep their policy (the subspaces report reads it)
POLICY_KEPT_FOR = "pved"
#: the committed record of a protocol's finished transfer runs (module docstring)
SUMMARY_FILE = "finished-transfer-runs.json"
#: where a transfer run lives under ``runs/``: ``<pair>/transfer/<run name>/seed<seed>``
TRANSFER_REL = re.compile(r"[A-Za-z0-9_-]+/transfer/[A-Za-z0-9_.+-]+/seed[0-9]+")
#: what ``make publish`` puts beside a finished protocol's record, in the order a restore
#: writes them: ``summary.json`` last, since it is what marks a protocol finished
PUBLISHED_FILES = ("selection.json", "summary.md", "summary.json")


def _eval_rows(metrics: bytes) -> bytes:
    """The lines of a ``metrics.jsonl`` that carry an evaluation (``eval/...``) value."""
    kept = []
    for line in metrics.decode().splitlines():
        if not line.strip():
            continue
        row = json.loads(line)
        if any(key.startswith("eval/") for key in row):
            kept.append(line)
    return ("\n".join(kept) + "\n").encode() if kept else b""


def _archived_files(job_fn: Any, method: str | None, run_dir: Path) -> Iterator[tuple[str, bytes]]:
    """(name, content) of what the archive keeps of one finished run directory,
    ``result.json`` last: it marks an archived run as whole, so a commit taken while a
    save is under way holds no run without its artefact."""
    metrics = run_dir / "metrics.jsonl"
    if job_fn is transfer:
        if metrics.exists():
            yield "metrics.jsonl", _eval_rows(metrics.read_bytes())
        # a run restored from a summary has no policy, and its result names none (a
        # result that names one whose file is gone is damaged, and fails here)
        result = json.loads((run_dir / "result.json").read_text())
        if method == POLICY_KEPT_FOR and "policy" in result:
            yield "policy.pt", (run_dir / "policy.pt").read_bytes()
    else:
        if metrics.exists():
            yield "metrics.jsonl", metrics.read_bytes()
        yield ARTEFACTS[job_fn], (run_dir / ARTEFACTS[job_fn]).read_bytes()
    for name in ("config.json", "result.json"):
        yield name, (run_dir / name).read_bytes()


def _plan_record(protocol_dir: Path) -> bytes:
    """The protocol's ``protocol.json`` as a record holds it: a plan written before paths
    in records were relative gets them relative (:func:`relative_plan`), in the layout
    ``atomic_write_json`` gives, so a plan already relative is copied byte for byte."""
    plan = json.loads((protocol_dir / PLAN_FILE).read_text())
    return (json.dumps(relative_plan(plan), indent=2) + "\n").encode()


def _write_if_changed(path: Path, content: bytes) -> bool:
    """Write ``content`` to ``path`` atomically unless it holds it already; True if written."""
    if path.exists() and path.read_bytes() == content:
        return False
    atomic_write_bytes(path, content)
    return True


def save_archive(protocol_dir: Path | str, archive_dir: Path | str) -> dict[str, int]:
    """Copy the protocol's finished policy, model and transfer runs, slimmed (module
    docstring), and its ``protocol.json`` into ``archive_dir``; returns counts:
    ``written`` (runs new or changed in the archive) and ``unchanged``.

    Files are written atomically and only when their content changed, so saving again
    after more runs finish adds those runs and leaves the rest untouched."""
    plan = ProtocolPlan.load(Path(protocol_dir))
    archive = check_writable("--archive", archive_dir)
    results = finished_results(plan)
    counts = {"written": 0, "unchanged": 0}
    archive.mkdir(parents=True, exist_ok=True)
    _write_if_changed(archive / PLAN_FILE, _plan_record(plan.out))
    for job in plan.expand(results):
        if job.key not in results or job.run_dir is None:
            continue
        if job.fn is not transfer and job.fn not in ARTEFACTS:
            continue  # pairing datasets and source banks: rebuilt where needed
        rel = job.run_dir.relative_to(plan.runs)
        try:
            files = list(_archived_files(job.fn, job.kwargs.get("method"), job.run_dir))
        except (OSError, ValueError, UnicodeDecodeError) as err:
            raise PvedError(f"finished run {job.key} cannot be archived: {err}") from None
        # a list, not a generator: every changed file is written, not just the first
        changed = [_write_if_changed(archive / RUNS / rel / name, c) for name, c in files]
        counts["written" if any(changed) else "unchanged"] += 1
    return counts


def save_summary(protocol_dir: Path | str, summary_dir: Path | str) -> dict[str, int]:
    """Write the protocol's ``protocol.json`` and ``finished-transfer-runs.json`` (module
    docstring) into ``summary_dir``; returns counts: ``runs`` summarised and ``written``
    (1 when the summary changed, 0 when it already held them all).

    Keys are sorted and the file indented, so that a commit of a later summary shows the
    runs that finished since as added lines."""
    plan = ProtocolPlan.load(Path(protocol_dir))
    check_writable("--archive", summary_dir)
    results = finished_results(plan)
    runs: dict[str, Any] = {}
    for job in plan.expand(results):
        if job.fn is not transfer or job.key not in results or job.run_dir is None:
            continue
        try:
            config = json.loads((job.run_dir / "config.json").read_text())
            metrics = job.run_dir / "metrics.jsonl"
            rows = _eval_rows(metrics.read_bytes()).decode() if metrics.exists() else ""
            curve = [json.loads(line) for line in rows.splitlines()]
        except (OSError, ValueError, UnicodeDecodeError) as err:
            raise PvedError(f"finished run {job.key} cannot be summarised: {err}") from None
        rel = str(job.run_dir.relative_to(plan.runs))
        # where a run was restored from is this machine's business, not the record's
        result = {k: v for k, v in results[job.key].items() if k != RESTORED_FROM}
        for key in ("policy", "model", "dataset", "bank"):  # its files, as the protocol holds them
            if isinstance(result.get(key), str):
                result[key] = record_path(result[key], plan.out)
        runs[rel] = {"result": result, "config": config, "curve": curve}
    out = Path(summary_dir)
    out.mkdir(parents=True, exist_ok=True)
    _write_if_changed(out / PLAN_FILE, _plan_record(plan.out))
    text = json.dumps(dict(sorted(runs.items())), indent=1, sort_keys=True) + "\n"
    written = _write_if_changed(out / SUMMARY_FILE, text.encode())
    return {"runs": len(runs), "written": int(written)}


def _summarised_runs(summary_file: Path) -> dict[str, dict[str, Any]]:
    """The summary's runs, each checked: a run path of the expected shape, a result
    under the hash of its config, and a curve of evaluation rows."""
    try:
        runs = json.loads(summary_file.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as err:
        raise PvedError(f"{summary_file} is not readable ({err})") from None
    if not isinstance(runs, dict):
        raise PvedError(f"{summary_file} is not a pved run summary")
    for rel, entry in runs.items():
        where = f"{summary_file}: run {rel}"
        if not TRANSFER_REL.fullmatch(rel):
            raise PvedError(f"{where} is not a transfer run's path")
        if not isinstance(entry, dict) or not all(
            isinstance(entry.get(k), t)
            for k, t in (("result", dict), ("config", dict), ("curve", list))
        ):
            raise PvedError(f"{where} lacks its result, config or curve")
        if entry["result"].get("config_hash") != entry["config"].get("config_hash"):
            raise PvedError(f"{where}: its result and config disagree")
        if not all(
            isinstance(row, dict) and isinstance(row.get("step"), int) for row in entry["curve"]
        ):
            raise PvedError(f"{where} has a curve row without its step")
    return runs


def _check_archived_run(run_dir: Path) -> None:
    """An archived run must be whole: its result under the hash of its config, and the
    artefact its stage's later runs read."""
    try:
        config = json.loads((run_dir / "config.json").read_text())
        result = json.loads((run_dir / "result.json").read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as err:
        raise PvedError(f"archived run {run_dir} is unreadable ({err})") from None
    if not isinstance(config, dict) or not isinstance(result, dict):
        raise PvedError(f"archived run {run_dir} is not a pved run")
    if result.get("config_hash") != config.get("config_hash"):
        raise PvedError(f"archived run {run_dir}: result.json and config.json disagree")
    inner = config.get("config")
    stage = inner.get("stage") if isinstance(inner, dict) else None
    artefact = {"policy": "policy.pt", "model": "model.pt"}.get(str(stage))
    if artefact is not None and not (run_dir / artefact).is_file():
        raise PvedError(f"archived run {run_dir} lacks its {artefact}")


def _staged_summary_run(entry: dict[str, Any], staged: Path) -> None:
    """A summarised run's directory as the run left it, less what the summary does not
    keep (its policy, the PPO loss rows): ``config.json``, the curve as ``metrics.jsonl``,
    and ``result.json`` without the path to a policy that is not there."""
    staged.mkdir(parents=True)
    atomic_write_json(staged / "config.json", entry["config"])
    lines = "".join(json.dumps(row) + "\n" for row in entry["curve"])
    atomic_write_bytes(staged / "metrics.jsonl", lines.encode())
    atomic_write_json(
        staged / "result.json",
        {k: v for k, v in entry["result"].items() if k not in ("policy", "model")},
    )


def restore_archive(archive_dir: Path | str, protocol_dir: Path | str) -> dict[str, int]:
    """Put the runs of an archive, or of a summary directory (module docstring), into the
    protocol directory ``protocol_dir`` (created with their ``protocol.json`` when new);
    returns counts: ``restored`` and ``exists`` (a run directory is there already: it is
    kept as it is), and ``summary files`` where a finished protocol's published summary
    came back with its runs (module docstring; files already there are kept). A run both
    archived and summarised comes from the archive.

    A protocol directory that holds another plan is refused; every run is checked before
    any is copied (a damaged archive or summary restores nothing), and each run
    directory appears whole or not at all (made beside, then renamed)."""
    archive = Path(archive_dir)
    out = check_writable("--protocol", protocol_dir)
    try:
        archived_plan = json.loads((archive / PLAN_FILE).read_text())
    except FileNotFoundError:
        raise PvedError(f"{archive} is not a protocol archive (no {PLAN_FILE})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise PvedError(f"{archive / PLAN_FILE} is not readable ({err})") from None
    plan = ProtocolPlan.load(archive)  # a plan this version can read
    archived = sorted(f.parent for f in (archive / RUNS).glob("**/result.json"))
    for src in archived:  # all checked first: a bad archive restores nothing
        _check_archived_run(src)
    summarised = {}
    if (archive / SUMMARY_FILE).exists():
        summarised = _summarised_runs(archive / SUMMARY_FILE)
        foreign = [rel for rel in summarised if rel.split("/")[0] not in plan.pairs]
        if foreign:
            raise PvedError(f"{archive / SUMMARY_FILE}: run {foreign[0]} is not of this plan")
    published = _published_summary(archive, plan)
    if (out / PLAN_FILE).exists():
        here = json.loads((out / PLAN_FILE).read_text())
        keys = ("pairs", "methods", "budget", "transfer_steps", "beta_grids")
        if {k: here.get(k) for k in keys} != {k: archived_plan.get(k) for k in keys}:
            raise PvedError(f"{out} holds another protocol than the archive {archive}")
    else:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(out / PLAN_FILE, (archive / PLAN_FILE).read_bytes())
    counts = {"restored": 0, "exists": 0}
    runs = out / RUNS
    runs.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".restore-", dir=runs))
    sources: dict[str, Path | dict[str, Any]] = dict(summarised)
    sources.update({str(src.relative_to(archive / RUNS)): src for src in archived})
    try:
        for rel, source in sorted(sources.items()):
            dest = runs / rel
            if dest.exists():
                counts["exists"] += 1
                continue
            copy = staging / rel
            if isinstance(source, Path):
                shutil.copytree(source, copy)
                repoint_result(copy, dest)
            else:
                _staged_summary_run(source, copy)
            result = json.loads((copy / "result.json").read_text())
            atomic_write_json(copy / "result.json", {**result, RESTORED_FROM: str(archive)})
            dest.parent.mkdir(parents=True, exist_ok=True)
            copy.rename(dest)
            counts["restored"] += 1
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    copied = 0
    for name in published:  # after the runs: a protocol reads as finished once it is whole
        if not (out / name).exists():
            atomic_write_bytes(out / name, (archive / name).read_bytes())
            copied += 1
    if copied:
        counts["summary files"] = copied
    return counts


def _published_summary(archive: Path, plan: ProtocolPlan) -> list[str]:
    """The published files of a finished protocol in ``archive`` (none where it has no
    ``summary.json``), checked to be this plan's."""
    summary_file = archive / "summary.json"
    if not summary_file.is_file():
        return []
    try:
        summary = json.loads(summary_file.read_text())
        pairs, budget = set(summary["pairs"]), summary["budget"]
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as err:
        raise PvedError(f"{summary_file} is not a protocol summary ({err!r})") from None
    if pairs != set(plan.pairs) or budget != plan.budget.name:
        raise PvedError(
            f"{summary_file} summarises another protocol ({sorted(pairs)}, {budget!r}) "
            f"than {archive / PLAN_FILE}"
        )
    return [name for name in PUBLISHED_FILES if (archive / name).is_file()]
