"""The two factories of every environment the catalogue (:mod:`pved.env_ids`) names.

``make`` builds the Gymnasium form, ``make_batched`` the batched one; the module of an
env's classes is imported the first time one of its envs is made. The catalogue's names
are handed on from here, where the package's users have always found them.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

import gymnasium as gym

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


def make_batched(env_id: str, num_envs: int, **kwargs: Any) -> BatchedEnv:
    """The batched form of ``env_id`` with ``num_envs`` copies (autoreset on).

    ``kwargs`` are the env's constructor arguments (e.g. ``reward="full"``, ``config=``).
    """
    entry = get_entry(env_id)
    _check_kwargs(entry, kwargs)
    cls = _load(entry.batched_entry_point)
    env: BatchedEnv = cls(num_envs=num_envs, **{**entry.kwargs, **kwargs})
    return env
