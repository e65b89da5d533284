"""Where a source comes from when it is not a pved policy: the stages' side of it.

A pair's source is a policy file (pved's or SB3's: ``pved.rl.external``) or recorded
episodes in a Minari dataset (``pved.pairing.minari_io``). This module resolves a stage's
source options into one of the two, checks a dataset against the source agent before
any work, and exports pved's own source rollouts as a Minari dataset
(``pved export-minari``), e.g. to test the recorded route on data whose policy is known.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pved.checks import check_int, check_seed
from pved.config import EVAL_NUM_ENVS
from pved.envs import make_batched
from pved.envs.base import BatchedEnv
from pved.errors import OptionError, PvedError
from pved.pair import Pair, resolve_pair
from pved.pairing.collect import Episode, rollout_first_episodes
from pved.pairing.minari_io import (
    RecordedData,
    check_new_dataset_id,
    check_recorded_for,
    export_episodes,
    open_recorded,
    read_recorded_episodes,
)
from pved.rl.external import load_policy_file
from pved.run_layout import policy_path


def check_one_source(source_policy: object, source_dataset: object) -> None:
    """A stage takes its source from a policy or from a dataset, not both."""
    if source_policy is not None and source_dataset is not None:
        raise OptionError(
            "--source-dataset", source_dataset, "given without --source-policy (one source)"
        )


def recorded_episodes(
    data: RecordedData,
    env_name: str,
    env: BatchedEnv,
    task_keys: tuple[str, ...],
    episodes: int | None,
) -> list[Episode]:
    """The first ``episodes`` (default all) of ``data`` after checking it was recorded
    for ``env``'s agent; asking for more than it holds is refused in one line."""
    check_recorded_for(data, env_name, env)
    if data.episodes == 0:
        raise PvedError(f"Minari dataset {data.ref} holds no episodes")
    if episodes is not None and episodes > data.episodes:
        raise PvedError(
            f"Minari dataset {data.ref} holds {data.episodes} episodes, {episodes} were asked for"
        )
    return read_recorded_episodes(data, task_keys, limit=episodes)


def export_source_dataset(
    pair: str | Path | Pair,
    dataset_id: str,
    *,
    task: str | None = None,
    source_policy: Path | str | None = None,
    episodes: int = 100,
    seed: int = 0,
    deterministic: bool = True,
    runs_root: Path | None = None,
) -> Path:
    """Roll out the pair's source agent on ``task`` (default: the pair's target task,
    what a bank holds; its training task is what pairing reads) and write the episodes
    as the Minari dataset ``dataset_id``; returns its folder.

    Episode ``j`` is reset with seed ``seed + j`` and rolled out in the batch size
    ``build_bank`` (target task) or ``collect-pairs`` (training task) use, so a bank or
    pairs made from the dataset equal, bit for bit, those made from the same policy and
    seed directly. The episodes' task parameters (the pair's bank match
    keys on the target task, its shared task keys on the training task) are their reset
    options.

    The source's env and policy are the pair spec's (:meth:`~pved.pair.Pair.env`,
    :func:`~pved.run_layout.policy_path`: a shipped policy, the pair's own
    ``train-policy`` run under ``runs_root``, or the file the spec names), as every other
    stage finds them, so a spec pair whose agents pved does not know exports as a built-in
    one does.
    """
    pair = resolve_pair(pair, runs_root)
    preset = pair.preset
    task = preset.target_task if task is None else task
    if task not in (preset.training_task, preset.target_task):
        raise PvedError(
            f"unknown task {task!r} for {pair.name}: its tasks are {preset.training_task} "
            f"(training) and {preset.target_task} (target)"
        )
    check_int("--episodes", episodes, low=1)
    check_seed("--seed", seed)
    check_new_dataset_id(dataset_id)
    keys = preset.bank_match_keys if task == preset.target_task else preset.shared_task_keys
    name, env_kwargs = pair.env(preset.source_agent, task)
    path = policy_path(pair, preset.source_agent, task, source_policy)
    # the batch the consuming stage rolls out in: the policy's float32 forward pass rounds
    # by batch size (BLAS blocking, ~1e-7), and only the same batch repeats it bit for bit
    copies = min(EVAL_NUM_ENVS, episodes) if task == preset.target_task else preset.pairing.num_envs
    env = make_batched(name, copies, **env_kwargs)
    policy = load_policy_file(path, env=env, env_name=name)
    eps: list[Episode] = []
    for b in range(-(-episodes // env.num_envs)):
        eps.extend(
            rollout_first_episodes(env, policy, seed + b * env.num_envs, None, deterministic)
        )
    provenance: dict[str, Any] = {
        "pair": pair.name,
        "agent": preset.source_agent,
        "task": task,
        "env_id": name,
        "policy": str(path),
        "seed": seed,
        "deterministic_actions": deterministic,
    }
    return export_episodes(
        dataset_id,
        eps[:episodes],
        env_name=name,
        task_keys=tuple(keys),
        seeds=[seed + j for j in range(episodes)],
        algorithm_name=f"pved rollouts of {path.name}",
        description=f"{preset.source_agent} on {task}, exported by pved for pair {pair.name}",
        provenance=provenance,
    )


__all__ = [
    "RecordedData",
    "check_one_source",
    "export_source_dataset",
    "open_recorded",
    "recorded_episodes",
]
