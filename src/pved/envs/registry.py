"""The two factories of every environment the catalogue (:mod:`pved.env_ids`) names.

``make`` builds the Gymnasium form, ``make_batched`` the batched one; the module of an
env's classes is imported the first time one of its envs is made. The catalogue's names
are handed on from here, where the package's users have always found them.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from pved.env_ids import (
    AGENTS,
    ENV_IDS,
    NAMESPACE,
    TASKS,
    VERSION,
    EnvEntry,
    env_id,
    get_entry,
    register_envs,
    registered_env_ids,
)
from pved.envs.base import BatchedEnv
from pved.errors import PvedError

__all__ = [
    "AGENTS",
    "ENV_IDS",
    "NAMESPACE",
    "TASKS",
    "VERSION",
    "EnvEntry",
    "env_id",
    "get_entry",
    "make",
    "make_batched",
    "register_envs",
    "registered_env_ids",
]


def _load(entry_point: str) -> Any:
    module_name, _, attr = entry_point.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def _check_kwargs(entry: EnvEntry, kwargs: Mapping[str, Any]) -> None:
    fixed = sorted(set(kwargs) & set(entry.kwargs))
    if fixed:
        raise PvedError(f"{entry.env_id} fixes {', '.join(fixed)}; choose another env id instead")


def make(env_id: str, **kwargs: Any) -> gym.Env[Any, Any]:
    """``gymnasium.make(env_id, **kwargs)`` after checking that ``env_id`` is a pved id.

    Example: ``make("pved/Reacher4Push-v0", reward="full", render_mode="rgb_array")``.
    """
    _check_kwargs(get_entry(env_id), kwargs)
    register_envs()
    return gym.make(env_id, **kwargs)


def make_batched(
    env_id: str,
    num_envs: int,
    *,
    robot_state: Sequence[int] | None = None,
    step_limit: int | None = None,
    **kwargs: Any,
) -> BatchedEnv:
    """The batched form of ``env_id`` with ``num_envs`` copies (autoreset on).

    ``kwargs`` are the env's constructor arguments (e.g. ``reward="full"``, ``config=``).
    Any other Gymnasium id (a stock one, or ``module:EnvId``, whose module registers it)
    has no batched form of its own: it is batched by :class:`GymnasiumBatch` (its copies
    stepped one after another), with ``robot_state`` as its robot-state indices
    (default: the whole observation). A pved env reports its own; a ``robot_state``
    given for one must be that. ``step_limit`` truncates episodes at that many control
    steps instead of the env's own limit (a source bank's rollouts reach as far as the
    target's episode: ``pved.transfer.source_bank.bank_step_limit``).
    """
    if step_limit is not None and (isinstance(step_limit, bool) or int(step_limit) < 1):
        raise PvedError(f"step_limit must be a whole number of steps >= 1, got {step_limit!r}")
    if not env_id.startswith(f"{NAMESPACE}/"):
        from pved.envs.gym_adapter import GymnasiumBatch

        if step_limit is not None:  # Gymnasium's own TimeLimit, set by make
            kwargs = {**kwargs, "max_episode_steps": int(step_limit)}
        state = None if robot_state is None else np.asarray(robot_state, dtype=np.int64)
        return GymnasiumBatch(
            env_id=env_id, num_envs=num_envs, make_kwargs=kwargs, robot_state_indices=state
        )
    entry = get_entry(env_id)
    _check_kwargs(entry, kwargs)
    cls = _load(entry.batched_entry_point)
    env: BatchedEnv = cls(num_envs=num_envs, **{**entry.kwargs, **kwargs})
    if robot_state is not None and [int(i) for i in robot_state] != [
        int(i) for i in env.robot_state_indices
    ]:
        env.close()
        raise PvedError(
            f"{env_id} reports its robot state at {[int(i) for i in env.robot_state_indices]}, "
            f"not {[int(i) for i in robot_state]}; give no robot_state for a pved env"
        )
    if step_limit is not None:  # every pved env truncates on this attribute at each step
        env.max_episode_steps = int(step_limit)
    return env
