"""Recorded source episodes as Minari datasets (Farama's format for offline data).

A source agent need not come with a policy: its recorded episodes can fill the source
bank (Eq. 10's s_S, a_S) and the source side of the pairs, where the target env can be
reset to each episode's task parameters. This module reads such a dataset into pved's
:class:`~pved.pairing.collect.Episode` and writes pved's own rollouts as one, so a user
can check the route on data they made.

How Minari's fields map (docs/decisions/sources.md):

- ``observations`` (T+1, obs_dim): the first T are the states the T ``actions`` were taken
  in (``Episode.obs``); the last is the one the last action led to (``final_obs``).
- task parameters: the episode's reset ``options`` (episode metadata, what a pved env is
  reset with), else the first row of its ``infos`` (the reset info, as a Gymnasium env
  reports its task, e.g. a goal).
- ``infos["is_success"]`` at the last step, where present, is the episode's success.

Minari is an optional extra (``pip install pved[minari]``) imported only here, when a
dataset is read or written. Datasets given by id live under ``MINARI_DATASETS_PATH``
(default ``~/.minari/datasets``); nothing is downloaded.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from pved import __version__
from pved.envs.base import BatchedEnv
from pved.errors import PvedError
from pved.pairing.collect import Episode

MINARI_HINT = "pip install pved[minari]"
_METADATA = "metadata.json"


def _minari() -> Any:
    try:
        import minari
    except ImportError:
        raise PvedError(f"reading or writing Minari datasets needs minari: {MINARI_HINT}") from None
    return minari


def datasets_root() -> Path:
    """Where Minari keeps datasets by id: ``MINARI_DATASETS_PATH`` or ``~/.minari/datasets``
    (Minari's own rule, computed here so that looking does not create the folder)."""
    root = os.environ.get("MINARI_DATASETS_PATH")
    return Path(root) if root else Path.home() / ".minari" / "datasets"


@dataclass(frozen=True)
class RecordedData:
    """A Minari dataset opened for its metadata (no episode read yet).

    Attributes:
        ref: the id or path it was given as.
        dataset_id: the id its metadata records.
        data_path: its ``data`` folder.
        env_id: the Gymnasium id of the env it was recorded on (None: not recorded).
        obs_dim, act_dim: its flat observation and action sizes.
        episodes: how many episodes it holds.
        provenance: plain data for a bank's or paired dataset's header: id, Minari
            version, algorithm, author, description, env id, content digest, and what
            pved recorded of its making when pved wrote it.
    """

    ref: str
    dataset_id: str
    data_path: Path
    env_id: str | None
    obs_dim: int
    act_dim: int
    episodes: int
    provenance: dict[str, Any]


def _data_path(ref: str) -> Path:
    path = Path(ref)
    if path.is_dir():
        for candidate in (path / "data", path):
            if (candidate / _METADATA).is_file():
                return candidate
        raise PvedError(f"{ref} is a folder but not a Minari dataset (no data/{_METADATA})")
    by_id = datasets_root() / ref / "data"
    if not (by_id / _METADATA).is_file():
        raise PvedError(
            f"Minari dataset {ref!r} not found: neither a dataset folder nor an id under "
            f"{datasets_root()} (MINARI_DATASETS_PATH)"
        )
    return by_id


def dataset_digest(data_path: Path) -> str:
    """Short content hash of a dataset's files (names and bytes), so a changed dataset
    invalidates the stages made from it."""
    digest = hashlib.sha256(b"minari-dataset")
    for file in sorted(p for p in data_path.rglob("*") if p.is_file()):
        name = file.relative_to(data_path).as_posix().encode()
        data = file.read_bytes()
        digest.update(len(name).to_bytes(8, "little") + name)
        digest.update(len(data).to_bytes(8, "little") + data)
    return digest.hexdigest()[:16]


def open_recorded(ref: str | Path) -> RecordedData:
    """Open the Minari dataset ``ref`` (an id under :func:`datasets_root` or a dataset
    folder) and read its metadata; every failure is a one-line :class:`PvedError`."""
    ref = str(ref)
    data_path = _data_path(ref)
    minari = _minari()
    try:
        dataset = minari.MinariDataset(data_path)
    except Exception as exc:  # Minari raises many types for a bad folder
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PvedError(f"cannot read Minari dataset {ref}: {first[:160]}") from None
    obs_space, act_space = dataset.observation_space, dataset.action_space
    for what, space in (("observations", obs_space), ("actions", act_space)):
        if not isinstance(space, gym.spaces.Box) or len(space.shape) != 1:
            raise PvedError(f"Minari dataset {ref} has {what} in {space}; pved reads flat Box ones")
    meta = dataset.storage.metadata
    env_id = dataset.env_spec.id if dataset.env_spec is not None else None
    provenance: dict[str, Any] = {
        "dataset_id": dataset.id,
        "minari_version": dataset.minari_version,
        "env_id": env_id,
        "episodes": int(dataset.total_episodes),
        "digest": dataset_digest(data_path),
    }
    for key in ("algorithm_name", "description", "code_permalink", "pved"):
        if key in meta:
            provenance[key] = meta[key]
    if "author" in meta:
        provenance["author"] = sorted(str(a) for a in meta["author"])
    return RecordedData(
        ref=ref,
        dataset_id=str(dataset.id),
        data_path=data_path,
        env_id=env_id,
        obs_dim=int(obs_space.shape[0]),
        act_dim=int(act_space.shape[0]),
        episodes=int(dataset.total_episodes),
        provenance=provenance,
    )


def check_recorded_for(data: RecordedData, env_name: str, env: BatchedEnv) -> None:
    """Refuse, in one line, a dataset recorded for another agent: its env id (where it
    records one) and its observation and action sizes against ``env``'s."""
    if data.env_id is not None and data.env_id != env_name:
        raise PvedError(
            f"Minari dataset {data.ref} was recorded on {data.env_id}, the source's env is "
            f"{env_name}"
        )
    obs_dim = int(env.single_observation_space.shape[0])
    act_dim = int(env.single_action_space.shape[0])
    if data.obs_dim != obs_dim:
        raise PvedError(
            f"Minari dataset {data.ref} has observations of {data.obs_dim} dims, {env_name} "
            f"of {obs_dim}"
        )
    if data.act_dim != act_dim:
        raise PvedError(
            f"Minari dataset {data.ref} has actions of {data.act_dim} dims, {env_name} of {act_dim}"
        )


def _task_value(key: str, options: dict[str, Any], infos: dict[str, Any] | None) -> Any:
    if key in options:
        return np.asarray(options[key], dtype=np.float64)
    if infos is not None and key in infos and len(infos[key]) > 0:
        return np.asarray(infos[key][0], dtype=np.float64)
    return None


def read_recorded_episodes(
    data: RecordedData, task_keys: tuple[str, ...], limit: int | None = None
) -> list[Episode]:
    """The first ``limit`` (default all) episodes of ``data`` as pved episodes, with the
    task parameters ``task_keys`` in their ``reset_info``; an episode lacking one, or
    whose arrays disagree in length, raises :class:`PvedError`."""
    minari = _minari()
    dataset = minari.MinariDataset(data.data_path)
    count = data.episodes if limit is None else min(limit, data.episodes)
    indices = list(range(count))
    metas = list(dataset.storage.get_episode_metadata(indices))
    episodes: list[Episode] = []
    for index, ep, meta in zip(indices, dataset.iterate_episodes(indices), metas, strict=True):
        obs = np.asarray(ep.observations, dtype=np.float64)
        act = np.asarray(ep.actions, dtype=np.float64)
        if obs.ndim != 2 or act.ndim != 2 or len(obs) != len(act) + 1 or len(act) == 0:
            raise PvedError(
                f"Minari dataset {data.ref}, episode {index}: {len(obs)} observations for "
                f"{len(act)} actions (expected one more observation than actions)"
            )
        options = dict(meta.get("options") or {})
        infos = ep.infos if isinstance(ep.infos, dict) else None
        reset_info: dict[str, Any] = {}
        for key in task_keys:
            value = _task_value(key, options, infos)
            if value is None:
                raise PvedError(
                    f"Minari dataset {data.ref}, episode {index}: no task parameter {key!r} "
                    "in its reset options or first info"
                )
            reset_info[key] = value
        success = bool(infos["is_success"][-1]) if infos and "is_success" in infos else False
        episodes.append(
            Episode(
                obs[:-1],
                act,
                reset_info,
                success,
                reward=np.asarray(ep.rewards, dtype=np.float64),
                final_obs=obs[-1],
                terminated=bool(np.asarray(ep.terminations)[-1]),
            )
        )
    return episodes


def check_new_dataset_id(dataset_id: str) -> tuple[str | None, Path]:
    """(namespace, folder) of a dataset about to be written as ``dataset_id``; a
    malformed id or one already taken raises :class:`PvedError` in one line."""
    _minari()
    from minari.dataset.minari_dataset import parse_dataset_id

    try:
        namespace = parse_dataset_id(dataset_id)[0]
    except ValueError as exc:
        raise PvedError(str(exc).splitlines()[0]) from None
    final = datasets_root() / dataset_id
    if final.exists():
        raise PvedError(f"Minari dataset {dataset_id} already exists at {final}")
    return namespace, final


def export_episodes(
    dataset_id: str,
    episodes: list[Episode],
    *,
    env_name: str,
    task_keys: tuple[str, ...],
    seeds: list[int] | None = None,
    algorithm_name: str = "pved rollouts",
    description: str | None = None,
    provenance: dict[str, Any] | None = None,
) -> Path:
    """Write ``episodes`` (rolled out with pved, e.g. by ``rollout_first_episodes``) as
    the Minari dataset ``dataset_id`` under :func:`datasets_root`; returns its folder.

    Each episode's ``task_keys`` are its reset ``options`` (and are repeated in its
    ``infos``, as pved's envs report them every step); ``seeds`` are the reset seeds.
    The dataset is written beside its final place and moved there whole, so a failure
    leaves nothing behind; an existing dataset of that id is refused, before any work.
    """
    minari = _minari()
    from minari.data_collector import EpisodeBuffer
    from minari.dataset.minari_storage import MinariStorage
    from minari.namespace import NAMESPACE_METADATA_FILENAME, create_namespace

    namespace, final = check_new_dataset_id(dataset_id)
    if not episodes:
        raise PvedError("no episodes to export")
    missing = [k for k in task_keys if k not in episodes[0].reset_info]
    if missing or any(e.final_obs is None or e.reward is None for e in episodes):
        raise PvedError(f"episodes lack {missing or 'final observations or rewards'}")
    spec = gym.spec(env_name)
    env = gym.make(spec)
    try:
        obs_space, act_space = env.observation_space, env.action_space
    finally:
        env.close()
    buffers = []
    for i, e in enumerate(episodes):
        steps = len(e.act)
        task = {k: np.asarray(e.reset_info[k], dtype=np.float64) for k in task_keys}
        success = np.zeros(steps + 1, dtype=bool)
        success[-1] = e.success
        last = np.zeros(steps, dtype=bool)
        last[-1] = True
        assert e.final_obs is not None and e.reward is not None
        buffers.append(
            EpisodeBuffer(
                id=i,
                seed=None if seeds is None else int(seeds[i]),
                options=task,
                observations=np.concatenate([e.obs, e.final_obs[None]], 0),
                actions=np.asarray(e.act, dtype=np.float64),
                rewards=np.asarray(e.reward, dtype=np.float64),
                terminations=last & bool(e.terminated),
                truncations=last & (not e.terminated),
                infos={
                    **{k: np.repeat(v[None], steps + 1, 0) for k, v in task.items()},
                    "is_success": success,
                },
            )
        )
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.parent / f".{final.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        storage = MinariStorage.new(
            tmp / "data", observation_space=obs_space, action_space=act_space, env_spec=spec
        )
        meta: dict[str, Any] = {
            "dataset_id": dataset_id,
            "minari_version": minari.__version__,
            "algorithm_name": algorithm_name,
            "author": {f"pved {__version__}"},
            "pved": dict(provenance or {}),
        }
        if description is not None:
            meta["description"] = description
        storage.update_metadata(meta)
        storage.update_episodes(buffers)
        if (
            namespace is not None
            and not (datasets_root() / namespace / NAMESPACE_METADATA_FILENAME).exists()
        ):
            create_namespace(namespace)
        tmp.rename(final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final
