"""Run a growing graph of stage jobs on Ray: one CPU per job, bounded retries, a live view.

The protocol (:mod:`pved.protocol.plan`) does not know all its runs in advance:
which beta the evaluation runs use is decided when the tuning runs are done. So the runner
asks a *planner* for jobs again after every finished job: ``planner.expand(results)``
returns every job that can be defined from the results so far (the same job again each
time, by key), and the runner submits those whose dependencies have finished. The planner
stays a pure function of finished results, which is what makes a restart cheap: every stage
skips a run whose ``result.json`` exists and resumes one that has checkpoints, so after a
crash or ``kill -9`` the same command walks the same graph, finds most jobs done at once
and continues the rest from their last checkpoints.

Ray is started locally with ``workers`` CPUs unless ``address`` names a running cluster
(whose nodes must have ``pved`` installed and see the output directory, e.g. on a shared
file system). Where Ray is not installed (its wheel is ~80 MB: too big to carry to some
machines) the ``processes`` backend runs the same graph on a local pool of processes, one
job each. A job that raises, or whose worker dies, is submitted again up to ``retries``
times, then recorded as failed with its error; jobs that depend on it are reported as
blocked. Nothing is hidden: the final :class:`RunnerReport` lists both.

Not every job has to run. A job that is not an *end product* (``Job.end_product``: a
stage made only for the jobs that depend on it, such as a model) runs only when an end
product still to be made needs it. And a job whose ``result.json`` is on disk is checked
by running it again (its stage finds it done under the same config) only when its
dependencies are there or will be made anyway; where one of them is gone and nothing else
needs it (a protocol restored from its summary on a new machine: its finished tuning
runs, whose models were not kept), the result on disk is taken as it is, rather than
remaking hours of models only to confirm runs that are done. A run restored from another
machine (its result names where from: :data:`pved.runs.RESTORED_FROM`) is never checked:
inputs remade here differ from that machine's in their last digits, and checking would
redo it.

A job whose run directory an exported batch has claimed (:func:`pved.runs.write_claim`)
is not started while the claim lasts; the runner waits for it rather than ending, and a
run imported meanwhile is then found done.

One module past 600 lines on purpose: one scheduler over two interchangeable executors
(Ray, local processes) that share its bookkeeping of jobs, retries and the report.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import importlib.util
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from pved.blas import kernel_env
from pved.errors import PvedError
from pved.protocol.watch import LiveView
from pved.runs import (
    RESTORED_FROM,
    claim_holder,
    last_logged_step,
    to_jsonable,
)

#: Environment of every worker: one thread per run (parallelism comes from runs side by
#: side), one OpenBLAS kernel on every machine, headless rendering.
WORKER_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    **kernel_env(),
    "MUJOCO_GL": os.environ.get("MUJOCO_GL", "osmesa"),
    "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "osmesa"),
}


@dataclass(frozen=True)
class Job:
    """One stage call.

    Attributes:
        key: unique name of the job in the graph (also its name in reports).
        fn: the stage function, called as ``fn(**kwargs)`` in a worker; it must be
            importable there (a module-level function) and return JSON-able data.
        kwargs: its arguments (picklable).
        deps: keys of the jobs that must have finished first.
        steps: env steps it will take (0 when it is not an RL run): progress and ETA.
        run_dir: its run directory, when known: ``metrics.jsonl`` there gives the live
            progress and ``result.json`` there says it was finished before this call.
        tags: what the experiment wants to remember about it (not passed to ``fn``).
        priority: among jobs ready at once, lower goes first (ties: the plan's order). The
            runner submits no more jobs than the backend has workers, so a job that others
            wait on can be put ahead of independent ones (shorter wall time on many cores).
        end_product: whether the experiment wants the job's result for itself; False for a
            stage made only for the jobs that depend on it, which runs only while one of
            them is still to be made (module docstring).
        required_config: entries the ``config`` of ``run_dir/config.json`` must hold for
            a ``result.json`` there to count as this job's: a run made by code that
            computed otherwise (and, restored, cannot be checked by its config hash,
            whose inputs are gone) is then made again rather than taken as it is.
        run_options: arguments passed to ``fn`` besides ``kwargs`` that say how the job
            runs, not what it makes (how often it checkpoints): kept apart so that
            ``kwargs`` stays what identifies the run (a batch exports ``kwargs`` alone).
    """

    key: str
    fn: Callable[..., Any]
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    deps: tuple[str, ...] = ()
    steps: int = 0
    run_dir: Path | None = None
    tags: Mapping[str, Any] = field(default_factory=dict)
    priority: int = 0
    end_product: bool = True
    required_config: Mapping[str, Any] = field(default_factory=dict)
    run_options: Mapping[str, Any] = field(default_factory=dict)


class Planner(Protocol):
    """What the runner needs from the experiment it runs."""

    def expand(self, results: Mapping[str, Any]) -> list[Job]:
        """Every job definable from the finished jobs' ``results`` (by key)."""
        ...

    def expected_steps(self) -> int:
        """Env steps of the whole experiment, including jobs not yet definable."""
        ...


@dataclass
class RunnerReport:
    """What happened: each finished job's result, the failures and the blocked jobs."""

    results: dict[str, Any]
    failed: dict[str, str]  # key -> last error (one line)
    blocked: list[str]  # keys of jobs that could not run because a dependency failed
    reused: list[str]  # keys of jobs finished by an earlier invocation
    attempts: dict[str, int]
    wall_s: float


def _jobs_to_run(
    known: Mapping[str, Job], results: Mapping[str, Any], on_disk: Mapping[str, Any]
) -> set[str]:
    """Keys of the unfinished jobs that are to run (module docstring): the end products
    not finished on disk and, transitively, what they need that is not on disk either;
    then every job finished on disk whose dependencies are finished or among those, which
    runs to be checked. A job on disk whose dependencies are not is taken as it is (a
    model kept without its dataset)."""
    unfinished = {k for k in known if k not in results}
    todo = [k for k in unfinished if known[k].end_product and k not in on_disk]
    to_run = set(todo)
    while todo:
        for dep in known[todo.pop()].deps:
            if dep in unfinished and dep not in to_run and dep not in on_disk:
                to_run.add(dep)
                todo.append(dep)
    grown = True
    while grown:
        grown = False
        for key in unfinished & set(on_disk) - to_run:
            if all(d in results or d in to_run for d in known[key].deps):
                to_run.add(key)
                grown = True
    return to_run


def _call(fn: Callable[..., Any], kwargs: Mapping[str, Any]) -> Any:
    """Worker side of a job: one thread, then the stage function."""
    import torch

    torch.set_num_threads(1)
    return fn(**kwargs)


#: The backends :func:`run_jobs` knows; ``auto`` is Ray where it is installed.
BACKENDS = ("auto", "ray", "processes")

#: Least niceness of a ``processes`` worker, Ray's default for its workers: on a shared
#: machine, interactive work keeps priority over a long grid. A driver started nicer than
#: this (``nice -n 19 pved protocol ...``) keeps its own niceness for its workers.
WORKER_NICENESS = 15

#: Seconds a ``processes`` worker gets to end after SIGTERM at shutdown, before SIGKILL.
WORKER_STOP_GRACE_S = 10.0


def resolve_backend(backend: str, address: str | None = None) -> str:
    """``ray`` or ``processes`` for ``backend``; :class:`PvedError` when it cannot run here."""
    if backend not in BACKENDS:
        raise PvedError(f"unknown backend {backend!r}; known: {', '.join(BACKENDS)}")
    has_ray = importlib.util.find_spec("ray") is not None
    if backend == "auto":
        backend = "ray" if has_ray or address else "processes"
    if backend == "ray" and not has_ray:
        raise PvedError("backend 'ray' needs Ray installed (pip install ray); or use processes")
    if backend == "processes" and address:
        raise PvedError("--address attaches to a Ray cluster; it needs backend 'ray'")
    return backend


class _Executor(Protocol):
    """What :func:`run_jobs` needs of a backend; a handle stands for one submitted job."""

    def submit(self, fn: Callable[..., Any], kwargs: dict[str, Any]) -> Any: ...

    def capacity(self) -> int:
        """How many jobs can run at once now (the runner submits no more)."""
        ...

    def wait(self, handles: list[Any], timeout: float) -> list[Any]:
        """The handles among ``handles`` that have finished (at least one, or none after
        ``timeout`` seconds)."""
        ...

    def result(self, handle: Any) -> Any:
        """The job's return value; raises its error (or the worker's death)."""
        ...

    def shutdown(self) -> None: ...


class _RayExecutor:
    def __init__(self, workers: int | None, address: str | None):
        import ray

        self.ray = ray
        self.started_here = not ray.is_initialized()
        if self.started_here:
            init: dict[str, Any] = {
                "include_dashboard": False,
                "log_to_driver": False,
                "runtime_env": {"env_vars": {**WORKER_ENV, **_spec_files_env()}},
            }
            if address:
                check_reachable(address)
                init["address"] = address
            else:
                init["num_cpus"] = workers or os.cpu_count() or 1
            try:
                ray.init(**init)
            except (ConnectionError, RuntimeError, ValueError) as err:
                where = f"the Ray cluster at {address}" if address else "a local Ray instance"
                raise PvedError(f"cannot start or reach {where}: {_one_line(err)}") from None
        # max_retries=0: the retries are ours, so that each attempt's error can be recorded
        self.remote_call = ray.remote(num_cpus=1, max_retries=0)(_call)

    def submit(self, fn: Callable[..., Any], kwargs: dict[str, Any]) -> Any:
        return self.remote_call.remote(fn, kwargs)

    def capacity(self) -> int:
        # the cluster's CPUs as they are now: a cluster that grows gets more jobs
        return max(1, int(self.ray.cluster_resources().get("CPU", 1)))

    def wait(self, handles: list[Any], timeout: float) -> list[Any]:
        ready, _ = self.ray.wait(handles, num_returns=1, timeout=timeout)
        return list(ready)

    def result(self, handle: Any) -> Any:
        return self.ray.get(handle)

    def shutdown(self) -> None:
        if self.started_here:
            self.ray.shutdown()


def _spec_files_env() -> dict[str, str]:
    """The pair spec files this process read (:data:`pved.spec.SPEC_FILES_ENV`), for the
    workers: a worker on another node of a cluster was not started by this process and
    inherits nothing from it, and finds a spec pair's name only through this variable
    (the files must be where every node sees them, as the output directory is)."""
    from pved.spec import SPEC_FILES_ENV

    files = os.environ.get(SPEC_FILES_ENV)
    return {SPEC_FILES_ENV: files} if files else {}


def _init_process_worker() -> None:
    """A ``processes`` worker: at least Ray's niceness, and death with the driver (Linux),
    so a killed driver leaves no run writing behind the next invocation's back.

    ``os.nice`` adds to the niceness the worker inherited from its driver, so it is raised
    only up to :data:`WORKER_NICENESS`: two grids run side by side at niceness 15 and 19
    keep that order (adding 15 to both would put both at the ceiling, 19)."""
    with contextlib.suppress(OSError):
        os.nice(max(0, WORKER_NICENESS - os.nice(0)))
    if sys.platform.startswith("linux"):
        import ctypes

        with contextlib.suppress(OSError, AttributeError):
            pr_set_pdeathsig = 1
            ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGKILL)


