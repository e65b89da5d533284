"""Vectorised policy evaluation over a :class:`BatchedEnv`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pved.envs.base import BatchedEnv
from pved.errors import PvedError
from pved.rl.policy import Actor


def evaluate_policy(
    policy: Actor,
    env: BatchedEnv,
    episodes: int,
    seed: int,
    deterministic: bool = True,
    info_keys: Sequence[str] = (),
    max_steps: int | None = None,
) -> dict[str, float]:
    """Run exactly ``episodes`` complete episodes of ``policy`` on the copies of ``env``.

    Copy ``i`` of N is given a quota of ``episodes // N`` episodes (one more for the first
    ``episodes % N`` copies) and only its first quota of episodes counts. Fixing the quotas
    in advance keeps the estimate unbiased: simply taking the first ``episodes`` episodes
    to finish anywhere would over-sample short ones. Every env step is one policy forward
    over the whole batch.

    ``info`` values of a finished episode are read at its last step (``info`` of the step
    that ended it, the BatchedEnv autoreset convention).

    Args:
        policy: the policy to run.
        env: the batched env (reset here with ``seed``; copy i gets ``seed + i``).
        episodes: number of complete episodes to average over.
        seed: env reset seed; also seeds the action noise when not deterministic.
        deterministic: use the mean action.
        info_keys: ``info`` entries to average at episode end (e.g. ``"x_position"``),
            reported as ``<key>_mean``.
        max_steps: safety limit on batched steps (default: 10 × episodes-per-copy ×
            ``env.max_episode_steps``).

    Returns:
        ``return_mean``, ``return_std``, ``length_mean``, ``completion_rate`` (the
        fraction of episodes that ran to the time limit without terminating: for the
        locomotion agents, without falling), ``episodes``, ``success_rate``
        (when the env reports ``is_success``) and ``<key>_mean`` for each info key.
    """
    if episodes <= 0:
        raise PvedError(f"evaluate_policy needs episodes > 0, got {episodes}")
    n = env.num_envs
    quota = np.full(n, episodes // n, dtype=np.int64)
    quota[: episodes % n] += 1
    done_count = np.zeros(n, dtype=np.int64)
    ep_ret = np.zeros(n, dtype=np.float64)
    ep_len = np.zeros(n, dtype=np.int64)
    returns: list[float] = []
    lengths: list[int] = []
    completed: list[bool] = []
    successes: list[float] = []
    extras: dict[str, list[float]] = {k: [] for k in info_keys}
    rng = np.random.default_rng(seed)
    limit = (
        max_steps if max_steps is not None else 10 * int(quota.max()) * int(env.max_episode_steps)
    )

    obs, _ = env.reset(seed=seed)
    steps = 0
    while np.any(done_count < quota):
        if steps >= limit:
            raise PvedError(
                f"evaluate_policy: {int((quota - done_count).clip(0).sum())} episodes unfinished "
                f"after {steps} steps"
            )
        actions = policy.act(obs, deterministic=deterministic, rng=rng)
        obs, reward, terminated, truncated, info = env.step(actions)
        steps += 1
        ep_ret += np.asarray(reward, dtype=np.float64)
        ep_len += 1
        done = np.asarray(terminated, dtype=bool) | np.asarray(truncated, dtype=bool)
        counted = done & (done_count < quota)
        if counted.any():
            idx = np.flatnonzero(counted)
            returns.extend(ep_ret[idx].tolist())
            lengths.extend(ep_len[idx].tolist())
            completed.extend((~np.asarray(terminated, dtype=bool))[idx].tolist())
            if "is_success" in info:
                successes.extend(np.asarray(info["is_success"], dtype=np.float64)[idx].tolist())
            for key in info_keys:
                if key not in info:
                    raise PvedError(f"evaluate_policy: the env's info has no {key!r}")
                extras[key].extend(np.asarray(info[key], dtype=np.float64)[idx].tolist())
        done_count += done
        ep_ret[done] = 0.0
        ep_len[done] = 0

    result = {
        "return_mean": float(np.mean(returns)),
        "return_std": float(np.std(returns)),
        "length_mean": float(np.mean(lengths)),
        "completion_rate": float(np.mean(completed)),
        "episodes": float(len(returns)),
    }
    if successes:
        result["success_rate"] = float(np.mean(successes))
    for key, values in extras.items():
        result[f"{key}_mean"] = float(np.mean(values))
    return result
