"""Protocol runs made away from the protocol: a batch directory for a machine that
cannot reach the one the protocol runs on (a batch node, a lent machine with no network).

Three steps, each a ``pved batch`` verb:

1. :func:`export_batch` writes the protocol's transfer runs that are ready to start (their
   model and source bank exist) and not started here into a batch directory:
   ``batch.json`` (each run's arguments, paths relative to the batch) and the models and
   banks they read, under ``runs/`` as the protocol lays them out. It claims each run
   for the batch for an hour (by default): a protocol running here meanwhile waits
   for a claimed run instead of making it too, and the next export leaves it out.
2. :func:`run_batch`, on the other machine, runs them side by side, one process each,
   until they are done or a deadline passes; a run killed at the deadline keeps its last
   checkpoint. :func:`pack_batch` puts the run directories into tar files of a given
   size at most, for transports that limit file sizes.
3. :func:`import_batch`, back where the protocol runs, moves each run directory into the
   protocol's ``runs/``, after checking that its config hash is the one the protocol
   would give that run here (same PPO config, budget, model and bank digests). It never
   replaces a run directory that exists; a partial run resumes from its checkpoint when
   the protocol is run again, and a finished one is taken as done. The claim on each
   run the batch sent back ends; :func:`release_batch` ends the rest (runs the other
   machine never started), else they expire.

Only transfer runs travel: the other stages read the pairing dataset (hundreds of MB on
the locomotion pairs) and are few. A batch's runs are the same computation as the
protocol's own; library versions on the other machine may change their last digits.
"""

from __future__ import annotations

import itertools
import json
import multiprocessing
import os
import shutil
import tarfile
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pved import __version__
from pved.checks import check_int, check_number, check_writable
from pved.errors import PvedError
from pved.experiments.stages import transfer
from pved.experiments.transfer_spec import transfer_spec
from pved.protocol.plan import ProtocolPlan, finished_results
from pved.protocol.runner import WORKER_ENV, _environment, _one_line
from pved.runs import (
    atomic_write_json,
    claim_holder,
    config_hash,
    file_digest,
    release_claim,
    repoint_result,
    write_claim,
)

BATCH_FILE = "batch.json"
LOG_FILE = "log.json"
BATCH_FORMAT = "pved-batch"
BATCH_VERSION = 1
#: Job arguments that are paths inside the protocol's ``runs/`` (stored relative to it).
PATH_ARGS = ("model_path", "bank_path")
RUNS = "runs"


@dataclass(frozen=True)
class BatchJob:
    """One exported run: its protocol job key and ``transfer`` arguments, with
    ``runs_root`` left out and :data:`PATH_ARGS` relative to the runs root."""

    key: str
    kwargs: dict[str, Any]
    run_dir: str  # relative to the runs root

    def resolved(self, runs_root: Path) -> dict[str, Any]:
        """The arguments of ``transfer`` for a runs root at ``runs_root``."""
        kwargs = dict(self.kwargs, runs_root=runs_root, progress=False)
        for name in PATH_ARGS:
            if name in kwargs:
                kwargs[name] = runs_root / kwargs[name]
        return kwargs


def _relative(path: Path, root: Path, what: str) -> str:
    try:
        return str(Path(path).resolve().relative_to(root.resolve()))
    except ValueError:
        raise PvedError(f"{what} {path} is outside the protocol's runs ({root})") from None


