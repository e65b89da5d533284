"""A bank of the source agent's state-actions on the target task.

Eq. 10 needs, at every step of the target agent, a source state-action (s_S, a_S) to
compare with. The paper does not pair trajectories on the target task, so we roll out
the source's target-task policy on many task instances once, and at transfer time match
each target episode to the bank episode whose task parameters are nearest (e.g. the
button's start position) and each target step t to the bank episode's step taken at the
same moment as the pairs were aligned (:func:`bank_time_scale`). A bank's rollouts run as
long as the target's episode on that time base (:func:`bank_step_limit`); a target step
past the end of a source episode that ended earlier (the source fell) is compared with
nothing (:func:`source_covered`; docs/decisions/transfer.md, "A target step past the
source's end").
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pved import __version__
from pved.envs import make_batched
from pved.envs.base import BatchedEnv
from pved.errors import PvedError
from pved.pairing.collect import Episode, rollout_first_episodes
from pved.rl.policy import Actor
from pved.runs import atomic_write_bytes

FORMAT = "pved-source-bank/1"

#: Alignments that pair the two agents' steps by physical time when both control periods
#: are known (``phase`` re-pairs around the time partner; see ``pved.pairing.align``).
TIME_ALIGNMENTS = ("time", "phase")


def bank_time_scale(alignment: str, dt_source: float | None, dt_target: float | None) -> float:
    """Source steps per target step at transfer, as the pairs the model learned from.

    Pairs aligned by physical time (``time``, and ``phase`` around it) pair the target's
    step t, taken at t·dt_T seconds, with the source step taken at the same moment,
    t·dt_T/dt_S; so must the bank, or the model compares states it never saw paired
    (Humanoid acts every 0.015 s, Ant every 0.05 s: Ant step t is Humanoid step 3.33·t).
    Alignments by step index (``subsample``, ``dtw``) keep step t for step t: at transfer
    the target episode's length is not known in advance, so t itself is the nearest
    reading of a subsampling by length.
    """
    if alignment in TIME_ALIGNMENTS and dt_source is not None and dt_target is not None:
        if not (dt_source > 0 and dt_target > 0):
            raise PvedError(f"control periods must be positive, got {dt_source}, {dt_target}")
        return float(dt_target) / float(dt_source)
    return 1.0


def source_steps(t: np.ndarray, lengths: np.ndarray, time_scale: float = 1.0) -> np.ndarray:
    """Source step (N,) for target steps ``t`` (N,) in episodes of ``lengths`` (N,):
    round(t·time_scale), held at the episode's last step once it has ended (an index to
    read; :func:`source_covered` says whether the row is compared at all)."""
    step = np.rint(np.asarray(t, dtype=np.float64) * time_scale).astype(np.int64)
    return np.minimum(step, np.asarray(lengths, dtype=np.int64) - 1)


def source_covered(t: np.ndarray, lengths: np.ndarray, time_scale: float = 1.0) -> np.ndarray:
    """Whether target steps ``t`` (N,) meet a step of their source episodes of ``lengths``
    (N,), bool (N,): round(t·time_scale) is a step the source took. Past a source episode's
    end there is no source state-action of that moment; the last row held there (a fallen
    source's pose) is not one, so Eq. 10's term is 0 and a guide's row is left out
    (docs/decisions/transfer.md, "A target step past the source's end")."""
    step = np.rint(np.asarray(t, dtype=np.float64) * time_scale).astype(np.int64)
    return np.asarray(step < np.asarray(lengths, dtype=np.int64), dtype=bool)


def bank_step_limit(target_steps: int, time_scale: float) -> int:
    """Control steps a bank's source rollouts may run so that they reach as far as a target
    episode of ``target_steps`` steps does, read with ``time_scale`` source steps per target
    step (:func:`bank_time_scale`): ceil(target_steps·time_scale), and at least the source
    step the target's last step reads, plus one. On humanoid-ant, a 1000-step Ant episode
    (50 s) needs 3334 Humanoid steps (50 s at 0.015 s), not the Humanoid's own 1000 (15 s)."""
    if target_steps < 1 or not (math.isfinite(time_scale) and time_scale > 0):
        raise PvedError(
            f"a bank's step limit needs target steps >= 1 and a positive time scale, got "
            f"{target_steps} and {time_scale}"
        )
    last = int(np.rint((target_steps - 1) * time_scale)) + 1
    return max(math.ceil(target_steps * time_scale), last)


@dataclass
class SourceBank:
    """Source state-actions per episode, padded to a common length.

    Attributes:
        x: (E, T_max, D_S) robot state then action; rows past an episode's end repeat
            its last row (padding: no step compares with them, :func:`source_covered`).
        lengths: (E,) episode lengths.
        keys: (E, K) task parameters the episodes are matched on.
        header: JSON-able description (env id, policy, match keys, dims, seed, the
            source's control period ``dt`` where its env has one).
    """

    x: np.ndarray
    lengths: np.ndarray
    keys: np.ndarray
    header: dict[str, Any]

    @property
    def dim(self) -> int:
        return int(self.x.shape[2])

    def match(self, task_params: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """Index (N,) of the bank episode nearest to each row of ``task_params`` (N, K).

        A task without parameters (K = 0, e.g. the fixed Curve terrain) has no nearest
        episode: each target episode then gets a bank episode drawn uniformly with ``rng``,
        so the shaping sees the source's whole spread of behaviour, not one episode.
        """
        params = np.asarray(task_params, dtype=np.float64).reshape(len(task_params), -1)
        if params.shape[1] != self.keys.shape[1]:
            raise PvedError(
                f"task parameters have {params.shape[1]} entries, "
                f"the bank matches on {self.keys.shape[1]}"
            )
        if params.shape[1] == 0:
            if rng is None:
                raise PvedError("a bank without match keys needs an rng to draw episodes")
            return np.asarray(rng.integers(0, len(self.keys), size=len(params)), dtype=np.int64)
        dist = ((params[:, None, :] - self.keys[None, :, :]) ** 2).sum(-1)
        return np.asarray(dist.argmin(1), dtype=np.int64)

    @property
    def dt(self) -> float | None:
        """The source's control period in seconds (None: the env had none)."""
        dt = self.header.get("dt")
        return None if dt is None else float(dt)

    def lookup(self, episode: np.ndarray, t: np.ndarray, time_scale: float = 1.0) -> np.ndarray:
        """Source state-actions (N, D_S) of bank episodes ``episode`` (N,) at the source
        step matching target step ``t`` (N,): :func:`source_steps` with ``time_scale``
        source steps per target step (:func:`bank_time_scale`); past an episode's end its
        last row (:func:`source_covered` marks those)."""
        step = source_steps(t, self.lengths[episode], time_scale)
        return np.asarray(self.x[episode, step])


def env_dt(name: str) -> float | None:
    """The control period in seconds of env ``name`` (None for an env without one)."""
    env = make_batched(name, 1)
    try:
        dt = getattr(env, "dt", None)
    finally:
        env.close()
    return None if dt is None else float(dt)


def bank_dt(bank: SourceBank) -> float | None:
    """The source's control period: the bank header's, or for a bank written before the
    header kept it, that of the env named in its header (None when neither has one)."""
    if "dt" in bank.header:
        return bank.dt
    name = bank.header.get("env_id")
    return env_dt(str(name)) if name else None


def build_source_bank(
    env: BatchedEnv,
    policy: Actor,
    episodes: int,
    match_keys: tuple[str, ...],
    *,
    seed: int = 0,
    deterministic: bool = True,
    header: dict[str, Any] | None = None,
) -> SourceBank:
    """Roll out ``policy`` for ``episodes`` episodes and keep robot state + action."""
    eps = []
    for b in range(-(-episodes // env.num_envs)):
        eps.extend(
            rollout_first_episodes(env, policy, seed + b * env.num_envs, None, deterministic)
        )
    return bank_from_episodes(
        eps[:episodes],
        match_keys,
        env.robot_state_indices,
        header=header,
        seed=seed,
        dt=getattr(env, "dt", None),
    )


def bank_from_episodes(
    eps: Sequence[Episode],
    match_keys: tuple[str, ...],
    robot_state_indices: Sequence[int] | np.ndarray,
    *,
    header: dict[str, Any] | None = None,
    seed: int | None = None,
    dt: float | None = None,
) -> SourceBank:
    """The bank of episodes already rolled out or recorded (a Minari dataset's): each
    one's robot state (``robot_state_indices`` of its observations) and actions, matched on
    its reset info's ``match_keys``; ``seed`` is the rollouts' (None for recorded data) and
    ``dt`` the source's control period."""
    if not eps:
        raise PvedError("a source bank needs at least one episode")
    idx = np.asarray(robot_state_indices, dtype=np.int64)
    t_max = max(len(e.obs) for e in eps)
    dim = len(idx) + eps[0].act.shape[1]
    x = np.zeros((len(eps), t_max, dim), dtype=np.float32)
    for i, e in enumerate(eps):
        rows = np.concatenate([e.obs[:, idx], e.act], 1)
        x[i, : len(rows)] = rows
        x[i, len(rows) :] = rows[-1]
    keys = np.array(
        [[v for k in match_keys for v in np.ravel(e.reset_info[k])] for e in eps],
        dtype=np.float64,
    ).reshape(len(eps), -1)
    full_header = {
        **(header or {}),
        "match_keys": list(match_keys),
        "episodes": len(eps),
        "seed": seed,
        "success_rate": float(np.mean([e.success for e in eps])),
        "robot_state_indices": [int(i) for i in idx],
        # the source's control period, which the lookup's time base needs
        "dt": dt,
    }
    return SourceBank(x, np.array([len(e.obs) for e in eps], dtype=np.int64), keys, full_header)


def save_bank(path: Path | str, bank: SourceBank) -> Path:
    """Atomically write the bank as ``.npz`` with a JSON header."""
    header = {"format": FORMAT, "pved_version": __version__, **bank.header}
    buffer = io.BytesIO()
    np.savez_compressed(
        buffer, x=bank.x, lengths=bank.lengths, keys=bank.keys, header=np.array(json.dumps(header))
    )
    path = Path(path)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def load_bank(path: Path | str) -> SourceBank:
    """Read a source bank; a missing, corrupt or foreign file raises :class:`PvedError`."""
    path = Path(path)
    if not path.exists():
        raise PvedError(f"source bank not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header"]))
            bank = SourceBank(data["x"], data["lengths"], data["keys"], header)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError, json.JSONDecodeError):
        raise PvedError(f"cannot read source bank {path}: corrupt or foreign file") from None
    if header.get("format") != FORMAT:
        raise PvedError(f"{path} is not a pved source bank")
    return bank
