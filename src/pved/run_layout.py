"""Whether a given input fits the pair, and where the files a stage reads are found.

The stages (:mod:`pved.experiments.stages`), the protocol, and the analyses and
diagnostics that read their files refuse here, in one line, a model, a source bank or a
dataset made for another pair or spec, before any work; they find the policy an agent
acts with, the dataset a model was fitted on, and name a protocol's transfer runs. Every
function takes the pair resolved at the door (:class:`pved.pair.Pair`, whose ``runs``
says where each stage's output lies). It sits below both the experiments and the
analyses, so that reading a run directory never needs the code that runs stages.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pved.config import PRETRAINED, TRAINED
from pved.envs import make_batched
from pved.errors import PvedError
from pved.models.base import SharedSpaceModel
from pved.pair import DEFAULT_RUNS, Pair
from pved.pretrained import pretrained_policy_path
from pved.runs import file_digest, run_file
from pved.spec import builtin_names
from pved.transfer.source_bank import SourceBank, bank_step_limit, bank_time_scale

__all__ = [
    "DEFAULT_RUNS",
    "bank_rollout_steps",
    "check_bank_for",
    "check_dataset_for",
    "check_model_for",
    "check_spec",
    "model_dataset_path",
    "policy_path",
    "transfer_run_method",
    "transfer_run_name",
]


def policy_path(pair: Pair, agent: str, task: str, given: Path | str | None = None) -> Path:
    """The policy file ``agent`` acts with on ``task``: ``given`` (a file or its run
    directory), else what the pair's spec names: the policy shipped with pved, the
    pair's own ``pved train-policy`` run (seed 0, under the pair's runs root), or a file (a pved
    policy or a Stable-Baselines3 ``.zip``). Every stage finds its policies here and reads
    them with :func:`pved.rl.external.load_policy_file`."""
    if given is not None:
        return run_file(given, "policy.pt", f"{agent}'s policy")
    choice = pair.preset.agent_env(agent, task).policy
    if choice == PRETRAINED:
        return pretrained_policy_path(agent, task)
    if choice == TRAINED:
        trained = pair.runs.policy(agent, task)
        if not trained.is_file():
            spec = pair.name if pair.name in builtin_names() else "SPEC.toml"
            raise PvedError(
                f"{agent}'s policy on {task} not found: {trained} (not trained yet: "
                f"pved train-policy --pair {spec} --agent {agent} --task {task})"
            )
        return trained
    return run_file(choice, "policy.pt", f"{agent}'s policy on {task} (the spec's)")


def check_model_for(
    pair: Pair,
    model: SharedSpaceModel,
    path: Path | str,
    method: str | None = None,
    target_robot_state: Sequence[int] | np.ndarray | None = None,
) -> None:
    """Refuse, in one line, a model made for another pair: its metadata's pair, agents
    and robot-state selection of the target (``target_robot_state``: the target env's,
    when known) against ``pair``'s, its name against ``method`` (when given). A key a
    model file lacks (one made before the key was written) is not checked."""
    meta, preset = model.metadata, pair.preset
    wanted = {
        "pair": pair.name,
        "source_agent": preset.source_agent,
        "target_agent": preset.target_agent,
    }
    for key, want in wanted.items():
        if meta.get(key) not in (None, want):
            raise PvedError(
                f"model {path} was trained for another pair: its {key} is {meta[key]!r}, "
                f"{pair.name}'s is {want!r}"
            )
    check_spec(pair, meta, f"model {path}")
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
    pair: Pair, bank: SourceBank, path: Path | str, model: SharedSpaceModel | None = None
) -> None:
    """Refuse, in one line, a source bank made for another pair: its header's env (the
    pair's source agent on its target task), match keys and robot-state selection (that
    of ``model``'s source, when given) against the pair's. A key a bank file lacks is not
    checked."""
    header, match_keys = bank.header, pair.preset.bank_match_keys
    want_env = pair.bank_env[0]
    if header.get("env_id") not in (None, want_env):
        raise PvedError(
            f"source bank {path} was made on {header['env_id']}, {pair.name}'s is {want_env}"
        )
    check_spec(pair, header, f"source bank {path}")
    keys = header.get("match_keys")
    if keys is not None and list(keys) != list(match_keys):
        raise PvedError(
            f"source bank {path} matches on {list(keys)}, {pair.name} on {list(match_keys)}"
        )
    have = header.get("robot_state_indices")
    want = None if model is None else model.metadata.get("robot_state_indices_source")
    if have is not None and want is not None and list(have) != list(want):
        raise PvedError(
            f"source bank {path} holds the source's robot state at {list(have)}, "
            f"the model reads it at {list(want)}"
        )


def check_spec(pair: Pair, header: dict[str, Any], what: str) -> None:
    """Refuse a file made under another version of ``pair``'s spec (or for a built-in
    pair when ``pair`` is a spec of its own, and the reverse): its ``spec`` digest
    against the pair's (:attr:`pved.pair.Pair.identity`)."""
    want = pair.identity.get("spec")
    have = header.get("spec")
    if have != want:
        raise PvedError(
            f"{what} was made under another spec of {pair.name} (its spec digest "
            f"{have or 'none: a built-in pair'}, this spec's {want or 'none: a built-in pair'})"
        )


