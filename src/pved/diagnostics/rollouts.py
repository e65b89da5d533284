"""Gymnasium-form rollouts of a source and a target policy, kept for re-simulation.

The analyses of a transferred target (paper IV.C: :mod:`pved.diagnostics.tsne`, Theorem 1's
bound in :mod:`pved.diagnostics.bound`, the clips of :mod:`pved.diagnostics.video`) all start
from the same thing: one episode per seed of each agent, the target reset with the
source's task parameters so both solve the same task instance, and each step's model row
``x = concat(robot_state, action)`` (III.C, Eq. 7).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from pved.envs.registry import make
from pved.errors import PvedError
from pved.rl.policy import Policy


@dataclass
class EpisodeRecord:
    """One Gymnasium-form episode, kept with what re-simulating it needs.

    ``obs[t]`` is the observation ``act[t]`` was taken in and ``reward[t]`` the reward of
    that step; replaying ``act`` after ``reset(seed=seed, options=options)`` reproduces
    the episode exactly (the simulation is deterministic given the seed).
    """

    obs: np.ndarray  # (T, obs_dim)
    act: np.ndarray  # (T, act_dim)
    reward: np.ndarray  # (T,)
    seed: int
    options: dict[str, np.ndarray] | None
    reset_info: dict[str, Any]
    success: bool
    # (T,) the env's info["x_position"] (torso x, m, locomotion envs) in the state obs[t]
    # describes; None where the env does not report it (Reacher, Jaco/Fetch).
    x_position: np.ndarray | None = None

    @property
    def length(self) -> int:
        return int(self.act.shape[0])


def make_env(
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    *,
    render: bool = False,
    width: int = 240,
    height: int = 240,
) -> Any:
    """The Gymnasium form of ``env_id``; with ``render`` an offscreen ``rgb_array`` env of
    the given image size (envs without size arguments fall back to their default)."""
    kwargs = dict(env_kwargs or {})
    if not render:
        return make(env_id, **kwargs)
    try:
        return make(env_id, render_mode="rgb_array", width=width, height=height, **kwargs)
    except TypeError:  # an env whose constructor has no width/height
        return make(env_id, render_mode="rgb_array", **kwargs)


def _check_policy(policy: Policy, env: Any, name: str) -> None:
    obs_dim = env.observation_space.shape[0]
    act_dim = env.action_space.shape[0]
    if policy.obs_dim != obs_dim or policy.act_dim != act_dim:
        raise PvedError(
            f"{name} policy dims (obs {policy.obs_dim}, act {policy.act_dim}) do not match "
            f"its env (obs {obs_dim}, act {act_dim})"
        )


def run_episode(
    env: Any,
    policy: Policy,
    seed: int,
    options: Mapping[str, Any] | None = None,
    *,
    max_steps: int | None = None,
    deterministic: bool = True,
    frames: list[np.ndarray] | None = None,
) -> EpisodeRecord:
    """Run one episode of ``policy`` in the Gymnasium-form ``env`` (reset with ``seed`` and
    ``options``) until it terminates, truncates or reaches ``max_steps`` steps.

    With ``frames`` given (env in ``rgb_array`` mode), the initial frame and one frame
    after every step are appended to it. Where the env's reset and step infos hold
    ``x_position``, it is recorded per step (aligned with ``obs``).
    """
    opts = {k: np.asarray(v, dtype=np.float64) for k, v in options.items()} if options else None
    obs, info = env.reset(seed=int(seed), options=opts)
    # The x of the state obs describes: the reset's info, then each step's info.
    x_now = info.get("x_position")
    x_log: list[float] | None = [] if x_now is not None else None
    rng = np.random.default_rng(seed)  # exploration noise when not deterministic
    if frames is not None:
        frames.append(np.asarray(env.render()))
    obs_log: list[np.ndarray] = []
    act_log: list[np.ndarray] = []
    rew_log: list[float] = []
    success = False
    limit = np.inf if max_steps is None else int(max_steps)
    while len(act_log) < limit:
        action = policy.act(np.asarray(obs, dtype=np.float64)[None], deterministic, rng)[0]
        obs_log.append(np.asarray(obs, dtype=np.float64).copy())
        act_log.append(np.asarray(action, dtype=np.float64))
        if x_log is not None:
            x_log.append(float(np.asarray(x_now)))
        obs, reward, terminated, truncated, step_info = env.step(action)
        x_now = step_info.get("x_position")
        if x_now is None:  # an env reporting x only at reset: none rather than a partial log
            x_log = None
        rew_log.append(float(reward))
        success = bool(step_info.get("is_success", success))
        if frames is not None:
            frames.append(np.asarray(env.render()))
        if terminated or truncated:
            break
    if not act_log:
        raise PvedError("an episode needs at least one step (max_steps >= 1)")
    return EpisodeRecord(
        obs=np.stack(obs_log),
        act=np.stack(act_log),
        reward=np.asarray(rew_log),
        seed=int(seed),
        options=opts,
        reset_info={k: np.asarray(v) for k, v in info.items()},
        success=success,
        x_position=None if x_log is None else np.asarray(x_log, dtype=np.float64),
    )


def shared_task_options(
    reset_info: Mapping[str, Any], match_keys: Sequence[str]
) -> dict[str, np.ndarray] | None:
    """The source episode's task parameters ``match_keys`` as target reset options, so
    both agents solve the same task instance (as in pairing and the source bank)."""
    if not match_keys:
        return None
    missing = [k for k in match_keys if k not in reset_info]
    if missing:
        raise PvedError(f"source reset info has no task parameter(s) {', '.join(missing)}")
    return {k: np.asarray(reset_info[k], dtype=np.float64) for k in match_keys}


def run_paired_episodes(
    source_policy: Policy,
    target_policy: Policy,
    source_env_id: str,
    target_env_id: str,
    episodes: int,
    seed: int,
    *,
    match_keys: Sequence[str] = (),
    source_env_kwargs: Mapping[str, Any] | None = None,
    target_env_kwargs: Mapping[str, Any] | None = None,
    max_steps: int | None = None,
    deterministic: bool = True,
) -> tuple[list[EpisodeRecord], list[EpisodeRecord], np.ndarray, np.ndarray]:
    """Episode ``e`` of both agents uses seed ``seed + e``; the target is reset with the
    source's ``match_keys`` task parameters.

    Returns:
        source episodes, target episodes, and the robot-state indices of the source and
        target observations (from the envs).
    """
    if episodes < 1:
        raise PvedError(f"episodes must be >= 1, got {episodes}")
    env_s = make_env(source_env_id, source_env_kwargs)
    env_t = make_env(target_env_id, target_env_kwargs)
    try:
        _check_policy(source_policy, env_s, "source")
        _check_policy(target_policy, env_t, "target")
        src, tgt = [], []
        for e in range(episodes):
            s = seed + e
            ep_s = run_episode(
                env_s, source_policy, s, max_steps=max_steps, deterministic=deterministic
            )
            options = shared_task_options(ep_s.reset_info, match_keys)
            ep_t = run_episode(
                env_t, target_policy, s, options, max_steps=max_steps, deterministic=deterministic
            )
            src.append(ep_s)
            tgt.append(ep_t)
        idx_s = np.asarray(env_s.unwrapped.robot_state_indices, dtype=np.int64)
        idx_t = np.asarray(env_t.unwrapped.robot_state_indices, dtype=np.int64)
    finally:
        env_s.close()
        env_t.close()
    return src, tgt, idx_s, idx_t


def model_inputs(episode: EpisodeRecord, robot_state_indices: np.ndarray) -> torch.Tensor:
    """Raw model rows ``x = concat(robot_state, action)`` of every step (III.C, Eq. 7);
    the model standardises them itself."""
    x = np.concatenate([episode.obs[:, robot_state_indices], episode.act], axis=1)
    return torch.as_tensor(x, dtype=torch.float32)
