"""``--stages-from``: a transfer run is copied from another protocol only where the code
that made it is this code (its numeric fingerprint); earlier stages by their config."""

from __future__ import annotations

import json
from pathlib import Path

from pved.protocol.driver import copy_stage_runs
from pved.protocol.plan import PLAN_FILE
from pved.provenance import pinned_fingerprint

STEPS = {"reacher": 1_000_000}


def protocol(root: Path, methods: list[str]) -> Path:
    root.mkdir(parents=True)
    plan = {"pairs": ["reacher"], "methods": methods, "transfer_steps": STEPS}
    (root / PLAN_FILE).write_text(json.dumps(plan))
    return root


def finished(root: Path, key: str, fingerprint: str | None, recorded: bool = True) -> Path:
    """A finished run ``runs/<key>`` whose config.json records ``fingerprint`` (or,
    ``recorded`` False, no fingerprint field: a run made before runs recorded one)."""
    run = root / "runs" / key
    run.mkdir(parents=True)
    record = {"config": {"stage": key.split("/")[1]}, "config_hash": "h"}
    if recorded:
        record["fingerprint"] = fingerprint
    (run / "config.json").write_text(json.dumps(record))
    (run / "result.json").write_text(json.dumps({"config_hash": "h"}))
    return run


def test_only_transfer_runs_of_this_codes_fingerprint_are_copied(tmp_path: Path) -> None:
    now = pinned_fingerprint()
    assert now is not None  # the pins are readable in a checkout
    source = protocol(tmp_path / "paper-wide", ["pved-align", "ppo"])
    finished(source, "reacher/transfer/ppo/seed100000", now)
    finished(source, "reacher/transfer/ppo/seed120000", "0123456789ab")  # older code
    finished(source, "reacher/transfer/ppo/seed140000", None, recorded=False)  # before
    finished(source, "reacher/transfer/pved-align-beta0.1-init0-src0/seed20000", "0ld")
    # an earlier stage keeps the config rule, whatever code made it
    finished(source, "reacher/policy/reacher3-reach/seed0", None, recorded=False)
    out = protocol(tmp_path / "paper-45", ["pved-align", "ppo", "ppo-aa"])
    copy = copy_stage_runs(source, out, ["reacher"])
    copied = sorted(str(p.parent.relative_to(out)) for p in out.glob("runs/**/result.json"))
    assert copied == [
        "runs/reacher/policy/reacher3-reach/seed0",
        "runs/reacher/transfer/ppo/seed100000",
    ]
    assert (copy.copied, copy.other_code, copy.fingerprint) == (2, 3, now)
    line = copy.describe("reports/reacher-paper-wide")
    assert line.startswith("copied 2 finished runs from reports/reacher-paper-wide; passed ")
    assert "passed over 3 finished transfer runs not made under this code's numeric " in line
    assert f"({now}): they are made again" in line and "\n" not in line
    # a copy is not yet a run in use: the line says the plan's config decides
    assert line.endswith(
        "a copied run whose config is not the one this plan asks for is made again"
    )
    # the runs passed over are not taken on a second call either, nor counted as copied
    again = copy_stage_runs(source, out, ["reacher"])
    assert (again.copied, again.other_code) == (0, 3)
    assert "passed" not in copy_stage_runs(source, out, []).describe("x")
