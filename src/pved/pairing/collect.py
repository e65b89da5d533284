"""Paired rollouts on the training task (paper IV.A, "Training of PVED").

Both agents' training-task policies run side by side with the same root, the same
random task parameters per episode (the reach target; later the slope angle) and
similar random initial states; each episode pair is then time-aligned (``align.py``)
and written as one paired dataset (``dataset.py``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from pved.envs.base import BatchedEnv
from pved.errors import PvedError
from pved.pairing.align import align
from pved.pairing.dataset import PairedDataset
from pved.rl.policy import Actor


@dataclass
class Episode:
    """One finished episode: ``obs[t]`` is the observation the action ``act[t]`` was taken in."""

    obs: np.ndarray  # (T, obs_dim)
    act: np.ndarray  # (T, act_dim)
    reset_info: dict[str, Any]  # this copy's reset info (task parameters)
    success: bool
    # what a recorded-data format (Minari) keeps besides: the rewards (T,), the
    # observation the last action led to (obs_dim,), and whether the episode
    # terminated rather than being truncated; None where not recorded
    reward: np.ndarray | None = None
    final_obs: np.ndarray | None = None
    terminated: bool | None = None


def rollout_first_episodes(
    env: BatchedEnv,
    policy: Actor,
    seed: int,
    options: Mapping[str, Any] | None = None,
    deterministic: bool = True,
) -> list[Episode]:
    """Run one episode in each of the ``env.num_envs`` copies and return them.

    Copies that finish early keep stepping (the batch moves together) but their
    later, autoreset episodes are discarded, so every returned episode starts from the
    reset made here with ``seed`` and ``options``.
    """
    n = env.num_envs
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed, options=dict(options) if options else None)
    reset_info = [{k: np.asarray(v[i]) for k, v in info.items()} for i in range(n)]
    obs_log: list[np.ndarray] = []
    act_log: list[np.ndarray] = []
    rew_log: list[np.ndarray] = []
    length = np.full(n, -1, dtype=np.int64)
    success = np.zeros(n, dtype=bool)
    ended_by_termination = np.zeros(n, dtype=bool)
    final_obs = np.zeros_like(obs)
    for t in range(env.max_episode_steps + 1):
        if np.all(length >= 0):
            break
        action = policy.act(obs, deterministic=deterministic, rng=rng)
        obs_log.append(obs.copy())
        act_log.append(np.asarray(action, dtype=np.float64).copy())
        obs, reward, terminated, truncated, info = env.step(action)
        rew_log.append(np.asarray(reward, dtype=np.float64).copy())
        done = (terminated | truncated) & (length < 0)
        if "is_success" in info:
            success[done] = np.asarray(info["is_success"], dtype=bool)[done]
        ended_by_termination[done] = np.asarray(terminated, dtype=bool)[done]
        # the autoreset put the next episode's first observation in ``obs``
        final_obs[done] = np.asarray(info.get("final_obs", obs))[done]
        length[done] = t + 1
    if np.any(length < 0):
        raise PvedError(f"episodes did not end within max_episode_steps={env.max_episode_steps}")
    obs_arr = np.stack(obs_log, 1)  # (N, T, obs_dim)
    act_arr = np.stack(act_log, 1)
    rew_arr = np.stack(rew_log, 1)
    return [
        Episode(
            obs_arr[i, : length[i]],
            act_arr[i, : length[i]],
            reset_info[i],
            bool(success[i]),
            reward=rew_arr[i, : length[i]],
            final_obs=final_obs[i].copy(),
            terminated=bool(ended_by_termination[i]),
        )
        for i in range(n)
    ]


EpisodePair = tuple[Episode, Episode]


def collect_episode_pairs(
    source_env: BatchedEnv,
    target_env: BatchedEnv,
    source_policy: Actor,
    target_policy: Actor,
    episodes: int,
    *,
    shared_task_keys: tuple[str, ...],
    deterministic: bool = True,
    seed: int = 0,
    progress: bool = True,
) -> list[EpisodePair]:
    """Run ``episodes`` paired episodes and return them unaligned, source first.

    Per batch, the source env draws the task parameters named in ``shared_task_keys``
    (e.g. ``("target",)``) and the target env is reset with exactly those, so both agents
    solve the same task instance. Initial joint states are each env's own small random
    perturbation (the "similar random initial states" of the paper).
    """
    if source_env.num_envs != target_env.num_envs:
        raise PvedError("source and target envs must have the same number of copies")
    for name, env, pol in (
        ("source", source_env, source_policy),
        ("target", target_env, target_policy),
    ):
        if (
            pol.obs_dim != env.single_observation_space.shape[0]
            or pol.act_dim != env.single_action_space.shape[0]
        ):
            raise PvedError(
                f"{name} policy dims (obs {pol.obs_dim}, act {pol.act_dim}) do not match its env "
                f"(obs {env.single_observation_space.shape[0]}, "
                f"act {env.single_action_space.shape[0]})"
            )
    n = source_env.num_envs
    pairs: list[EpisodePair] = []
    bar = tqdm(total=episodes, desc="collect pairs", unit="ep", disable=not progress)
    for b in range(-(-episodes // n)):
        batch_seed = seed + b * n
        src = rollout_first_episodes(source_env, source_policy, batch_seed, None, deterministic)
        shared = {k: np.stack([e.reset_info[k] for e in src]) for k in shared_task_keys}
        tgt = rollout_first_episodes(target_env, target_policy, batch_seed, shared, deterministic)
        for e_s, e_t in zip(src, tgt, strict=True):
            for k in shared_task_keys:
                if not np.allclose(e_s.reset_info[k], e_t.reset_info[k]):
                    raise PvedError(f"target env did not accept the shared task parameter {k!r}")
        # keep exactly ``episodes`` pairs (the last batch may overshoot)
        pairs.extend(list(zip(src, tgt, strict=True))[: episodes - len(pairs)])
        bar.update(min(n, episodes - bar.n))
    bar.close()
    return pairs


def pair_recorded_episodes(
    source_episodes: list[Episode],
    target_env: BatchedEnv,
    target_policy: Actor,
    *,
    shared_task_keys: tuple[str, ...],
    deterministic: bool = True,
    seed: int = 0,
    progress: bool = True,
) -> list[EpisodePair]:
    """Pair recorded source episodes (a Minari dataset's) with target rollouts, source first.

    As :func:`collect_episode_pairs`, with the source's side read instead of rolled out:
    the target env is reset with each recorded episode's task parameters
    ``shared_task_keys`` and the target's policy run from there. Batch ``b`` of
    ``target_env.num_envs`` episodes is reset with seed ``seed + b·num_envs``, the seeds
    :func:`collect_episode_pairs` gives the target for the same episodes, so recorded
    rollouts of the source pair as its live ones do.
    """
    n = target_env.num_envs
    pairs: list[EpisodePair] = []
    bar = tqdm(total=len(source_episodes), desc="pair recorded", unit="ep", disable=not progress)
    for b in range(-(-len(source_episodes) // n)):
        src = source_episodes[b * n : (b + 1) * n]
        # a short last batch: the spare copies replay its last episode's task, then are dropped
        padded = src + [src[-1]] * (n - len(src))
        shared = {
            k: np.stack([np.asarray(e.reset_info[k]) for e in padded]) for k in shared_task_keys
        }
        tgt = rollout_first_episodes(target_env, target_policy, seed + b * n, shared, deterministic)
        for e_s, e_t in zip(src, tgt, strict=False):
            for k in shared_task_keys:
                if not np.allclose(e_s.reset_info[k], e_t.reset_info[k]):
                    raise PvedError(f"target env did not accept the shared task parameter {k!r}")
        pairs.extend(zip(src, tgt[: len(src)], strict=True))
        bar.update(len(src))
    bar.close()
    return pairs


def pairs_to_dataset(
    pairs: list[EpisodePair],
    alignment: list[tuple[np.ndarray, np.ndarray]],
    *,
    shared_task_keys: tuple[str, ...],
    header: Mapping[str, Any],
) -> PairedDataset:
    """Aligned rows of ``pairs``: episode e contributes rows ``(obs_S[i_s], obs_T[i_t])``
    for its ``alignment[e] = (i_s, i_t)`` (equal-length index arrays).

    ``header`` must already hold the agents' robot-state indices and dims; the episode
    statistics (success rates, mean lengths) are added here.
    """
    if len(alignment) != len(pairs):
        raise PvedError(f"{len(alignment)} alignments for {len(pairs)} episode pairs")
    rows: dict[str, list[np.ndarray]] = {k: [] for k in ("os", "as", "ot", "at", "ep", "ts", "tt")}
    for index, ((e_s, e_t), (i_s, i_t)) in enumerate(zip(pairs, alignment, strict=True)):
        i_s, i_t = np.asarray(i_s, dtype=np.int64), np.asarray(i_t, dtype=np.int64)
        if i_s.shape != i_t.shape or i_s.ndim != 1:
            raise PvedError(f"episode {index}: alignment index arrays differ in shape")
        rows["os"].append(e_s.obs[i_s])
        rows["as"].append(e_s.act[i_s])
        rows["ot"].append(e_t.obs[i_t])
        rows["at"].append(e_t.act[i_t])
        rows["ep"].append(np.full(len(i_s), index, dtype=np.int64))
        rows["ts"].append(i_s)
        rows["tt"].append(i_t)
    cat = {k: np.concatenate(v) for k, v in rows.items()}
    success = np.array([(e_s.success, e_t.success) for e_s, e_t in pairs], dtype=bool)
    length = np.array([(len(e_s.obs), len(e_t.obs)) for e_s, e_t in pairs], dtype=np.int64)
    full_header = {
        **dict(header),
        "episodes": len(pairs),
        "shared_task_keys": list(shared_task_keys),
        "success_rate_source": float(success[:, 0].mean()),
        "success_rate_target": float(success[:, 1].mean()),
        "mean_length_source": float(length[:, 0].mean()),
        "mean_length_target": float(length[:, 1].mean()),
    }
    return PairedDataset(
        obs_source=cat["os"],
        act_source=cat["as"],
        obs_target=cat["ot"],
        act_target=cat["at"],
        episode=cat["ep"],
        t_source=cat["ts"],
        t_target=cat["tt"],
        task={k: np.stack([e_s.reset_info[k] for e_s, _ in pairs]) for k in shared_task_keys},
        header=full_header,
    )


def env_header(source_env: BatchedEnv, target_env: BatchedEnv) -> dict[str, Any]:
    """What a paired dataset records of the two envs: dims and robot-state indices."""
    return {
        "robot_state_indices_source": [int(i) for i in source_env.robot_state_indices],
        "robot_state_indices_target": [int(i) for i in target_env.robot_state_indices],
        "obs_dim_source": int(source_env.single_observation_space.shape[0]),
        "act_dim_source": int(source_env.single_action_space.shape[0]),
        "obs_dim_target": int(target_env.single_observation_space.shape[0]),
        "act_dim_target": int(target_env.single_action_space.shape[0]),
    }


def collect_pairs(
    source_env: BatchedEnv,
    target_env: BatchedEnv,
    source_policy: Actor,
    target_policy: Actor,
    episodes: int,
    *,
    shared_task_keys: tuple[str, ...],
    align_method: str = "subsample",
    deterministic: bool = True,
    seed: int = 0,
    header: Mapping[str, Any] | None = None,
    progress: bool = True,
) -> PairedDataset:
    """Collect ``episodes`` paired episodes and align them by time alone
    (:func:`pved.pairing.align.align`) into a :class:`PairedDataset`.

    Alignments fitted to the episodes (DTW on shared means, gait phase) start from this
    one (``rounds.py``); the stage ``pved.experiments.stages.collect_pairs`` runs them.
    """
    pairs = collect_episode_pairs(
        source_env,
        target_env,
        source_policy,
        target_policy,
        episodes,
        shared_task_keys=shared_task_keys,
        deterministic=deterministic,
        seed=seed,
        progress=progress,
    )
    alignment = [align(align_method, len(e_s.obs), len(e_t.obs)) for e_s, e_t in pairs]
    full_header = {
        **(dict(header) if header else {}),
        **env_header(source_env, target_env),
        "alignment": align_method,
        "deterministic_actions": deterministic,
        "seed": seed,
    }
    return pairs_to_dataset(pairs, alignment, shared_task_keys=shared_task_keys, header=full_header)
