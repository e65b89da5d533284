"""The paired dataset file: one ``.npz`` per collection (DESIGN.md "Contracts").

Arrays (aligned rows; row k of the source arrays is paired with row k of the target's):

- ``obs_source`` (M, obs_dim_S), ``act_source`` (M, act_dim_S)
- ``obs_target`` (M, obs_dim_T), ``act_target`` (M, act_dim_T)
- ``episode`` (M,), ``t_source`` (M,), ``t_target`` (M,): where each row came from
- ``task_<name>`` (E, ...): the task parameters of each of the E episodes
- ``header``: a JSON string: format tag, pair, agents, env ids, dims, the robot-state
  indices of each agent's observation (what the model sees), policies used, alignment
  method, seed, package version.

The model input of an agent is its robot state (the header's indices into the
observation) concatenated with its action: ``x = [obs[:, idx], act]``.
"""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pved import __version__
from pved.errors import PvedError
from pved.runs import atomic_write_bytes

FORMAT = "pved-paired-dataset/1"
_ARRAYS = (
    "obs_source",
    "act_source",
    "obs_target",
    "act_target",
    "episode",
    "t_source",
    "t_target",
)


@dataclass
class PairedDataset:
    """Aligned state-action pairs of a source and a target agent."""

    obs_source: np.ndarray
    act_source: np.ndarray
    obs_target: np.ndarray
    act_target: np.ndarray
    episode: np.ndarray
    t_source: np.ndarray
    t_target: np.ndarray
    task: dict[str, np.ndarray]
    header: dict[str, Any]

    def __len__(self) -> int:
        return int(self.obs_source.shape[0])

    @property
    def robot_indices_source(self) -> np.ndarray:
        return np.asarray(self.header["robot_state_indices_source"], dtype=np.int64)

    @property
    def robot_indices_target(self) -> np.ndarray:
        return np.asarray(self.header["robot_state_indices_target"], dtype=np.int64)

    def model_inputs(self) -> tuple[np.ndarray, np.ndarray]:
        """``x_S`` (M, D_S) and ``x_T`` (M, D_T): robot state then action, per agent."""
        x_s = np.concatenate([self.obs_source[:, self.robot_indices_source], self.act_source], 1)
        x_t = np.concatenate([self.obs_target[:, self.robot_indices_target], self.act_target], 1)
        return x_s.astype(np.float32), x_t.astype(np.float32)

    @property
    def state_dims(self) -> tuple[int, int]:
        """Number of state entries at the front of ``x_S`` and ``x_T``."""
        return len(self.robot_indices_source), len(self.robot_indices_target)

    def check_agents(self, source_agent: str, target_agent: str) -> None:
        """Raise :class:`PvedError` when the dataset was collected for other agents."""
        got = (self.header.get("source_agent"), self.header.get("target_agent"))
        if got != (source_agent, target_agent):
            raise PvedError(
                f"dataset is for {got[0]}->{got[1]}, not {source_agent}->{target_agent}"
            )

    def check_dims(self, obs_dim_s: int, act_dim_s: int, obs_dim_t: int, act_dim_t: int) -> None:
        """Raise :class:`PvedError` when the arrays do not match the agents' dimensions."""
        want = {
            "obs_source": obs_dim_s,
            "act_source": act_dim_s,
            "obs_target": obs_dim_t,
            "act_target": act_dim_t,
        }
        for name, dim in want.items():
            got = getattr(self, name).shape[1]
            if got != dim:
                raise PvedError(f"dataset {name} has dim {got}, but the agent's is {dim}")


def save_dataset(path: Path | str, dataset: PairedDataset) -> Path:
    """Validate and atomically write ``dataset`` as ``.npz`` with its JSON header."""
    _validate(dataset, Path(path))
    header = {"format": FORMAT, "pved_version": __version__, **dataset.header}
    arrays: dict[str, np.ndarray] = {name: getattr(dataset, name) for name in _ARRAYS}
    arrays.update({f"task_{k}": v for k, v in dataset.task.items()})
    arrays["header"] = np.array(json.dumps(header))
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)  # type: ignore[arg-type]
    path = Path(path)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def load_dataset(path: Path | str) -> PairedDataset:
    """Read a paired dataset; a missing, corrupt or foreign file raises :class:`PvedError`."""
    path = Path(path)
    if not path.exists():
        raise PvedError(f"dataset not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as data:
            files = set(data.files)
            if "header" not in files:
                raise PvedError(f"{path} is not a pved paired dataset (no header)")
            header = json.loads(str(data["header"]))
            arrays = {name: data[name] for name in _ARRAYS if name in files}
            task = {k[5:]: data[k] for k in files if k.startswith("task_")}
    except PvedError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, json.JSONDecodeError) as exc:
        raise PvedError(
            f"cannot read dataset {path}: corrupt file ({type(exc).__name__})"
        ) from None
    if header.get("format") != FORMAT:
        raise PvedError(f"{path} is not a pved paired dataset (format {header.get('format')!r})")
    missing = [name for name in _ARRAYS if name not in arrays]
    if missing:
        raise PvedError(f"dataset {path} lacks arrays: {', '.join(missing)}")
    dataset = PairedDataset(**arrays, task=task, header=header)
    _validate(dataset, path)
    return dataset


def _validate(dataset: PairedDataset, path: Path) -> None:
    rows = {name: getattr(dataset, name).shape[0] for name in _ARRAYS}
    if len(set(rows.values())) != 1:
        raise PvedError(f"dataset {path}: arrays have different row counts {rows}")
    for name in ("obs_source", "act_source", "obs_target", "act_target"):
        array = getattr(dataset, name)
        if array.ndim != 2:
            raise PvedError(f"dataset {path}: {name} must be 2-D, got shape {array.shape}")
        if not np.all(np.isfinite(array)):
            raise PvedError(f"dataset {path}: {name} contains NaN or inf")
    header = dataset.header
    for key in ("robot_state_indices_source", "robot_state_indices_target"):
        if key not in header:
            raise PvedError(f"dataset {path}: header lacks {key}")
    for key, obs in (
        ("robot_state_indices_source", dataset.obs_source),
        ("robot_state_indices_target", dataset.obs_target),
    ):
        idx = np.asarray(header[key])
        if idx.size and (idx.min() < 0 or idx.max() >= obs.shape[1]):
            raise PvedError(f"dataset {path}: {key} out of range for obs dim {obs.shape[1]}")
