"""Where a stage's inputs lie by default, and whether a given one fits the pair.

The stages (:mod:`pved.experiments.stages`) and the analyses that read their files find
a pair's dataset and models here, and refuse, in one line, a model or a source bank made
for another pair before any work.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pved.config import PairPreset, get_preset
from pved.env_ids import env_id
from pved.errors import PvedError
from pved.models.base import SharedSpaceModel
from pved.runs import run_path
from pved.transfer.source_bank import SourceBank

DEFAULT_RUNS = Path("runs")


def default_dataset_path(pair: str, runs_root: Path = DEFAULT_RUNS, seed: int = 0) -> Path:
    """The pair's paired dataset of its preset's alignment (``collect_pairs``' output)."""
    return run_path(runs_root, pair, "pairs", get_preset(pair).pairing.align, seed) / "pairs.npz"


def default_model_path(
    pair: str, model: str, runs_root: Path = DEFAULT_RUNS, seed: int = 0
) -> Path:
    """The pair's ``model`` trained by ``train_model`` with ``seed``."""
    return run_path(runs_root, pair, "model", model, seed) / "model.pt"


def check_model_for(
    preset: PairPreset,
    model: SharedSpaceModel,
    path: Path | str,
    method: str | None = None,
    target_robot_state: Sequence[int] | np.ndarray | None = None,
) -> None:
    """Refuse, in one line, a model made for another pair: its metadata's pair, agents
    and robot-state selection of the target (``target_robot_state``: the target env's,
    when known) against ``preset``'s, its name against ``method`` (when given). A key a
    model file lacks (one made before the key was written) is not checked."""
    meta = model.metadata
    wanted = {
        "pair": preset.name,
        "source_agent": preset.source_agent,
        "target_agent": preset.target_agent,
    }
    for key, want in wanted.items():
        if meta.get(key) not in (None, want):
            raise PvedError(
                f"model {path} was trained for another pair: its {key} is {meta[key]!r}, "
                f"{preset.name}'s is {want!r}"
            )
    if method is not None and model.name != method:
        raise PvedError(f"model {path} is a {model.name!r} model, not {method!r}")
    have = meta.get("robot_state_indices_target")
    if have is not None and target_robot_state is not None:
        if [int(i) for i in have] != [int(i) for i in target_robot_state]:
            raise PvedError(
                f"model {path} reads the target's robot state at {list(have)}, "
                f"the {preset.target_agent} env has it at {list(target_robot_state)}"
            )


def check_bank_for(
    preset: PairPreset, bank: SourceBank, path: Path | str, model: SharedSpaceModel | None = None
) -> None:
    """Refuse, in one line, a source bank made for another pair: its header's env (the
    pair's source agent on its target task), match keys and robot-state selection (that
    of ``model``'s source, when given) against the pair's. A key a bank file lacks is not
    checked."""
    header = bank.header
    want_env = env_id(preset.source_agent, preset.target_task)
    if header.get("env_id") not in (None, want_env):
        raise PvedError(
            f"source bank {path} was made on {header['env_id']}, {preset.name}'s is {want_env}"
        )
    keys = header.get("match_keys")
    if keys is not None and list(keys) != list(preset.bank_match_keys):
        raise PvedError(
            f"source bank {path} matches on {list(keys)}, {preset.name} on "
            f"{list(preset.bank_match_keys)}"
        )
    have = header.get("robot_state_indices")
    want = None if model is None else model.metadata.get("robot_state_indices_source")
    if have is not None and want is not None and list(have) != list(want):
        raise PvedError(
            f"source bank {path} holds the source's robot state at {list(have)}, "
            f"the model reads it at {list(want)}"
        )