@contextlib.contextmanager
def _environment(values: Mapping[str, str]) -> Iterator[None]:
    """``os.environ`` with ``values`` set, restored afterwards (spawned workers inherit it)."""
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, old in saved.items():
            if old is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = old


def _pool_workers(
    pool: concurrent.futures.ProcessPoolExecutor,
) -> list[multiprocessing.process.BaseProcess]:
    """The worker processes ``pool`` holds now (the pool forgets them once shut down)."""
    return list((getattr(pool, "_processes", None) or {}).values())


def _pool_thread(pool: concurrent.futures.ProcessPoolExecutor) -> list[threading.Thread]:
    """The thread that manages ``pool``'s workers, if started (the pool forgets it once
    shut down)."""
    thread = getattr(pool, "_executor_manager_thread", None)
    return [thread] if thread is not None else []


class _ProcessExecutor:
    """A local pool of ``workers`` spawned processes (fresh interpreters: no forked torch
    or MuJoCo state). A worker that dies breaks the pool; the jobs it held fail this
    attempt and a new pool takes the retries."""

    def __init__(self, workers: int | None):
        self.workers = workers or os.cpu_count() or 1
        self.pool = self._new_pool()
        self.pools: dict[Any, concurrent.futures.ProcessPoolExecutor] = {}
        # the workers of pools replaced after a death, ended with the current pool's
        self.replaced_workers: list[multiprocessing.process.BaseProcess] = []
        # those pools' own threads, which reap the same workers (see shutdown)
        self.replaced_threads: list[threading.Thread] = []

    def _new_pool(self) -> concurrent.futures.ProcessPoolExecutor:
        return concurrent.futures.ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_process_worker,
        )

    def submit(self, fn: Callable[..., Any], kwargs: dict[str, Any]) -> Any:
        future = self.pool.submit(_call, fn, kwargs)
        self.pools[future] = self.pool
        return future

    def capacity(self) -> int:
        return self.workers

    def wait(self, handles: list[Any], timeout: float) -> list[Any]:
        done, _ = concurrent.futures.wait(
            handles, timeout=timeout, return_when=concurrent.futures.FIRST_COMPLETED
        )
        return list(done)

    def result(self, handle: Any) -> Any:
        pool = self.pools.pop(handle)
        try:
            return handle.result()
        except concurrent.futures.process.BrokenProcessPool:
            if pool is self.pool:  # the first of its jobs to report it: replace the pool
                # its surviving workers are being ended by the pool's own thread, which
                # a non-waiting shutdown does not wait for: kept, to be joined at the end
                self.replaced_workers += _pool_workers(self.pool)
                self.replaced_threads += _pool_thread(self.pool)
                self.pool.shutdown(wait=False, cancel_futures=True)
                self.pool = self._new_pool()
            raise RuntimeError("its worker process died (killed, or out of memory)") from None

    def shutdown(self) -> None:
        # Not waiting: after an error or Ctrl-C the running jobs are abandoned (Ctrl-C
        # reaches the workers too; a killed driver takes them along, see above). The
        # workers are ended here rather than left to the pool's stop messages: one that
        # missed its message (seen once, in CI on a loaded machine) kept the interpreter
        # from exiting, since multiprocessing joins its non-daemon children at exit.
        workers = _pool_workers(self.pool) + self.replaced_workers
        threads = _pool_thread(self.pool) + self.replaced_threads
        self.pool.shutdown(wait=False, cancel_futures=True)
        for worker in workers:
            if worker.is_alive():
                worker.terminate()
        for worker in workers:
            worker.join(timeout=WORKER_STOP_GRACE_S)
            if worker.is_alive():  # still there (seen once more in CI): no more asking
                worker.kill()
                worker.join(timeout=WORKER_STOP_GRACE_S)
        # Each pool's thread waits on the same workers. Whichever thread reaps a worker
        # records its exit code a moment later, and until then the other finds no such
        # child and multiprocessing counts the worker alive (CI saw one "started" after
        # this returned). The pools' threads end once their workers are reaped.
        for thread in threads:
            thread.join(timeout=WORKER_STOP_GRACE_S)