def _read_batch(batch_dir: Path) -> tuple[dict[str, Any], list[BatchJob]]:
    path = Path(batch_dir) / BATCH_FILE
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise PvedError(f"{batch_dir} is not a batch directory (no {BATCH_FILE})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise PvedError(f"{path} is corrupt ({err})") from None
    if not isinstance(data, dict) or data.get("format") != BATCH_FORMAT:
        raise PvedError(f"{path} is not a pved batch file")
    if data.get("version") != BATCH_VERSION:
        raise PvedError(f"{path} has batch version {data.get('version')}, not {BATCH_VERSION}")
    try:
        jobs = [BatchJob(j["key"], dict(j["kwargs"]), j["run_dir"]) for j in data["jobs"]]
    except (KeyError, TypeError) as err:
        raise PvedError(f"{path} is not a readable batch file ({err})") from None
    return data, jobs


def export_batch(
    protocol_dir: Path | str | Sequence[Path | str],
    batch_dir: Path | str,
    *,
    limit: int | None = None,
    skip: int = 0,
    claim_minutes: float = 60.0,
    max_input_bytes: int | None = None,
) -> list[str]:
    """Write the protocol's transfer runs that can start now and have not started here
    (no run directory, no other batch's claim) into ``batch_dir``, in the order the
    protocol would run them (the tuning runs first), at most ``limit``; returns their
    job keys.

    Each exported run is claimed for the batch for ``claim_minutes`` (0: not claimed),
    so that a protocol running here meanwhile leaves it to the batch instead of making
    it twice; importing a run, or :func:`release_batch`, ends its claim. ``skip``: leave
    the first ``skip`` out anyway (for a protocol started before claims existed).
    ``batch_dir`` must not exist: a batch is written once, then run and imported.

    ``max_input_bytes``: the models and banks the batch carries at most this many bytes
    in all (a transport with a size limit: the device machine's 64 MiB, working tree
    included). A run whose inputs would go past it is passed over, unclaimed, and later
    runs whose inputs the batch already carries (or that need none) are taken instead,
    up to ``limit``.

    Several protocol directories (of different pairs) make one batch, so that one pool
    of workers serves them all: ``limit`` and ``skip`` apply to each protocol, and their
    runs alternate, each protocol's in its own order. Each protocol then imports its own
    runs from the batch's tar files (it counts the others as ``other``)."""
    dirs = [protocol_dir] if isinstance(protocol_dir, (str, Path)) else list(protocol_dir)
    if not dirs:
        raise PvedError("export needs at least one protocol directory")
    batch = Path(batch_dir)
    if batch.exists():
        raise PvedError(f"{batch} exists; a batch goes into a new directory")
    if limit is not None:
        check_int("--limit", limit, low=1)
    check_int("--skip", skip, low=0)
    check_number("--claim-minutes", claim_minutes, low=0.0)
    if max_input_bytes is not None:
        check_int("max_input_bytes", max_input_bytes, low=1)
    check_writable("--batch", batch)
    input_bytes = 0  # of the inputs taken so far, all protocols
    now = time.time()
    per_protocol: list[list[dict[str, Any]]] = []
    claims: list[Path] = []  # the exported runs' directories in their protocols
    inputs: dict[str, str] = {}
    sources: dict[str, Path] = {}  # an input's relative path -> its file here
    plans = [ProtocolPlan.load(Path(d)) for d in dirs]
    for plan in plans:
        results = finished_results(plan)
        ready = [
            job
            for job in plan.expand(results)
            if job.fn is transfer
            and job.key not in results
            and job.run_dir is not None
            and not job.run_dir.exists()
            and claim_holder(job.run_dir, now) is None
            and all(dep in results for dep in job.deps)
        ]
        ready.sort(key=lambda job: job.priority)  # stable: the plan's order within a priority
        jobs: list[dict[str, Any]] = []
        for job in ready[skip:]:
            if limit is not None and len(jobs) >= limit:
                break
            assert job.run_dir is not None
            kwargs = {k: v for k, v in job.kwargs.items() if k not in ("runs_root", "progress")}
            new_inputs: dict[str, Path] = {}  # this run's inputs the batch lacks so far
            for name in PATH_ARGS:
                if name in kwargs:
                    rel = _relative(Path(kwargs[name]), plan.runs, name)
                    kwargs[name] = rel
                    if rel not in sources:
                        new_inputs[rel] = plan.runs / rel
            added = sum(path.stat().st_size for path in new_inputs.values())
            if max_input_bytes is not None and input_bytes + added > max_input_bytes:
                continue
            for name in PATH_ARGS:
                if name in kwargs:
                    rel = kwargs[name]
                    digest = file_digest(plan.runs / rel)
                    if inputs.setdefault(rel, digest) != digest:
                        raise PvedError(
                            f"two protocols have different files at {rel}; "
                            "export protocols of one pair in separate batches"
                        )
            sources.update(new_inputs)
            input_bytes += added
            jobs.append(
                {
                    "key": job.key,
                    "kwargs": kwargs,
                    "run_dir": _relative(job.run_dir, plan.runs, "run"),
                }
            )
            claims.append(job.run_dir)
        per_protocol.append(jobs)
    # alternate the protocols' runs, each protocol's in its own order
    jobs = [j for group in itertools.zip_longest(*per_protocol) for j in group if j is not None]
    run_dirs = [j["run_dir"] for j in jobs]
    if len(set(run_dirs)) != len(run_dirs):
        raise PvedError("two protocols have runs of the same name; export them separately")
    # written beside, then renamed: a batch directory is complete or absent
    batch.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{batch.name}.", dir=batch.parent))
    try:
        for rel, source in sources.items():
            dest = staging / RUNS / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, dest)
        atomic_write_json(
            staging / BATCH_FILE,
            {
                "format": BATCH_FORMAT,
                "version": BATCH_VERSION,
                "pved_version": __version__,
                "protocols": [plan.describe() for plan in plans],
                "inputs": inputs,
                "jobs": jobs,
            },
        )
        staging.rename(batch)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if claim_minutes > 0:
        holder = _holder(batch)
        for run_dir in claims:
            write_claim(run_dir, holder, now + 60.0 * claim_minutes)
    return [j["key"] for j in jobs]


