"""Helpers shared by several test modules (pytest puts this folder on ``sys.path``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pved import __version__
from pved.cli import main
from pved.experiments.protocol import PLAN_FILE, ProtocolPlan
from pved.runs import atomic_write_json


def run_cli(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    """``pved ARGV...`` in this process: (exit code, stdout, stderr)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def reacher_smoke_protocol(out: Path) -> Path:
    """A reacher smoke protocol (pved, ppo) in ``out`` whose transfer runs can all start:
    its pairs, bank and seed-0 model made by the plan's own jobs, no transfer run made."""
    plan = ProtocolPlan(["reacher"], ["pved", "ppo"], "smoke", out)
    atomic_write_json(out / PLAN_FILE, {**plan.describe(), "pved_version": __version__})
    jobs = {j.key: j for j in plan.expand({})}
    for key in ("reacher/pairs", "reacher/bank/src0", "reacher/model/pved/init0"):
        jobs[key].fn(**jobs[key].kwargs)
    return out