def read_job_result(run_dir: Path | None, required_config: Mapping[str, Any] | None = None) -> Any:
    """The ``result.json`` in ``run_dir``, or None where there is none (or no run dir), or
    where ``run_dir/config.json``'s config lacks an entry of ``required_config``."""
    if run_dir is None:
        return None
    try:
        result = json.loads((run_dir / "result.json").read_text())
        if required_config:
            config = json.loads((run_dir / "config.json").read_text()).get("config", {})
            wanted = json.loads(json.dumps(to_jsonable(dict(required_config))))
            if any(config.get(k) != v for k, v in wanted.items()):
                return None  # made by code that computed otherwise: made again
        return result
    except FileNotFoundError:
        return None
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
        return None  # damaged: the job runs, and its stage says what is wrong


def run_jobs(
    planner: Planner,
    *,
    workers: int | None = None,
    address: str | None = None,
    retries: int = 2,
    status_path: Path | None = None,
    log_dir: Path | None = None,
    live: bool = True,
    poll_s: float = 1.0,
    backend: str = "auto",
) -> RunnerReport:
    """Run ``planner``'s jobs on Ray (or a local process pool) until none is left to run.

    Args:
        planner: gives the jobs (see :class:`Planner`).
        workers: CPUs of the local Ray instance or process pool (default: all); ignored
            with ``address``.
        address: a running Ray cluster to attach to (``ray start --head`` prints it);
            None starts a local instance that ends with this call.
        retries: how many times a failed job is submitted again before it is reported.
        status_path: where the live view's ``status.json`` goes.
        log_dir: where each failed attempt's traceback is written (``<key>.txt``).
        live: print the live view.
        backend: ``ray``, ``processes`` (a local pool, for machines without Ray) or
            ``auto`` (Ray where it is installed).
    """
    if retries < 0:
        raise PvedError(f"retries must be >= 0, got {retries}")
    backend = resolve_backend(backend, address)
    with contextlib.ExitStack() as stack:
        executor: _Executor
        if backend == "ray":
            executor = _RayExecutor(workers, address)
        else:
            # spawned workers inherit the driver's environment
            stack.enter_context(_environment(WORKER_ENV))
            executor = _ProcessExecutor(workers)
        stack.callback(executor.shutdown)
        return _run(planner, executor, retries, status_path, log_dir, live, poll_s)