def _holder(batch_dir: Path) -> str:
    """The name a batch's claims go under: its directory, resolved."""
    return str(batch_dir.resolve())


def release_batch(protocol_dir: Path | str, batch_dir: Path | str | None = None) -> list[str]:
    """End the claims that ``batch_dir`` (every batch, when None) holds on the protocol's
    runs, e.g. after a batch that failed or ran out of time: the protocol then makes
    those runs itself. Returns the released runs' job keys."""
    plan = ProtocolPlan.load(Path(protocol_dir))
    holder = None if batch_dir is None else _holder(Path(batch_dir))
    return [
        job.key
        for job in plan.expand(finished_results(plan))
        if job.fn is transfer and job.run_dir is not None and release_claim(job.run_dir, holder)
    ]


def _run_one(kwargs: dict[str, Any], error_file: str) -> None:
    """A batch run's process: the transfer run, its error as one line in ``error_file``."""
    try:
        transfer(**kwargs)
    except BaseException as err:
        Path(error_file).write_text(_one_line(err))
        raise SystemExit(1) from None


def _run_state(run_dir: Path) -> str:
    if (run_dir / "result.json").exists():
        return "finished"
    checkpoints = run_dir / "checkpoints"
    if checkpoints.is_dir() and any(checkpoints.glob("*.pt")):
        return "partial"
    return "nothing"


