"""Where a stage's inputs and runs lie by default, and whether a given input fits the pair.

The stages (:mod:`pved.experiments.stages`), the protocol, and the analyses and
diagnostics that read their files find a pair's dataset, models, policies and transfer
runs here, and refuse, in one line, a model or a source bank made for another pair
before any work. It sits below both the experiments and the analyses, so that reading a
run directory never needs the code that runs stages.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pved.config import PRETRAINED, TRAINED, PairPreset
from pved.envs import make_batched
from pved.errors import PvedError
from pved.models.base import SharedSpaceModel
from pved.pretrained import pretrained_policy_path
from pved.runs import file_digest, run_file, run_path
from pved.spec import builtin_names, get_preset, spec_identity
from pved.transfer.source_bank import SourceBank, bank_step_limit, bank_time_scale

DEFAULT_RUNS = Path("runs")


def default_dataset_path(pair: str, runs_root: Path = DEFAULT_RUNS, seed: int = 0) -> Path:
    """The pair's paired dataset of its preset's alignment (``collect_pairs``' output)."""
    preset = get_preset(pair)
    return run_path(runs_root, preset.name, "pairs", preset.pairing.align, seed) / "pairs.npz"


def default_model_path(
    pair: str, model: str, runs_root: Path = DEFAULT_RUNS, seed: int = 0
) -> Path:
    """The pair's ``model`` trained by ``train_model`` with ``seed``."""
    return run_path(runs_root, get_preset(pair).name, "model", model, seed) / "model.pt"


def env_of(preset: PairPreset, agent: str, task: str) -> tuple[str, dict[str, Any]]:
    """``agent``'s env on ``task`` in ``preset``: its id, and the arguments
    :func:`~pved.envs.make_batched` takes for it (the spec's ``kwargs``, and its
    ``robot_state`` where the spec names one)."""
    entry = preset.agent_env(agent, task)
    kwargs: dict[str, Any] = dict(entry.kwargs)
    state = preset.robot_state_of(agent)
    if state is not None:
        kwargs["robot_state"] = state
    return entry.env_id, kwargs


def policy_path(
    preset: PairPreset,
    agent: str,
    task: str,
    given: Path | str | None = None,
    runs_root: Path = DEFAULT_RUNS,
) -> Path:
    """The policy file ``agent`` acts with on ``task``: ``given`` (a file or its run
    directory), else what the pair's spec names: the policy shipped with pved, the
    pair's own ``pved train-policy`` run (seed 0, under ``runs_root``), or a file (a pved
    policy or a Stable-Baselines3 ``.zip``). Every stage finds its policies here and reads
    them with :func:`pved.rl.external.load_policy_file`."""
    if given is not None:
        return run_file(given, "policy.pt", f"{agent}'s policy")
    choice = preset.agent_env(agent, task).policy
    if choice == PRETRAINED:
        return pretrained_policy_path(agent, task)
    if choice == TRAINED:
        trained = run_path(runs_root, preset.name, "policy", f"{agent}-{task}", 0) / "policy.pt"
        if not trained.is_file():
            spec = preset.name if preset.name in builtin_names() else "SPEC.toml"
            raise PvedError(
                f"{agent}'s policy on {task} not found: {trained} (not trained yet: "
                f"pved train-policy --pair {spec} --agent {agent} --task {task})"
            )
        return trained
    return run_file(choice, "policy.pt", f"{agent}'s policy on {task} (the spec's)")


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
    check_spec(preset, meta, f"model {path}")
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
    want_env = preset.agent_env(preset.source_agent, preset.target_task).env_id
    if header.get("env_id") not in (None, want_env):
        raise PvedError(
            f"source bank {path} was made on {header['env_id']}, {preset.name}'s is {want_env}"
        )
    check_spec(preset, header, f"source bank {path}")
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


def check_spec(preset: PairPreset, header: dict[str, Any], what: str) -> None:
    """Refuse a file made under another version of ``preset``'s spec (or for a built-in
    pair when ``preset`` is a spec of its own, and the reverse): its ``spec`` digest
    (:func:`pved.spec.spec_identity`) against the pair's."""
    want = spec_identity(preset).get("spec")
    have = header.get("spec")
    if have != want:
        raise PvedError(
            f"{what} was made under another spec of {preset.name} (its spec digest "
            f"{have or 'none: a built-in pair'}, this spec's {want or 'none: a built-in pair'})"
        )


def check_dataset_for(preset: PairPreset, header: dict[str, Any], path: Path | str) -> None:
    """Refuse, in one line, a paired dataset collected for another pair or spec, or on
    robot-state indices other than the spec names (its header against ``preset``)."""
    if header.get("pair") not in (None, preset.name):
        raise PvedError(
            f"dataset {path} was collected for pair {header['pair']!r}, not {preset.name!r}"
        )
    check_spec(preset, header, f"dataset {path}")
    for side, agent in (("source", preset.source_agent), ("target", preset.target_agent)):
        want = preset.robot_state_of(agent)
        have = header.get(f"robot_state_indices_{side}")
        if want is not None and have is not None and [int(i) for i in have] != list(want):
            raise PvedError(
                f"dataset {path} holds the {side}'s robot state at {list(have)}, the spec "
                f"names {list(want)}"
            )


def bank_rollout_steps(preset: PairPreset, name: str, env_kwargs: dict[str, Any]) -> int | None:
    """The step limit a bank's rollouts on the source env ``name`` need to reach as far as
    the target's target-task episode, on the pairs' time base
    (:func:`~pved.transfer.source_bank.bank_step_limit`); None where the source env's own
    limit already does (docs/decisions/transfer.md, "A target step past the source's end")."""
    tgt_name, tgt_kwargs = env_of(preset, preset.target_agent, preset.target_task)
    source, target = make_batched(name, 1, **env_kwargs), make_batched(tgt_name, 1, **tgt_kwargs)
    try:
        own = int(source.max_episode_steps)
        scale = bank_time_scale(
            preset.pairing.align, getattr(source, "dt", None), getattr(target, "dt", None)
        )
        need = bank_step_limit(int(target.max_episode_steps), scale)
    finally:
        source.close()
        target.close()
    return need if need > own else None


def model_dataset_path(
    preset: PairPreset, model: SharedSpaceModel, runs_root: Path = DEFAULT_RUNS
) -> Path:
    """The paired dataset ``model`` was fitted on: the pair's collected dataset under
    ``runs_root`` (its default first, then any other alignment or seed) whose digest is the
    one the model's metadata names. :class:`PvedError` naming where it looked when none
    is, or when the model names none."""
    want = model.metadata.get("dataset")
    if not want:
        raise PvedError(
            f"the model names no training dataset (fitted outside {preset.name}'s stages)"
        )
    first = default_dataset_path(preset.name, runs_root)
    others = sorted(Path(runs_root, preset.name, "pairs").glob("*/seed*/pairs.npz"))
    for path in [first, *(p for p in others if p != first)]:
        if path.is_file() and file_digest(path) == want:
            return path
    raise PvedError(
        f"the model's training pairs (digest {want}) are not under "
        f"{Path(runs_root, preset.name, 'pairs')}: collect them there (pved collect-pairs)"
    )


def transfer_run_name(method: str, beta: float, init: int, source: int) -> str:
    """The run directory name of a shaped method's transfer run in a protocol:
    ``<method>-beta<β>-init<model init>-src<source policy>`` (one ``seed<k>`` below it
    per PPO seed)."""
    return f"{method}-beta{beta:g}-init{init}-src{source}"


_SHAPED_RUN_NAME = re.compile(r"^(?P<method>.+)-beta[^/]+-init\d+-src\d+$")


def transfer_run_method(name: str) -> str:
    """The method of a transfer run directory name: the ``<method>`` of
    :func:`transfer_run_name`'s, else the name itself (``ppo``, ``oracle``)."""
    match = _SHAPED_RUN_NAME.match(name)
    return match["method"] if match else name