def _run(
    planner: Planner,
    executor: _Executor,
    retries: int,
    status_path: Path | None,
    log_dir: Path | None,
    live: bool,
    poll_s: float,
) -> RunnerReport:
    """:func:`run_jobs`' loop, on a started backend."""
    t0 = time.monotonic()
    results: dict[str, Any] = {}
    failed: dict[str, str] = {}
    attempts: dict[str, int] = {}
    reused: list[str] = []
    # env steps each job had reached before this call (finished on disk, or checkpointed)
    earlier: dict[str, int] = {}
    # result.json as found at submission: a job that writes a new one (its old one was
    # under another config) was redone, not reused
    found_results: dict[str, int] = {}
    in_flight: dict[Any, Job] = {}
    known: dict[str, Job] = {}
    # each job's result.json as it was when the job became known (None: there was none)
    on_disk: dict[str, Any] = {}
    view = LiveView(status_path) if live else None

    def submit(job: Job) -> None:
        attempts[job.key] = attempts.get(job.key, 0) + 1
        if attempts[job.key] == 1 and job.run_dir is not None:
            result_file = job.run_dir / "result.json"
            if result_file.exists():
                found_results[job.key] = result_file.stat().st_mtime_ns
            if job.steps:
                earlier[job.key] = min(job.steps, last_logged_step(job.run_dir))
        in_flight[executor.submit(job.fn, {**job.kwargs, **job.run_options})] = job

    def blocked_keys() -> list[str]:
        bad = set(failed)
        changed = True
        while changed:
            changed = False
            for job in known.values():
                if job.key not in bad and any(d in bad for d in job.deps):
                    bad.add(job.key)
                    changed = True
        return sorted(bad - set(failed))

    # env steps each job in flight has reached, as last read
    reached_now: dict[str, int] = {}

    def progress_steps() -> int:
        steps = sum(known[k].steps for k in results if k in known)
        for job in in_flight.values():
            if job.run_dir is not None and job.steps:
                reached = min(job.steps, last_logged_step(job.run_dir))
                reached_now[job.key] = reached
                steps += reached
                # A run under another config starts over (its old records are deleted),
                # and a resumed one goes back to its checkpoint: what counts as earlier
                # work is the least it has shown since this call submitted it.
                if job.key in earlier:
                    earlier[job.key] = min(earlier[job.key], reached)
        return steps

    def detail() -> dict[str, Any]:
        """The runs in flight (with their steps) and the failures, for ``status.json``."""
        running = [
            {"key": j.key, "steps": reached_now.get(j.key, 0), "of": j.steps}
            for j in in_flight.values()
        ]
        return {"running_runs": running, "failed_runs": dict(failed)}

    while True:
        for job in planner.expand(results):
            if job.key not in known:
                on_disk[job.key] = read_job_result(job.run_dir, job.required_config)
            # the latest definition: a selection can make a stage an end product
            known[job.key] = job
        found = {k: r for k, r in on_disk.items() if r is not None}
        to_run = _jobs_to_run(known, results, found)
        taken = [
            k
            for k, r in found.items()
            if k not in results and (k not in to_run or RESTORED_FROM in r)
        ]
        if taken:  # finished, and checking them would remake what nothing else needs
            for key in taken:
                results[key] = found[key]
                reused.append(key)
            continue  # the planner may define more jobs from these results
        running_keys = {j.key for j in in_flight.values()}
        blocked = set(blocked_keys())
        startable = [
            job
            for job in known.values()
            if job.key in to_run
            and job.key not in failed
            and job.key not in running_keys
            and job.key not in blocked
            and all(d in results for d in job.deps)
        ]
        # a run claimed by an exported batch is being made elsewhere: it waits for the
        # import (or the claim's expiry) rather than being made twice
        now = time.time()
        away = {j.key for j in startable if j.run_dir and claim_holder(j.run_dir, now)}
        ready = [j for j in startable if j.key not in away]
        # only as many as can run: a job that becomes ready later with a lower priority
        # (e.g. the runs a selection waits on) is not queued behind independent ones
        free = executor.capacity() - len(in_flight)
        for job in sorted(ready, key=lambda j: j.priority)[: max(0, free)]:
            submit(job)
        if view is not None:
            pending = len(to_run - set(failed) - {j.key for j in in_flight.values()})
            steps = progress_steps()
            view.update(
                len(results),
                len(in_flight),
                len(failed),
                pending,
                steps,
                max(planner.expected_steps(), steps),
                earlier_steps=sum(earlier.values()),
                away=len(away),
                detail=detail(),
            )
        if not in_flight:
            if not away:
                break
            time.sleep(poll_s)
            continue
        for handle in executor.wait(list(in_flight), poll_s):
            job = in_flight.pop(handle)
            try:
                results[job.key] = executor.result(handle)
                if job.key in found_results and job.run_dir is not None:
                    result_file = job.run_dir / "result.json"
                    if result_file.stat().st_mtime_ns == found_results[job.key]:
                        reused.append(job.key)
            except Exception as err:  # a stage error or a dead worker: retry, then report
                message = _one_line(err)
                if log_dir is not None:
                    log_dir.mkdir(parents=True, exist_ok=True)
                    with (log_dir / f"{job.key.replace('/', '_')}.txt").open("a") as fh:
                        fh.write(f"attempt {attempts[job.key]}:\n")
                        fh.write("".join(traceback.format_exception(err)) + "\n")
                if attempts[job.key] <= retries:
                    submit(job)
                else:
                    failed[job.key] = message
    if view is not None:
        view.update(
            len(results),
            0,
            len(failed),
            0,
            progress_steps(),
            max(planner.expected_steps(), progress_steps()),
            force=True,
            earlier_steps=sum(earlier.values()),
            detail=detail(),
            finished=True,
        )
        view.close()
    return RunnerReport(
        results=results,
        failed=failed,
        blocked=blocked_keys(),
        reused=reused,
        attempts=attempts,
        wall_s=time.monotonic() - t0,
    )


def check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast on a ``host:port`` nobody listens on (Ray itself would retry for
    minutes); other forms (``auto``, ``ray://...``) are left to Ray."""
    import socket

    host, sep, port = address.rpartition(":")
    if not sep or "://" in address or not port.isdigit():
        return
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as err:
        raise PvedError(f"no Ray cluster answers at {address} ({err})") from None


def _one_line(err: BaseException) -> str:
    """The innermost error's message on one line (Ray wraps task errors)."""
    cause: BaseException = err
    while True:  # Ray's task errors carry .cause; connection errors chain __cause__
        inner = getattr(cause, "cause", None) or cause.__cause__
        # a process pool chains the worker's traceback text as the job error's cause
        remote_traceback = type(inner).__name__ == "_RemoteTraceback"
        if not isinstance(inner, BaseException) or inner is cause or remote_traceback:
            break
        cause = inner
    text = str(cause).strip().splitlines()
    # Ray's own message starts with the traceback; its last line is the actual error
    line = text[-1] if text else type(cause).__name__
    return f"{type(cause).__name__}: {line}" if type(cause).__name__ not in line else line
