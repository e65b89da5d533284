"""Which environments exist, under which ids, and the two factories.

Ids are ``pved/<Agent><Task>-v0``. Each entry names the classes of both forms by
``"module:Class"`` strings, so registering every id on ``import pved`` imports no
simulator code; a module is imported the first time one of its envs is made.

Adding an environment: append an :class:`EnvEntry` to ``_ENTRIES``; ``AGENTS``, ``TASKS``
and the Gymnasium registration follow from it.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from pved.envs.base import BatchedEnv
from pved.errors import PvedError

NAMESPACE = "pved"
VERSION = 0


@dataclass(frozen=True)
class EnvEntry:
    """One registered environment.

    Attributes:
        agent: agent name, e.g. "Reacher3".
        task: task name, e.g. "Push".
        gym_entry_point: "module:Class" of the ``gymnasium.Env`` form.
        batched_entry_point: "module:Class" of the :class:`BatchedEnv` form, constructed
            as ``Class(num_envs=N, **kwargs, **user_kwargs)``.
        kwargs: constructor arguments both forms receive (e.g. the agent).
    """

    agent: str
    task: str
    gym_entry_point: str
    batched_entry_point: str
    kwargs: Mapping[str, Any] = field(default_factory=dict)

    @property
    def env_id(self) -> str:
        return f"{NAMESPACE}/{self.agent}{self.task}-v{VERSION}"


def _entry(module: str, prefix: str, agent: str, task: str) -> EnvEntry:
    """The env of ``agent`` on ``task`` from ``pved.envs.<module>``, whose classes are
    ``<prefix><task>Env`` (Gymnasium) and ``<prefix><task>Batched``."""
    return EnvEntry(
        agent=agent,
        task=task,
        gym_entry_point=f"pved.envs.{module}:{prefix}{task}Env",
        batched_entry_point=f"pved.envs.{module}:{prefix}{task}Batched",
        kwargs={"agent": agent},
    )


def _reacher(agent: str, task: str) -> EnvEntry:
    return _entry("reacher", "Reacher", agent, task)


def _arm(agent: str, task: str) -> EnvEntry:
    return _entry("arms", "Arm", agent, task)


def _locomotion(agent: str, task: str) -> EnvEntry:
    return _entry("locomotion", "Locomotion", agent, task)


_ENTRIES: tuple[EnvEntry, ...] = (
    _reacher("Reacher3", "Reach"),
    _reacher("Reacher4", "Reach"),
    _reacher("Reacher3", "Push"),
    _reacher("Reacher4", "Push"),
    # Robot-arm pair (source, target): Jaco -> Fetch4.
    _arm("Jaco", "Reach"),
    _arm("Fetch4", "Reach"),
    _arm("Jaco", "Peg"),
    _arm("Fetch4", "Peg"),
    # Locomotion pairs (source, target): Walker2d -> Hopper, Humanoid -> Ant.
    _locomotion("Walker2d", "Slope"),
    _locomotion("Hopper", "Slope"),
    _locomotion("Walker2d", "Curve"),
    _locomotion("Hopper", "Curve"),
    _locomotion("Humanoid", "Slope"),
    _locomotion("Ant", "Slope"),
    _locomotion("Humanoid", "Curve"),
    _locomotion("Ant", "Curve"),
)

#: Every registered id and its entry.
ENV_IDS: dict[str, EnvEntry] = {e.env_id: e for e in _ENTRIES}
#: Registered agents and tasks, in registration order.
AGENTS: tuple[str, ...] = tuple(dict.fromkeys(e.agent for e in _ENTRIES))
TASKS: tuple[str, ...] = tuple(dict.fromkeys(e.task for e in _ENTRIES))


def registered_env_ids() -> list[str]:
    """Every pved env id, in registration order."""
    return list(ENV_IDS)


def env_id(agent: str, task: str) -> str:
    """The id of ``agent`` on ``task``; raises :class:`PvedError` for an unknown agent,
    task or combination, listing the known ones."""
    if agent not in AGENTS:
        raise PvedError(f"unknown agent {agent!r}; known agents: {', '.join(AGENTS)}")
    if task not in TASKS:
        raise PvedError(f"unknown task {task!r}; known tasks: {', '.join(TASKS)}")
    for entry in _ENTRIES:
        if (entry.agent, entry.task) == (agent, task):
            return entry.env_id
    tasks = [e.task for e in _ENTRIES if e.agent == agent]
    raise PvedError(f"agent {agent!r} has no task {task!r}; its tasks: {', '.join(tasks)}")


def get_entry(env_id: str) -> EnvEntry:
    """The entry of ``env_id``; an unknown id raises :class:`PvedError` listing known ones."""
    try:
        return ENV_IDS[env_id]
    except KeyError:
        raise PvedError(f"unknown env id {env_id!r}; known ids: {', '.join(ENV_IDS)}") from None


def _load(entry_point: str) -> Any:
    module_name, _, attr = entry_point.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def register_envs() -> None:
    """Register every id with Gymnasium (idempotent; done on ``import pved``).

    No ``max_episode_steps`` is given to Gymnasium: each env truncates itself at its
    configured horizon, so no ``TimeLimit`` wrapper can disagree with its config.
    """
    for entry in _ENTRIES:
        if entry.env_id not in gym.registry:
            gym.register(
                id=entry.env_id,
                entry_point=entry.gym_entry_point,
                kwargs=dict(entry.kwargs),
            )


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
    env_id: str, num_envs: int, *, robot_state: Sequence[int] | None = None, **kwargs: Any
) -> BatchedEnv:
    """The batched form of ``env_id`` with ``num_envs`` copies (autoreset on).

    ``kwargs`` are the env's constructor arguments (e.g. ``reward="full"``, ``config=``).
    Any other Gymnasium id (a stock one, or ``module:EnvId``, whose module registers it)
    has no batched form of its own: it is batched by :class:`GymnasiumBatch` (its copies
    stepped one after another), with ``robot_state`` as its robot-state indices
    (default: the whole observation). A pved env reports its own; a ``robot_state``
    given for one must be that.
    """
    if not env_id.startswith(f"{NAMESPACE}/"):
        from pved.envs.gym_adapter import GymnasiumBatch

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
    return env
