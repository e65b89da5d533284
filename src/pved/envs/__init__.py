"""pved.envs: MuJoCo environments in two forms (batched and ``gymnasium.Env``).

``import pved`` registers every ``pved/<Agent><Task>-v0`` id with Gymnasium, from the
catalogue (:mod:`pved.env_ids`) without this package. ``make(env_id, **kwargs)`` builds
the Gymnasium form, ``make_batched(env_id, num_envs, **kwargs)`` the batched one;
``AGENTS``, ``TASKS`` and ``env_id(agent, task)`` list and name what exists.
"""

from pved.envs.base import BatchedEnv
from pved.envs.registry import (
    AGENTS,
    ENV_IDS,
    TASKS,
    EnvEntry,
    env_id,
    get_entry,
    make,
    make_batched,
    register_envs,
    registered_env_ids,
)

__all__ = [
    "AGENTS",
    "ENV_IDS",
    "TASKS",
    "BatchedEnv",
    "EnvEntry",
    "env_id",
    "get_entry",
    "make",
    "make_batched",
    "register_envs",
    "registered_env_ids",
]
