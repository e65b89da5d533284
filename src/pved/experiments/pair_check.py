"""``pved pair check SPEC``: a pair spec tried against its envs and policies before any
stage runs.

Every env of the spec is made (one copy) and reset; its robot-state indices, the task
keys its reset info must report, the metric's info keys and the policies' dims are
checked. The first mistake is one :class:`PvedError` line naming the spec's field; a
spec that passes gets a summary of both agents' dims and of what will be paired.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pved.config import PRETRAINED, TRAINED, PairPreset
from pved.envs import BatchedEnv, make_batched
from pved.errors import PvedError
from pved.pair import Pair, resolve_pair
from pved.rl.external import load_policy_file
from pved.run_layout import policy_path

#: ``evaluate_policy``'s results a metric can name besides ``<info key>_mean``.
METRICS = ("return_mean", "length_mean", "completion_rate", "success_rate")


def _field(preset: PairPreset, agent: str, task: str) -> str:
    side = "source" if agent == preset.source_agent else "target"
    role = "training" if task == preset.training_task else "target"
    return f"{side}.{role}"


def _make(pair: Pair, agent: str, task: str) -> BatchedEnv:
    name, kwargs = pair.env(agent, task)
    preset = pair.preset
    field = _field(preset, agent, task)
    try:
        return make_batched(name, 1, **kwargs)
    except PvedError as exc:
        raise PvedError(f"{preset.name}: {field}.env: {exc}") from None


def _info_keys(info: dict[str, Any]) -> str:
    keys = sorted(k for k in info if k != "final_obs")
    return ", ".join(keys) or "none"


def _check_keys(
    preset: PairPreset, field: str, keys: tuple[str, ...], env: BatchedEnv, env_name: str
) -> dict[str, np.ndarray]:
    """The reset info of ``env`` (seed 0) must hold each of ``keys``; returns it."""
    _, info = env.reset(seed=0)
    for key in keys:
        if key not in info:
            raise PvedError(
                f"{preset.name}: {field}: {key!r} is not in {env_name}'s reset info (its "
                f"keys: {_info_keys(info)}); a stock env reports none: write []"
            )
    return info


def check_pair(pair: str | Path | Pair, runs_root: Path | None = None) -> str:
    """Check the spec ``pair`` against its envs and policies; returns the summary text
    ``pved pair check`` prints. Raises :class:`PvedError` on the first mistake."""
    pair = resolve_pair(pair, runs_root)
    preset = pair.preset
    agents = (preset.source_agent, preset.target_agent)
    tasks = (preset.training_task, preset.target_task)
    envs = {(a, t): _make(pair, a, t) for a in agents for t in tasks}
    try:
        return _check(pair, envs)
    finally:
        for env in envs.values():
            env.close()


def _check(pair: Pair, envs: dict[tuple[str, str], BatchedEnv]) -> str:
    preset = pair.preset
    src, tgt = preset.source_agent, preset.target_agent
    train, target = preset.training_task, preset.target_task
    lines = [f"pair {preset.name}: {src} -> {tgt}, trained on {train}, transferred on {target}"]
    for agent in (src, tgt):
        shapes = set()
        for task in (train, target):
            env = envs[(agent, task)]
            obs_dim = env.single_observation_space.shape[0]
            act_dim = env.single_action_space.shape[0]
            shapes.add((len(env.robot_state_indices), act_dim))
            name = preset.agent_env(agent, task).env_id
            lines.append(
                f"  {agent} on {task}: {name}, obs {obs_dim}, act {act_dim}, robot state "
                f"{len(env.robot_state_indices)} entries {_span(env.robot_state_indices)}"
            )
        if len(shapes) > 1:
            side = "source" if agent == src else "target"
            raise PvedError(
                f"{preset.name}: {side}: {agent}'s envs on {train} and {target} differ in "
                "action or robot-state size; the model reads one body on both tasks"
            )

    # the task parameters: the source's reset reports them, the target takes them as
    # reset options and reports them back (as collect-pairs does)
    shared = preset.shared_task_keys
    info = _check_keys(preset, "tasks.shared", shared, envs[(src, train)], _id(preset, src, train))
    if shared:
        options = {k: np.asarray(info[k]) for k in shared}
        try:
            _, back = envs[(tgt, train)].reset(seed=0, options=options)
        except Exception as exc:  # the env's own refusal of an option, whatever its type
            raise PvedError(
                f"{preset.name}: tasks.shared: {_id(preset, tgt, train)} does not take "
                f"{', '.join(shared)} as reset options: {exc}"
            ) from None
        for key in shared:
            if key not in back or not np.allclose(back[key], options[key]):
                raise PvedError(
                    f"{preset.name}: tasks.shared: {_id(preset, tgt, train)} did not take "
                    f"the shared task parameter {key!r} from its reset options"
                )
    for agent in (src, tgt):
        _check_keys(
            preset,
            "tasks.bank_match",
            preset.bank_match_keys,
            envs[(agent, target)],
            _id(preset, agent, target),
        )

    # the metric: a result evaluate_policy gives on the target task
    metrics = (*METRICS, *(f"{k}_mean" for k in preset.eval_info_keys))
    if preset.metric not in metrics:
        raise PvedError(
            f"{preset.name}: metric.name: {preset.metric!r} is none of {', '.join(metrics)}"
        )
    env = envs[(tgt, target)]
    env.reset(seed=0)
    action = np.zeros((1, env.single_action_space.shape[0]))
    _, _, _, _, step_info = env.step(action)
    wanted = (*preset.eval_info_keys, *(("is_success",) if preset.metric == "success_rate" else ()))
    for key in wanted:
        if key not in step_info:
            raise PvedError(
                f"{preset.name}: metric: {key!r} is not in {_id(preset, tgt, target)}'s step "
                f"info (its keys: {_info_keys(step_info)})"
            )

    # the policies the stages act with: both agents' on the training task, the source's
    # on the target task (the target's there is what transfer learns)
    for agent, task in ((src, train), (tgt, train), (src, target)):
        field = f"{_field(preset, agent, task)}.policy"
        choice = preset.agent_env(agent, task).policy
        try:
            path = policy_path(pair, agent, task)
        except PvedError as exc:
            if choice == TRAINED:  # not trained yet: a step to take, not a mistake
                lines.append(f"  {agent}'s policy on {task}: {str(exc).partition('(')[2][:-1]}")
                continue
            raise PvedError(f"{preset.name}: {field}: {exc}") from None
        policy = load_policy_file(path)
        env = envs[(agent, task)]
        obs_dim = env.single_observation_space.shape[0]
        act_dim = env.single_action_space.shape[0]
        if (policy.obs_dim, policy.act_dim) != (obs_dim, act_dim):
            raise PvedError(
                f"{preset.name}: {field}: {path} has obs {policy.obs_dim}, act "
                f"{policy.act_dim}; {_id(preset, agent, task)} has obs {obs_dim}, act {act_dim}"
            )
        where = "shipped with pved" if choice == PRETRAINED else str(path)
        lines.append(f"  {agent}'s policy on {task}: {where} (obs {obs_dim}, act {act_dim})")

    dims: list[str] = []
    for agent in (src, tgt):
        env = envs[(agent, train)]
        dims.append(
            f"{agent} robot state {len(env.robot_state_indices)} + action "
            f"{env.single_action_space.shape[0]}"
        )
    by = f"sharing {', '.join(shared)}" if shared else "by seed (no shared task parameter)"
    lines.append(
        f"  pairs: {preset.pairing.episodes} episodes on {train}, {by}, aligned by "
        f"{preset.pairing.align}: {dims[0]} <-> {dims[1]}"
    )
    match = ", ".join(preset.bank_match_keys) or "nothing (drawn at random)"
    lines.append(f"  bank: {src} on {target}, matched on {match}; metric {preset.metric}")
    lines.append("ok")
    return "\n".join(lines)


def _id(preset: PairPreset, agent: str, task: str) -> str:
    return preset.agent_env(agent, task).env_id


def _span(indices: np.ndarray) -> str:
    idx = [int(i) for i in indices]
    if idx and idx == list(range(idx[0], idx[-1] + 1)):
        return f"[{idx[0]}..{idx[-1]}]"
    return str(idx)
