"""The numeric fingerprint (pved.experiments.fingerprint): the code computes the pinned
digests, so a commit that changes what runs compute says so by updating
src/pved/fingerprint_pins.json and naming the records it invalidates."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from helpers import run_cli
from pved.errors import PvedError
from pved.experiments import fingerprint
from pved.provenance import (
    FINGERPRINT_PINS,
    UNKNOWN,
    fingerprint_id,
    fingerprint_mismatch,
    pinned_fingerprint,
    read_pins,
)


@pytest.fixture(scope="module")
def computed() -> dict[str, str]:
    return fingerprint.compute_fingerprint()


def test_the_code_computes_the_pinned_digests(computed: dict[str, str]) -> None:
    pins = read_pins()
    here = fingerprint.platform_record()["torch_cpu"]
    pinned_cpu = (pins.get("pinned_under") or {}).get("torch_cpu")
    if here != pinned_cpu:  # torch's kernels are not pinned (pved.provenance.numeric_stack)
        pytest.skip(f"pinned under torch CPU kernels {pinned_cpu}, here {here}")
    check = fingerprint.check_fingerprint(computed)
    assert check["matches"], fingerprint.mismatch_message(check)
    assert check["id"] == pinned_fingerprint() == fingerprint_id(pins["digests"])


def test_each_stage_is_in_the_pins_and_repeats_to_the_bit(computed: dict[str, str]) -> None:
    assert list(computed) == list(fingerprint.STAGES) == list(read_pins()["digests"])
    # the fit alone again: its digest does not depend on what ran before it
    assert fingerprint.fit_digest() == computed["pved-fit"]


def test_a_changed_stage_is_named_with_what_the_commit_must_do() -> None:
    moved = {**read_pins()["digests"], "ppo": "0" * 16}
    check = fingerprint.check_fingerprint(moved)
    assert not check["matches"] and check["changed"] == ["ppo"]
    message = fingerprint.mismatch_message(check)
    assert "stage(s) ppo" in message and "fingerprint_pins.json" in message
    assert "invalidates" in message and check["id"] != check["pinned"]["id"]


def test_the_id_is_of_the_digests_alone() -> None:
    assert fingerprint_id({"a": "1", "b": "2"}) == fingerprint_id({"b": "2", "a": "1"})
    assert fingerprint_id({"a": "1"}) != fingerprint_id({"a": "2"})
    assert len(fingerprint_id({"a": "1"})) == 12


def test_a_bad_pin_file_is_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "pins.json"
    bad.write_text("{")
    with pytest.raises(PvedError, match="not readable JSON"):
        read_pins(bad)
    bad.write_text(json.dumps({"digests": {"ppo": 3}}))
    with pytest.raises(PvedError, match="no 'digests'"):
        read_pins(bad)
    assert FINGERPRINT_PINS.is_file()


def test_groups_under_other_or_unknown_fingerprints_are_flagged() -> None:
    assert fingerprint_mismatch({"f1": 3}, {"f1": 2}) is None
    assert "f1 (3) against f2 (2)" in str(fingerprint_mismatch({"f1": 3}, {"f2": 2}))
    assert fingerprint_mismatch({"f1": 3}, {"f1": 1, UNKNOWN: 1}) is not None
    assert fingerprint_mismatch({UNKNOWN: 3}, {UNKNOWN: 2}) is not None


def test_pved_fingerprint_prints_the_digests_and_refuses_a_mismatch(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # the digests stand in (the first test computes them): the verb's own logic
    pinned = read_pins()["digests"]
    monkeypatch.setattr(fingerprint, "compute_fingerprint", lambda: dict(pinned))
    code, out, _ = run_cli(capsys, "fingerprint")
    assert code == 0 and f"ppo: {pinned['ppo']} (pinned {pinned['ppo']})" in out
    assert f"id: {fingerprint_id(pinned)}" in out and "matches the pins" in out
    monkeypatch.setattr(fingerprint, "compute_fingerprint", lambda: {**pinned, "shaped": "x"})
    code, out, err = run_cli(capsys, "fingerprint")
    assert code == 2 and "differs from the pins" in out
    assert err.startswith("pved: error: the numeric fingerprint changed in stage(s) shaped")
    code, out, _ = run_cli(capsys, "fingerprint", "--json")
    assert json.loads(out[: out.rindex("}") + 1])["changed"] == ["shaped"]
