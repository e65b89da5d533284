"""Watching a protocol: the progress bar of its live line, and ``pved protocol status DIR``.

The driver of ``pved protocol`` (:class:`pved.protocol.runner.LiveView`) rewrites
``status.json`` in the protocol's directory every :data:`STATUS_EVERY_S` seconds: runs
done, in flight (each with its env steps), failed and waiting, env steps, the rate of this
call, the ETA, and which process on which host writes it. :func:`status_text` reads that
file and ``protocol.json``, nothing else: no Ray connection and no torch (this module
imports neither, nor any pved module that does), so ``pved protocol status DIR`` answers
in a fraction of a second while another process, here or on any machine that sees the
directory, runs the protocol.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pved.errors import PvedError

STATUS_FILE = "status.json"
#: Seconds between two writes of ``status.json`` by a running driver.
STATUS_EVERY_S = 2.0
#: A driver on another host counts as running while its status is at most this old.
STALE_AFTER_S = 60.0


def duration_text(seconds: float) -> str:
    """``seconds`` as hours:minutes:seconds, the hours uncapped: a protocol of a day and
    a half reads 36:00:00 (a clock format wraps it to 12:00:00)."""
    whole = max(0, round(seconds))
    return f"{whole // 3600:02d}:{whole // 60 % 60:02d}:{whole % 60:02d}"


def progress_bar(done: float, total: float, width: int = 20) -> str:
    """``[#####···············]  25%``: the share of ``total`` that is ``done``."""
    share = min(1.0, max(0.0, done / total)) if total > 0 else 0.0
    filled = int(share * width)
    return f"[{'#' * filled}{'·' * (width - filled)}] {share:4.0%}"


def writer_identity() -> dict[str, Any]:
    """Who writes a status: this host and process, for :func:`driver_state`."""
    return {"host": socket.gethostname(), "pid": os.getpid(), "updated": time.time()}


def driver_state(status: Mapping[str, Any], now: float | None = None) -> str:
    """Whether the driver that wrote ``status`` still runs: ``finished``; on this host,
    whether its process lives; elsewhere, whether its last write is recent."""
    if status.get("finished"):
        return "finished"
    now = time.time() if now is None else now
    age = now - float(status.get("updated", 0.0))
    pid, host = status.get("pid"), status.get("host")
    if host == socket.gethostname() and isinstance(pid, int):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return f"stopped: its driver (pid {pid}) is gone; rerun the command to resume"
        except PermissionError:
            pass  # another user's process: it lives
        return f"running (pid {pid}, status {age:.0f} s old)"
    if age <= STALE_AFTER_S:
        return f"running{f' on {host}' if host else ''} (status {age:.0f} s old)"
    since = f"no word{f' from {host}' if host else ''} for {duration_text(age)}"
    return f"{since}: stopped, or cut off from here"


def read_status(out: Path | str) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """(``protocol.json``, ``status.json`` or None before the driver's first write) of
    protocol directory ``out``; :class:`PvedError` where it is no protocol directory."""
    out = Path(out)
    try:
        plan = json.loads((out / "protocol.json").read_text())
    except FileNotFoundError:
        raise PvedError(f"{out} is not a protocol directory (no protocol.json)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PvedError(f"{out / 'protocol.json'} is unreadable ({exc})") from None
    try:
        status = json.loads((out / STATUS_FILE).read_text())
        # a status written by a pved that did not say when: its file's time says it
        status.setdefault("updated", (out / STATUS_FILE).stat().st_mtime)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        status = None  # not written yet (or being replaced: atomic, so only on Windows)
    return plan, status


def status_text(out: Path | str, now: float | None = None) -> str:
    """What ``pved protocol status DIR`` prints: the plan, the driver's state, the bar,
    runs done / running / failed / left, steps per second so far and the ETA, each run
    in flight with its steps, and each failure."""
    plan, status = read_status(out)
    budget = plan.get("budget", {}).get("name", "?") if isinstance(plan, dict) else "?"
    lines = [
        f"{out}: {', '.join(plan.get('pairs', []))} ({budget} budget), methods "
        f"{' '.join(plan.get('methods', []))}"
    ]
    if status is None:
        finished = list(Path(out).glob("runs/*/*/*/seed*/result.json"))
        lines.append(f"no status.json yet; {len(finished)} runs finished on disk")
        return "\n".join(lines)
    steps, total = int(status.get("env_steps", 0)), int(status.get("env_steps_total", 0))
    eta = status.get("eta_s")
    lines += [
        f"driver: {driver_state(status, now)}",
        f"{progress_bar(steps, total)}  {steps:,}/{total:,} env steps",
        f"runs: {status.get('done', 0)} done, {status.get('running', 0)} running, "
        f"{status.get('failed', 0)} failed, {status.get('pending', 0)} left"
        + (f" ({status['away']} away in a batch)" if status.get("away") else ""),
        f"{status.get('steps_per_s', 0.0):,.0f} env steps/s over "
        f"{duration_text(float(status.get('elapsed_s', 0.0)))} of this call | ETA "
        f"{'?' if eta is None else duration_text(float(eta))}",
    ]
    for run in status.get("running_runs", []):
        lines.append(f"  running: {run['key']}  {run['steps']:,}/{run['of']:,} env steps")
    for key, error in status.get("failed_runs", {}).items():
        lines.append(f"  failed: {key}: {error}")
    return "\n".join(lines)


class LiveView:
    """One progress bar over all the runs (by env steps), runs done / running / failed,
    env steps per second and ETA: one line rewritten in place on a terminal, a line every
    ``every_s`` seconds otherwise; and, every few seconds, ``status.json`` in the output
    directory with the runs in flight and the failures, which ``pved protocol status``
    reads (:mod:`pved.protocol.watch`).

    The rate counts only the steps trained by this call: a restarted protocol finds
    hundreds of finished runs (and checkpoints) within minutes, and counting those as
    progress gave rates of 100k+ steps/s and an ETA of minutes for hours of work."""

    def __init__(self, status_path: Path | None, stream: Any = None, every_s: float = 30.0):
        self.status_path = status_path
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every_s = 1.0 if self.tty else every_s
        self.last = 0.0
        self.last_status = -float("inf")
        self.start = time.monotonic()
        self.start_steps: int | None = None

    def update(
        self,
        done: int,
        running: int,
        failed: int,
        pending: int,
        steps: int,
        total: int,
        force: bool = False,
        earlier_steps: int = 0,
        away: int = 0,
        detail: Mapping[str, Any] | None = None,
        finished: bool = False,
    ) -> dict[str, Any]:
        """``steps``: env steps of the finished and running jobs; ``earlier_steps``: the
        part of them an earlier call trained (finished runs found on disk, and what the
        resumed runs had reached), left out of the rate; ``away``: the waiting jobs that
        an exported batch has claimed; ``detail``: more for ``status.json`` (the runs in
        flight, the failures); ``finished``: the last update of the call."""
        now = time.monotonic()
        fresh = steps - earlier_steps
        if self.start_steps is None:
            self.start_steps = fresh
        elapsed = now - self.start
        rate = (fresh - self.start_steps) / elapsed if elapsed > 0 else 0.0
        eta = (total - steps) / rate if rate > 0 else None
        status = {
            "done": done,
            "running": running,
            "failed": failed,
            "pending": pending,
            "away": away,
            "env_steps": steps,
            "env_steps_earlier": earlier_steps,
            "env_steps_total": total,
            "steps_per_s": rate,
            "eta_s": eta,
            "elapsed_s": elapsed,
            **(detail or {}),
            "finished": finished,
            **writer_identity(),
        }
        if self.status_path is not None and (force or now - self.last_status >= STATUS_EVERY_S):
            from pved.runs import atomic_write_json  # here: status readers never load torch

            self.last_status = now
            atomic_write_json(self.status_path, status)
        if force or now - self.last >= self.every_s:
            self.last = now
            eta_text = "?" if eta is None else duration_text(eta)
            line = (
                f"{progress_bar(steps, total)} | "
                f"runs: {done} done, {running} running, {failed} failed, {pending} waiting"
                + (f" ({away} away in a batch)" if away else "")
                + " | "
                f"{steps:,}/{total:,} env steps | {rate:,.0f} steps/s | ETA {eta_text}"
            )
            if self.tty:
                self.stream.write("\r\x1b[2K" + line)
            else:
                self.stream.write(line + "\n")
            self.stream.flush()
        return status

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()
