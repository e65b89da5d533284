"""The layers' rules (docs/decisions/layout.md), read from the source, and the pair
resolved once at the door (``pved.pair``)."""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import pytest

from pved.errors import PvedError
from pved.pair import DEFAULT_RUNS, Pair, resolve_pair
from pved.spec import get_preset

SRC = Path(__file__).resolve().parents[1] / "src" / "pved"
IMPORT = re.compile(r"^\s*(?:from|import)\s+(pved(?:\.\w+)*)", re.MULTILINE)


def _imports(path: Path) -> set[str]:
    return set(IMPORT.findall(path.read_text()))


def test_analysis_reads_records_and_imports_no_layer_that_runs_stages() -> None:
    above = ("pved.experiments", "pved.protocol", "pved.diagnostics", "pved.commands")
    found = {
        f"{path.relative_to(SRC)} imports {name}"
        for path in (SRC / "analysis").glob("*.py")
        for name in _imports(path)
        if name.startswith(above)
    }
    assert not found


def test_nothing_below_the_door_looks_a_pair_up_by_name() -> None:
    # the stages, what they read and the checks take the resolved Pair; only
    # pved.pair.resolve_pair turns a name or a spec file into one
    lookups = re.compile(r"\b(get_preset|load_pair|spec_identity|env_of)\(")
    below = [
        SRC / "run_layout.py",
        *(SRC / "experiments").glob("*.py"),
    ]
    found = [
        f"{path.relative_to(SRC)}: {m.group(1)}"
        for path in below
        for m in lookups.finditer(path.read_text())
    ]
    assert not found


def test_a_pair_resolves_once_into_one_value(tmp_path: Path) -> None:
    pair = resolve_pair("reacher")
    assert pair.preset == get_preset("reacher") and pair.identity == {}  # built-in
    assert pair.runs.root == DEFAULT_RUNS
    assert resolve_pair(pair) is pair
    moved = resolve_pair(pair, tmp_path)
    assert moved.runs.model("pved", 2) == tmp_path / "reacher/model/pved/seed2/model.pt"
    assert moved.runs.dataset("time") == tmp_path / "reacher/pairs/time/seed0/pairs.npz"
    name, kwargs = moved.target_env
    assert name == pair.preset.agent_env(pair.preset.target_agent, pair.preset.target_task).env_id
    assert isinstance(kwargs, dict)
    # a value: it travels to a protocol's worker processes as it is
    assert pickle.loads(pickle.dumps(moved)) == moved
    with pytest.raises(PvedError, match="unknown pair"):
        resolve_pair("no-such-pair")


def test_a_spec_of_ones_own_carries_its_digest(tmp_path: Path) -> None:
    from pved.spec import dump_pair

    spec = tmp_path / "mine.toml"
    text = dump_pair(get_preset("reacher")).replace('name = "reacher"', 'name = "mine"', 1)
    spec.write_text(text)
    pair = resolve_pair(spec, tmp_path / "runs")
    assert isinstance(pair, Pair) and pair.name == "mine"
    assert set(pair.identity) == {"spec"}
    assert (
        pair.runs.bank("Reacher3", "Push")
        == tmp_path / "runs/mine/bank/Reacher3-Push/seed0/bank.npz"
    )
    obs, act = pair.dims(pair.preset.target_agent, pair.preset.target_task)
    assert obs > 0 and act > 0