def run_batch(
    batch_dir: Path | str,
    *,
    workers: int | None = None,
    deadline_s: float | None = None,
    start_by_s: float | None = None,
    poll_s: float = 1.0,
) -> dict[str, Any]:
    """Run a batch's runs, ``workers`` at a time (default: the CPUs), each in its own
    process with one thread; returns ``log.json``'s content (also written there).

    ``deadline_s``: seconds from the call after which the runs still going are killed
    (each keeps its last checkpoint). ``start_by_s``: no run starts later than this
    (default: the deadline), so that a run that cannot finish is not begun."""
    t0 = time.monotonic()
    if workers is not None:
        check_int("--workers", workers, low=1)
    if deadline_s is not None:
        check_number("--deadline-s", deadline_s, low=0.0, low_open=True)
    if start_by_s is not None:
        check_number("--start-by-s", start_by_s, low=0.0)
    batch = Path(batch_dir)
    data, jobs = _read_batch(batch)
    runs_root = (batch / RUNS).resolve()
    for rel, digest in data.get("inputs", {}).items():
        path = runs_root / rel
        if not path.exists():
            raise PvedError(f"batch input {path} is missing")
        if file_digest(path) != digest:
            raise PvedError(f"batch input {path} differs from the one exported")
    workers = workers or os.cpu_count() or 1
    start_by = start_by_s if start_by_s is not None else deadline_s
    ctx = multiprocessing.get_context("spawn")  # fresh interpreters: no forked torch state
    errors = Path(tempfile.mkdtemp(prefix="pved-batch-"))
    log: dict[str, dict[str, Any]] = {}
    queue = list(jobs)
    running: dict[str, tuple[Any, float]] = {}
    try:
        with _environment(WORKER_ENV):
            while queue or running:
                now = time.monotonic() - t0
                for key, (proc, started) in list(running.items()):
                    if proc.exitcode is None:
                        continue
                    proc.join()
                    entry = log[key]
                    entry["wall_s"] = round(now - started, 1)
                    if proc.exitcode != 0:
                        error = errors / entry["error_slot"]
                        entry["error"] = (
                            error.read_text() if error.exists() else f"exit code {proc.exitcode}"
                        )
                    del running[key]
                if deadline_s is not None and now >= deadline_s:
                    for key, (proc, started) in running.items():
                        proc.kill()
                        proc.join()
                        log[key].update(wall_s=round(now - started, 1), killed_at_deadline=True)
                    running.clear()
                    break
                while queue and len(running) < workers and (start_by is None or now < start_by):
                    job = queue.pop(0)
                    slot = str(len(log))
                    proc = ctx.Process(
                        target=_run_one,
                        args=(job.resolved(runs_root), str(errors / slot)),
                        daemon=True,
                    )
                    proc.start()
                    running[job.key] = (proc, now)
                    log[job.key] = {"started_s": round(now, 1), "error_slot": slot}
                if not running:
                    break  # nothing may start any more
                time.sleep(poll_s)
    finally:
        for proc, _started in running.values():
            proc.kill()
        shutil.rmtree(errors, ignore_errors=True)
    entries = {}
    for job in jobs:
        entry = {k: v for k, v in log.get(job.key, {}).items() if k != "error_slot"}
        entry["state"] = _run_state(runs_root / job.run_dir) if job.key in log else "not started"
        entries[job.key] = entry
    report = {"elapsed_s": round(time.monotonic() - t0, 1), "workers": workers, "jobs": entries}
    atomic_write_json(batch / LOG_FILE, report)
    return report


def pack_batch(
    batch_dir: Path | str, dest: Path | str, *, max_bytes: int = 15 * 2**20
) -> list[Path]:
    """Pack the batch's finished and checkpointed run directories (not its inputs) into
    ``dest/runs<i>.tar.gz`` of at most ``max_bytes`` uncompressed each (a run larger than
    that gets a file of its own), plus a copy of ``log.json``; returns the tar files."""
    batch = Path(batch_dir)
    _, jobs = _read_batch(batch)
    runs_root = batch / RUNS
    out = check_writable("--to", dest)
    out.mkdir(parents=True, exist_ok=True)
    groups: list[list[str]] = [[]]
    size = 0
    for job in jobs:
        run_dir = runs_root / job.run_dir
        if _run_state(run_dir) == "nothing":
            continue
        run_size = sum(f.stat().st_size for f in run_dir.rglob("*") if f.is_file())
        if groups[-1] and size + run_size > max_bytes:
            groups.append([])
            size = 0
        groups[-1].append(job.run_dir)
        size += run_size
    files = []
    for i, group in enumerate(g for g in groups if g):
        path = out / f"runs{i}.tar.gz"
        tmp = path.with_name(f".{path.name}.tmp")
        with tarfile.open(tmp, "w:gz") as tar:
            for rel in group:
                tar.add(runs_root / rel, arcname=f"{RUNS}/{rel}")
        tmp.replace(path)
        files.append(path)
    if (batch / LOG_FILE).exists():
        shutil.copy2(batch / LOG_FILE, out / LOG_FILE)
    return files


def _extract(tar_path: Path, dest: Path) -> None:
    try:
        with tarfile.open(tar_path) as tar:
            for member in tar.getmembers():
                name = Path(member.name)
                if name.is_absolute() or ".." in name.parts or name.parts[:1] != (RUNS,):
                    raise PvedError(f"{tar_path} holds {member.name}: not a batch's run")
                if not (member.isfile() or member.isdir()):
                    raise PvedError(f"{tar_path} holds {member.name}: not a file")
            tar.extractall(dest, filter="data")
    except (tarfile.TarError, OSError, EOFError) as err:
        raise PvedError(f"{tar_path} is not a readable tar file ({_one_line(err)})") from None


