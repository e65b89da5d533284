"""``GymnasiumBatch``: N copies of any Gymnasium env behind the BatchedEnv contract.

This is how a user's own Gymnasium env (or agent) meets pved's PPO and evaluation. It
steps the copies one after another in Python, so it is as fast as the env's own
``step``; pved's built-in envs step their batch in numpy instead.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from pved.envs.base import BatchedEnv, Info
from pved.errors import PvedError


def _is_numeric(value: Any) -> bool:
    arr = np.asarray(value)
    return arr.dtype.kind in "biuf"


class GymnasiumBatch(BatchedEnv):
    """N Gymnasium envs with same-step autoreset.

    When copy ``i`` ends inside :meth:`step` it is reset (without a seed, so it draws
    from its own generator, as Gymnasium's vector envs do); the returned observation is
    the new episode's first one and the old episode's last is ``info["final_obs"][i]``.
    For copies that did not end, ``final_obs`` holds their returned observation.

    ``info`` entries of the step that are numeric (scalars or fixed-shape arrays) become
    arrays with a leading batch axis; a copy whose info lacks a key gets NaN there. For a
    copy that ended, the values are those of its final step.

    Args:
        env_fns: one factory per copy, or
        env_id: a registered id (with ``num_envs`` and ``make_kwargs``) to ``gym.make``.
        robot_state_indices: observation indices of the robot's own state (default all).
    """

    def __init__(
        self,
        env_fns: Sequence[Callable[[], gym.Env[Any, Any]]] | None = None,
        *,
        env_id: str | None = None,
        num_envs: int = 1,
        make_kwargs: dict[str, Any] | None = None,
        robot_state_indices: np.ndarray | None = None,
    ) -> None:
        if (env_fns is None) == (env_id is None):
            raise PvedError("GymnasiumBatch needs exactly one of env_fns or env_id")
        if env_id is not None:
            if num_envs <= 0:
                raise PvedError(f"GymnasiumBatch needs num_envs > 0, got {num_envs}")
            kwargs = dict(make_kwargs or {})
            try:
                self.envs = [gym.make(env_id, **kwargs) for _ in range(num_envs)]
            except gym.error.Error as exc:
                # Gymnasium's own message names the id and, for a typo, the near ones
                raise PvedError(f"unknown env id {env_id!r}: {exc}") from None
            except (TypeError, ValueError, ImportError, AttributeError) as exc:
                # an argument the env does not take, a module that does not import
                raise PvedError(f"cannot make Gymnasium env {env_id!r}: {exc}") from None
        else:
            assert env_fns is not None
            if len(env_fns) == 0:
                raise PvedError("GymnasiumBatch needs at least one env")
            self.envs = [fn() for fn in env_fns]
        self.num_envs = len(self.envs)
        first = self.envs[0]
        obs_space, act_space = first.observation_space, first.action_space
        if not isinstance(obs_space, gym.spaces.Box) or not isinstance(act_space, gym.spaces.Box):
            raise PvedError("GymnasiumBatch needs Box observation and action spaces")
        for env in self.envs[1:]:
            if env.observation_space != obs_space or env.action_space != act_space:
                raise PvedError("GymnasiumBatch copies must share observation and action spaces")
        self.single_observation_space = obs_space
        self.single_action_space = act_space
        self.env_id = (
            env_id
            if env_id is not None
            else (first.spec.id if first.spec else type(first.unwrapped).__name__)
        )
        obs_dim = int(np.prod(obs_space.shape))
        self.robot_state_indices = (
            np.arange(obs_dim) if robot_state_indices is None else np.asarray(robot_state_indices)
        )
        bad = [int(i) for i in self.robot_state_indices if not 0 <= int(i) < obs_dim]
        if bad:
            raise PvedError(
                f"robot state index {bad[0]} is outside {self.env_id}'s observation "
                f"(size {obs_dim})"
            )
        # the control period, for alignment by physical time (MuJoCo envs have one)
        dt = getattr(first.unwrapped, "dt", None)
        self.dt: float | None = None if dt is None else float(dt)
        spec_steps = first.spec.max_episode_steps if first.spec is not None else None
        self.max_episode_steps = int(spec_steps) if spec_steps is not None else 1000
        self._obs_dim = obs_dim

    def _stack_obs(self, obs: Sequence[Any]) -> np.ndarray:
        return np.stack([np.asarray(o, dtype=np.float64).reshape(self._obs_dim) for o in obs])

    @staticmethod
    def _stack_info(infos: Sequence[dict[str, Any]], n: int) -> Info:
        keys: dict[str, tuple[int, ...]] = {}
        for info in infos:
            for k, v in info.items():
                if k not in keys and _is_numeric(v):
                    keys[k] = np.shape(v)
        out: Info = {}
        for k, shape in keys.items():
            arr = np.full((n, *shape), np.nan)
            for i, info in enumerate(infos):
                if k in info and _is_numeric(info[k]) and np.shape(info[k]) == shape:
                    arr[i] = info[k]
            out[k] = arr
        return out

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, Info]:
        # batched options (one row per copy, as the pairing passes shared task
        # parameters) are handed to each copy as its own row
        results = [
            env.reset(seed=None if seed is None else seed + i, options=self._row(options, i))
            for i, env in enumerate(self.envs)
        ]
        obs = self._stack_obs([r[0] for r in results])
        return obs, self._stack_info([r[1] for r in results], self.num_envs)

    def _row(self, options: dict[str, Any] | None, i: int) -> dict[str, Any] | None:
        if options is None:
            return None
        out = {}
        for key, value in options.items():
            arr = np.asarray(value)
            out[key] = arr[i] if arr.ndim > 0 and arr.shape[0] == self.num_envs else value
        return out

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Info]:
        actions = np.asarray(actions)
        if actions.shape[0] != self.num_envs:
            raise PvedError(
                f"GymnasiumBatch.step expects {self.num_envs} actions, got shape {actions.shape}"
            )
        n = self.num_envs
        obs_list: list[Any] = []
        final_list: list[Any] = []
        rewards = np.zeros(n)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        infos: list[dict[str, Any]] = []
        for i, env in enumerate(self.envs):
            obs, reward, term, trunc, info = env.step(actions[i])
            rewards[i], terminated[i], truncated[i] = float(reward), bool(term), bool(trunc)
            final_list.append(obs)
            if term or trunc:
                obs, _ = env.reset()
            obs_list.append(obs)
            infos.append(dict(info))
        out_info = self._stack_info(infos, n)
        out_info["final_obs"] = self._stack_obs(final_list)
        return self._stack_obs(obs_list), rewards, terminated, truncated, out_info

    def close(self) -> None:
        for env in self.envs:
            env.close()