def check_dataset_for(pair: Pair, header: dict[str, Any], path: Path | str) -> None:
    """Refuse, in one line, a paired dataset collected for another pair or spec, or on
    robot-state indices other than the spec names (its header against ``pair``)."""
    if header.get("pair") not in (None, pair.name):
        raise PvedError(
            f"dataset {path} was collected for pair {header['pair']!r}, not {pair.name!r}"
        )
    check_spec(pair, header, f"dataset {path}")
    for side, agent in (("source", pair.preset.source_agent), ("target", pair.preset.target_agent)):
        want = pair.preset.robot_state_of(agent)
        have = header.get(f"robot_state_indices_{side}")
        if want is not None and have is not None and [int(i) for i in have] != list(want):
            raise PvedError(
                f"dataset {path} holds the {side}'s robot state at {list(have)}, the spec "
                f"names {list(want)}"
            )


def bank_rollout_steps(pair: Pair) -> int | None:
    """The step limit a bank's rollouts on the source env (:attr:`Pair.bank_env`) need
    to reach as far as the target's target-task episode, on the pairs' time base
    (:func:`~pved.transfer.source_bank.bank_step_limit`); None where the source env's own
    limit already does (docs/decisions/transfer.md, "A target step past the source's end")."""
    (src_name, src_kwargs), (tgt_name, tgt_kwargs) = pair.bank_env, pair.target_env
    source = make_batched(src_name, 1, **src_kwargs)
    target = make_batched(tgt_name, 1, **tgt_kwargs)
    try:
        own = int(source.max_episode_steps)
        scale = bank_time_scale(
            pair.preset.pairing.align, getattr(source, "dt", None), getattr(target, "dt", None)
        )
        need = bank_step_limit(int(target.max_episode_steps), scale)
    finally:
        source.close()
        target.close()
    return need if need > own else None


def model_dataset_path(pair: Pair, model: SharedSpaceModel) -> Path:
    """The paired dataset ``model`` was fitted on: the pair's collected dataset under its
    runs root (its default first, then any other alignment or seed) whose digest is the
    one the model's metadata names. :class:`PvedError` naming where it looked when none
    is, or when the model names none."""
    want = model.metadata.get("dataset")
    if not want:
        raise PvedError(
            f"the model names no training dataset (fitted outside {pair.name}'s stages)"
        )
    first = pair.runs.dataset(pair.preset.pairing.align)
    where = first.parents[2]
    others = sorted(where.glob("*/seed*/pairs.npz"))
    for path in [first, *(p for p in others if p != first)]:
        if path.is_file() and file_digest(path) == want:
            return path
    raise PvedError(
        f"the model's training pairs (digest {want}) are not under {where}: collect them "
        "there (pved collect-pairs)"
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