def import_batch(
    protocol_dir: Path | str, sources: Sequence[Path | str], *, finished_only: bool = False
) -> dict[str, list[str]]:
    """Move the run directories of ``sources`` (tar files from :func:`pack_batch`, or batch
    directories) into the protocol's ``runs/``; returns job keys by outcome:
    ``finished`` and ``partial`` (imported), ``exists`` (a run directory is here already:
    kept), ``unknown`` (no run of this protocol that can start now), ``mismatch`` (its
    config hash is not the one this run has here) and ``empty`` (no result, no
    checkpoint, or only a checkpoint when ``finished_only``: a batch still running
    leaves its unfinished runs where they are) and ``other`` (a run of a pair this
    protocol does not have: another protocol's, from a batch they share)."""
    plan = ProtocolPlan.load(Path(protocol_dir))
    check_writable("--protocol", plan.runs)
    results = finished_results(plan)
    expected = {
        _relative(job.run_dir, plan.runs, "run"): job
        for job in plan.expand(results)
        if job.fn is transfer and job.run_dir is not None
    }
    outcome: dict[str, list[str]] = {
        k: [] for k in ("finished", "partial", "exists", "unknown", "mismatch", "empty", "other")
    }
    plan.runs.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".import-", dir=plan.runs))
    try:
        roots: list[Path] = []
        for i, source in enumerate(Path(s) for s in sources):
            if source.is_dir():
                if not (source / BATCH_FILE).exists():
                    raise PvedError(f"{source} is not a batch directory (no {BATCH_FILE})")
                roots.append(source / RUNS)
            elif source.is_file():
                _extract(source, staging / str(i))
                roots.append(staging / str(i) / RUNS)
            else:
                raise PvedError(f"{source} not found")
        for root in roots:
            for config_file in sorted(root.glob("*/transfer/*/seed*/config.json")):
                run_dir = config_file.parent
                rel = str(run_dir.relative_to(root))
                if Path(rel).parts[0] not in plan.pairs:
                    outcome["other"].append(rel)  # another protocol's, in a shared batch
                    continue
                job = expected.get(rel)
                if job is None:
                    outcome["unknown"].append(rel)
                    continue
                state = _run_state(run_dir)
                assert job.run_dir is not None
                if finished_only and state == "partial":
                    outcome["empty"].append(job.key)  # still going there: still claimed
                    continue
                # from here on the batch is done with the run; it goes back to the
                # protocol (made by the batch, already here, or to be made here)
                if state == "nothing":
                    release_claim(job.run_dir)
                    outcome["empty"].append(job.key)
                    continue
                if job.run_dir.exists():
                    release_claim(job.run_dir)
                    outcome["exists"].append(job.key)
                    continue
                if _imported_hash(run_dir, state) != _expected_hash(job.kwargs):
                    release_claim(job.run_dir)
                    outcome["mismatch"].append(job.key)
                    continue
                if staging not in run_dir.parents:  # a batch directory's: copied, kept there
                    copy = staging / "copies" / rel
                    shutil.copytree(run_dir, copy)
                    run_dir = copy
                if state == "finished":
                    repoint_result(run_dir, job.run_dir)
                # one rename on the same file system: the run appears whole or not at all
                job.run_dir.parent.mkdir(parents=True, exist_ok=True)
                run_dir.rename(job.run_dir)
                release_claim(job.run_dir)  # only now: never unclaimed while absent
                outcome[state].append(job.key)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return outcome


def _expected_hash(kwargs: Mapping[str, Any]) -> str:
    args = {k: v for k, v in kwargs.items() if k != "progress"}
    return config_hash(transfer_spec(**args).config)


def _imported_hash(run_dir: Path, state: str) -> str | None:
    """The config hash a run directory was made under (``result.json``'s when finished,
    else ``config.json``'s); None when unreadable."""
    name = "result.json" if state == "finished" else "config.json"
    try:
        value = json.loads((run_dir / name).read_text()).get("config_hash")
    except (OSError, json.JSONDecodeError, UnicodeDecodeError, AttributeError):
        return None
    return value if isinstance(value, str) else None
