"""Watching a protocol (issue 67): the live line's progress bar, and ``pved protocol
status DIR`` / ``pved protocol-status DIR`` answering from the directory alone while
another process runs the protocol, without loading torch or Ray."""

from __future__ import annotations

import io
import json
import os
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from helpers import run_cli
from pved.protocol.watch import LiveView, driver_state, progress_bar

JOBS = '''
import json, sys, time
from pathlib import Path


def ok() -> int:
    return 1


def fails() -> None:
    raise ValueError("this run always fails")


def half_way(run_dir: str, go: str) -> int:
    """A run that logs 500 of its 1,000 steps, then waits for the test's word."""
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    (Path(run_dir) / "metrics.jsonl").write_text(json.dumps({"step": 500}) + "\\n")
    while not Path(go).exists():
        time.sleep(0.05)
    return 2
'''

DRIVER = """
import sys
from pathlib import Path

import jobs
from pved.protocol.runner import Job, run_jobs

out = Path(sys.argv[-1])


class Plan:
    def expand(self, results):
        return [
            Job("a/ok", jobs.ok),
            Job("a/fails", jobs.fails),
            Job("a/slow", jobs.half_way, {"run_dir": str(out / "slow"), "go": str(out / "go")},
                steps=1000, run_dir=out / "slow"),
        ]

    def expected_steps(self):
        return 1000


if __name__ == "__main__":  # its workers are spawned: they import this file again
    run_jobs(Plan(), workers=2, retries=0, status_path=out / "status.json", backend="processes")
"""


def _status(*argv: str) -> subprocess.CompletedProcess[str]:
    """``pved ARGV`` in a fresh interpreter, which must not have loaded torch or Ray."""
    code = (
        "import sys\n"
        "from pved.cli import main\n"
        f"code = main({list(argv)!r})\n"
        "assert 'torch' not in sys.modules and 'ray' not in sys.modules, 'heavy import'\n"
        "sys.exit(code)\n"
    )
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)


def test_status_of_a_protocol_another_process_runs(tmp_path: Path) -> None:
    out = tmp_path / "proto"
    out.mkdir()
    plan = {"pairs": ["reacher"], "methods": ["pved", "ppo"], "budget": {"name": "smoke"}}
    (out / "protocol.json").write_text(json.dumps(plan))
    (tmp_path / "jobs.py").write_text(JOBS)
    (tmp_path / "driver.py").write_text(textwrap.dedent(DRIVER))
    empty = _status("protocol", "status", str(out))
    assert empty.returncode == 0, empty.stderr
    assert "no status.json yet; 0 runs finished on disk" in empty.stdout
    driver = subprocess.Popen(
        [sys.executable, str(tmp_path / "driver.py"), str(out)],
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
    )
    try:
        # the slow run half-way, the other two over: the driver's next write says so
        t0 = time.monotonic()
        while True:
            status = out / "status.json"
            if status.exists() and json.loads(status.read_text()).get("done") == 1:
                break
            assert driver.poll() is None and time.monotonic() - t0 < 120, "no status"
            time.sleep(0.2)
        seen = _status("protocol", "status", str(out))
        assert seen.returncode == 0, seen.stderr
        text = seen.stdout
        assert f"{out}: reacher (smoke budget), methods pved ppo" in text
        assert f"driver: running (pid {driver.pid}" in text
        assert "[##########··········]  50%  500/1,000 env steps" in text
        assert "runs: 1 done, 1 running, 1 failed, 0 left" in text
        assert "env steps/s over" in text and "| ETA " in text
        assert "  running: a/slow  500/1,000 env steps" in text
        assert "  failed: a/fails: ValueError: this run always fails" in text
        # the alias answers the same
        alias = _status("protocol-status", str(out))
        assert alias.returncode == 0 and alias.stdout.splitlines()[2:] == text.splitlines()[2:]
    finally:
        (out / "go").write_text("go")
        driver.wait(timeout=120)
    assert "runs: 2 done" in driver.stderr.read()  # type: ignore[union-attr]
    done = _status("protocol", "status", str(out)).stdout
    assert "driver: finished" in done and "[####################] 100%" in done


def test_status_of_a_driver_that_is_gone_or_elsewhere() -> None:
    now = 1000.0
    gone = {"host": socket.gethostname(), "pid": 2**22 + 7, "updated": now}
    assert driver_state(gone, now).startswith("stopped: its driver (pid 4194311) is gone")
    far = {"host": "elsewhere", "pid": 1, "updated": now - 5}
    assert driver_state(far, now) == "running on elsewhere (status 5 s old)"
    assert driver_state({**far, "updated": now - 3600}, now).startswith(
        "no word from elsewhere for 01:00:00"
    )


def test_status_of_no_protocol_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run_cli(capsys, "protocol", "status", tmp_path)
    assert code == 2 and f"{tmp_path} is not a protocol directory (no protocol.json)" in err
    code, _, err = run_cli(capsys, "protocol-status")
    assert code == 2 and "the following arguments are required: DIR" in err
    # `pved protocol` itself parses as before
    code, _, err = run_cli(capsys, "protocol", "--pair", "no-such-pair", "--out", tmp_path)
    assert code == 2 and "unknown pair 'no-such-pair'" in err


def test_the_live_line_carries_one_bar_over_all_runs(tmp_path: Path) -> None:
    stream = io.StringIO()
    view = LiveView(tmp_path / "status.json", stream=stream)
    view.update(3, 2, 0, 5, 2_500, 10_000, force=True, detail={"running_runs": []})
    line = stream.getvalue().strip()
    assert line.startswith("[#####···············]  25% | runs: 3 done, 2 running")
    status = json.loads((tmp_path / "status.json").read_text())
    assert status["running_runs"] == [] and status["finished"] is False and status["pid"] > 0
    assert progress_bar(0, 0) == "[····················]   0%"
