"""Run directories: the file contract every stage writes (DESIGN.md "Contracts").

``runs/<pair>/<stage>/<name>/seed<k>/`` holds

- ``config.json``: the resolved config, its hash, and, outside the hashed config, the
  package version, git commit and whether the tree was dirty, the numeric stack and
  fingerprint (:mod:`pved.provenance`);
- ``metrics.jsonl``: one JSON object per logged step (also mirrored to TensorBoard);
- ``events.out.tfevents.*``: TensorBoard events;
- ``checkpoints/step<N>.pt``: resumable state, newest wins;
- ``result.json``: written last and atomically; its presence with the same config hash
  means the stage is done and is skipped.

Beside a run directory not yet made, ``.seed<k>.claim`` says that the run is being made
elsewhere (an exported batch) until a given time: the protocol leaves it alone till then.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from pved import __version__
from pved.blas import loaded_kernel, loaded_mkl_branch, loaded_numpy_simd
from pved.errors import PvedError
from pved.provenance import git_output, record_fields

CHECKPOINT_DIR = "checkpoints"


def to_jsonable(value: Any) -> Any:
    """Dataclasses, paths, tuples and numpy scalars as plain JSON values."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "item") and callable(value.item):  # numpy / torch scalars
        return value.item()
    return value


def config_hash(config: Mapping[str, Any]) -> str:
    """Stable short hash of a resolved config (key order does not matter)."""
    text = json.dumps(to_jsonable(config), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _hash_state(digest: Any, obj: Any) -> None:
    """Feed a loaded PyTorch state into ``digest`` by value: tensors by dtype, shape and
    bytes; dicts in key order; each part length-prefixed, so no two states collide by
    concatenation."""

    def part(tag: bytes, payload: bytes) -> None:
        digest.update(tag + len(payload).to_bytes(8, "little") + payload)

    if isinstance(obj, torch.Tensor):
        flat = obj.detach().cpu().contiguous().reshape(-1)
        part(b"T", f"{flat.dtype}{tuple(obj.shape)}".encode())
        part(b"B", flat.view(torch.uint8).numpy().tobytes())
    elif isinstance(obj, dict):
        part(b"D", str(len(obj)).encode())
        for key in sorted(obj, key=repr):
            _hash_state(digest, key)
            _hash_state(digest, obj[key])
    elif isinstance(obj, (list, tuple)):
        part(b"L" if isinstance(obj, list) else b"U", str(len(obj)).encode())
        for item in obj:
            _hash_state(digest, item)
    else:  # str, int, float, bool, None: what a pved state holds besides tensors
        part(type(obj).__name__.encode(), repr(obj).encode())


def file_digest(path: Path) -> str:
    """Short content hash of an input file, so a changed input invalidates a done stage.

    A PyTorch file (policy, model) is hashed by the state it holds, not by its bytes:
    ``torch.save`` writes a fresh random serialization id and the temporary file's name
    into every file, and pickles equal strings differently by object identity, so two
    saves of one state differ byte for byte. A model retrained bit for bit then keeps
    the digest its transfer runs were made under."""
    data = Path(path).read_bytes()
    if data[:4] == b"PK\x03\x04":  # a zip archive: a PyTorch file, or a numpy .npz
        try:
            state = safe_torch_load(Path(path))
        except PvedError:  # not a PyTorch file: hashed by its bytes
            pass
        else:
            return state_digest(state)
    return hashlib.sha256(data).hexdigest()[:16]


def state_digest(state: Any) -> str:
    """Short hash of a PyTorch state by value (tensors by dtype, shape and bytes; floats
    by ``repr``, so exactly): what :func:`file_digest` gives the file holding it."""
    digest = hashlib.sha256(b"pved-torch-state")
    _hash_state(digest, state)
    return digest.hexdigest()[:16]


def _read_git_commit() -> str | None:
    """HEAD of the git checkout this file lies in (None outside one, or without git)."""
    return git_output("rev-parse", "HEAD") or None


_COMMIT_AT_IMPORT = _read_git_commit()


def git_commit() -> str | None:
    """The commit of the source tree pved runs from, when it is a git checkout: HEAD as
    it was when this process imported pved, so that a run records the code it ran."""
    return _COMMIT_AT_IMPORT


def _umask_mode() -> int:
    """The mode a plainly created file gets (0o666 less the umask): mkstemp's temporary
    files are private (0o600), and results are meant to be read by others too."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see the old file or the whole new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, _umask_mode())
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_json(path: Path) -> Any:
    """The JSON in ``path``; PvedError (one line, naming the file) when it cannot be read
    or parsed: a missing, truncated or foreign file."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise PvedError(f"{path} is not readable JSON ({type(err).__name__})") from None


def atomic_write_json(path: Path, obj: Any) -> None:
    """Atomically write ``obj`` as indented JSON."""
    atomic_write_bytes(path, (json.dumps(to_jsonable(obj), indent=2) + "\n").encode())


def atomic_torch_save(path: Path, obj: Any) -> None:
    """Atomically ``torch.save`` a state (tensors, numbers, strings, dicts, lists only, so
    that it loads back with ``weights_only=True``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.fchmod(fd, _umask_mode())
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def safe_torch_load(path: Path) -> Any:
    """Load a checkpoint or weights file without executing code; a corrupt or foreign
    file raises :class:`PvedError` naming it."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise PvedError(f"file not found: {path}") from None
    except Exception as exc:  # torch raises many types for bad files
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PvedError(f"cannot load {path}: not a pved checkpoint ({first[:120]})") from None


#: the ``result.json`` field of a run restored from an archive or summary made on another
#: machine (its value: where from). Such a run is done as it is: it is not checked
#: against inputs remade here, which another machine's arithmetic makes differ in their
#: last digits (docs/decisions.md, "A restored run is not confirmed by remaking its inputs").
RESTORED_FROM = "restored_from"


def repoint_result(run_dir: Path, final_dir: Path) -> None:
    """Point ``result.json``'s paths to the run's own artefacts (``policy``, ``model``,
    ``dataset``, ``bank``), written where the run was made, at ``final_dir``, where a copy
    of the run is about to live. A path to an artefact the copy lacks is dropped rather
    than left pointing at another directory or machine."""
    path = run_dir / "result.json"
    result = json.loads(path.read_text())
    for key in ("policy", "model", "dataset", "bank"):
        if isinstance(result.get(key), str):
            name = Path(result[key]).name
            if (run_dir / name).is_file():
                result[key] = str(final_dir / name)
            else:
                del result[key]
    atomic_write_json(path, result)


def claim_file(run_dir: Path) -> Path:
    """Where a claim on ``run_dir`` lives: a hidden file beside it, so that globbing the
    runs (``*/transfer/*/seed*``) never sees it."""
    return run_dir.with_name(f".{run_dir.name}.claim")


def write_claim(run_dir: Path, holder: str, until: float) -> None:
    """Claim ``run_dir`` for ``holder`` (e.g. a batch directory) until ``until`` (seconds
    since the epoch): a claim expires on its own, so a batch that never comes back only
    delays its runs here."""
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(claim_file(run_dir), {"holder": holder, "until": until})


def claim_holder(run_dir: Path, now: float | None = None) -> str | None:
    """The holder of an unexpired claim on ``run_dir``, else None. An unreadable claim
    counts as none: a damaged file must not hold a protocol's run back."""
    try:
        claim = json.loads(claim_file(run_dir).read_text())
        holder, until = claim["holder"], float(claim["until"])
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError):
        return None
    if not isinstance(holder, str):
        return None
    return holder if until > (time.time() if now is None else now) else None


def release_claim(run_dir: Path, holder: str | None = None) -> bool:
    """Remove the claim on ``run_dir`` (only ``holder``'s, when given, expired or not);
    returns whether one was removed."""
    path = claim_file(run_dir)
    if holder is not None:
        try:
            if json.loads(path.read_text()).get("holder") != holder:
                return False
        except (OSError, ValueError, AttributeError, UnicodeDecodeError):
            return False
    try:
        path.unlink()
    except FileNotFoundError:
        return False
    return True


#: the fields of ``config.json`` beside the config and its hash: the process's, never hashed
PROVENANCE_KEYS = (
    "pved_version",
    "git_commit",
    "blas_kernel",
    "mkl_branch",
    "numpy_simd",
    "git_dirty",
    "stack",
    "fingerprint",
)


def _provenance(config_record: Mapping[str, Any]) -> dict[str, Any]:
    """What a ``config.json`` says of the process that wrote it: pved's version and
    commit, OpenBLAS's kernel, MKL's branch, numpy's SIMD group, whether the tree was
    dirty, the numeric stack and fingerprint (:mod:`pved.provenance`; None where a
    record predates the field)."""
    return {key: config_record.get(key) for key in PROVENANCE_KEYS}


def last_logged_step(run_dir: Path) -> int:
    """The ``step`` of the last whole record of ``run_dir``'s ``metrics.jsonl`` (0 if none
    yet): a running job's progress, read from its tail (a line being written is skipped)."""
    try:
        with (run_dir / "metrics.jsonl").open("rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - 4096))
            lines = fh.read().decode(errors="replace").splitlines()
    except OSError:
        return 0
    for line in reversed(lines):
        try:
            return int(json.loads(line)["step"])
        except (ValueError, KeyError, TypeError):
            continue
    return 0


def run_path(root: Path | str, pair: str, stage: str, name: str, seed: int) -> Path:
    """``<root>/<pair>/<stage>/<name>/seed<k>``."""
    return Path(root) / pair / stage / name / f"seed{seed}"


def run_file(path: Path | str, name: str, what: str | None = None) -> Path:
    """``path`` itself, or ``path/name`` when ``path`` is a run directory (a stage's
    ``model.pt``, ``bank.npz``, ``pairs.npz``, ``policy.pt``); :class:`PvedError` naming
    ``what`` (default: ``name``) when there is no such file."""
    path = Path(path)
    resolved = path / name if path.is_dir() else path
    if not resolved.is_file():
        where = f"{path} (a directory without {name})" if path.is_dir() else str(path)
        raise PvedError(f"{what or name} not found: {where}")
    return resolved


class Run:
    """One stage's run directory.

    Typical use::

        run = Run(path, config)
        if run.is_done():
            return run.read_result()
        state = run.latest_checkpoint()      # None, or the newest saved state
        ...
        run.log(step, loss=..., return_mean=...)
        run.save_checkpoint(step, state)
        run.finish({"success_rate": ...})     # result.json, written last
    """

    def __init__(self, path: Path | str, config: Mapping[str, Any], tensorboard: bool = True):
        self.path = Path(path)
        self.config = to_jsonable(config)
        self.hash = config_hash(self.config)
        self._use_tensorboard = tensorboard
        self._writer: Any = None
        self._started = False

    # -- state queries -------------------------------------------------------------
    @property
    def result_path(self) -> Path:
        return self.path / "result.json"

    def is_done(self) -> bool:
        """True when ``result.json`` exists and was written under the same config hash."""
        if not self.result_path.exists():
            return False
        try:
            result = json.loads(self.result_path.read_text())
        except (OSError, json.JSONDecodeError):
            return False
        return bool(result.get("config_hash") == self.hash)

    def read_result(self) -> dict[str, Any]:
        """The finished run's ``result.json``."""
        return dict(json.loads(self.result_path.read_text()))

    # -- writing ---------------------------------------------------------------------
    def start(self) -> None:
        """Create the directory and write ``config.json``. A previous run with another
        config hash and no result is cleared of its checkpoints and metrics, so that it
        cannot be resumed into the new config. A previous start of this same config (a
        run resumed, perhaps on another machine or under another commit) is kept in
        ``previous_starts``, oldest first (whether or not a start got as far as a
        checkpoint): what decides a run's last digits (the commit,
        the BLAS kernel, MKL's branch) may differ between the parts of a resumed run,
        and the top-level fields only describe the latest start. Starting the same
        :class:`Run` object again (a stage and the trainer it calls both start it) does
        nothing more."""
        if self._started:
            return
        self._started = True
        self.path.mkdir(parents=True, exist_ok=True)
        config_file = self.path / "config.json"
        previous_starts: list[dict[str, Any]] = []
        if config_file.exists():
            try:
                previous = dict(json.loads(config_file.read_text()))
            except (OSError, json.JSONDecodeError, TypeError, ValueError):
                previous = {}
            old = previous.get("config_hash")
            if old == self.hash:
                earlier = previous.get("previous_starts")
                earlier = earlier if isinstance(earlier, list) else []
                previous_starts = [*earlier, _provenance(previous)]
            else:
                for ckpt in self.checkpoint_dir.glob("*.pt"):
                    ckpt.unlink()
                (self.path / "metrics.jsonl").unlink(missing_ok=True)
                for events in self.path.glob("events.out.tfevents.*"):
                    events.unlink()
                self.result_path.unlink(missing_ok=True)
        atomic_write_json(
            config_file,
            {
                "config": self.config,
                "config_hash": self.hash,
                "pved_version": __version__,
                "git_commit": git_commit(),
                "blas_kernel": loaded_kernel(),
                "mkl_branch": loaded_mkl_branch(),
                "numpy_simd": loaded_numpy_simd(),
                # outside the hashed config, as the commit is: the code a run was made by
                # does not decide whether it is reused (pved.provenance)
                **record_fields(),
                **({"previous_starts": previous_starts} if previous_starts else {}),
            },
        )

    def log(self, step: int, **scalars: float) -> None:
        """Append one ``metrics.jsonl`` line and the same scalars to TensorBoard."""
        clean = {k: float(v) for k, v in scalars.items()}
        record = {
            "step": int(step),
            **{k: (v if math.isfinite(v) else None) for k, v in clean.items()},
        }
        with open(self.path / "metrics.jsonl", "a") as handle:
            handle.write(json.dumps(record) + "\n")
        if self._use_tensorboard:
            writer = self._tensorboard()
            for key, value in clean.items():
                writer.add_scalar(key, value, int(step))

    def _tensorboard(self) -> Any:
        if self._writer is None:
            from torch.utils.tensorboard import SummaryWriter

            self._writer = SummaryWriter(log_dir=str(self.path), flush_secs=30)
        return self._writer

    def read_metrics(self) -> list[dict[str, Any]]:
        """All ``metrics.jsonl`` records in order."""
        path = self.path / "metrics.jsonl"
        if not path.exists():
            return []
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]

    def drop_metrics_after(self, step: int, final_eval: bool = False) -> None:
        """On resume, forget the ``metrics.jsonl`` records past ``step``, the step of the
        checkpoint resumed from (-1 when there is none and the run starts over): an
        interrupted run logged them after its last checkpoint, the resumed run logs those
        steps again, and learning curves must not count them twice. (TensorBoard events
        are append-only and keep both.) ``final_eval``: that checkpoint is the run's last,
        taken before its final evaluation, so the evaluation records at ``step`` were
        logged after it too (a run killed before writing its result) and go as well."""
        path = self.path / "metrics.jsonl"
        records = self.read_metrics()

        def after(r: Mapping[str, Any]) -> bool:
            at = int(r.get("step", 0))
            return at > step or (
                final_eval and at == step and any(k.startswith("eval/") for k in r)
            )

        kept = [r for r in records if not after(r)]
        if len(kept) != len(records):
            atomic_write_bytes(path, "".join(json.dumps(r) + "\n" for r in kept).encode())

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / CHECKPOINT_DIR

    def save_checkpoint(self, step: int, state: Mapping[str, Any], keep: int = 2) -> Path:
        """Atomically save a resumable state; older checkpoints beyond ``keep`` go."""
        path = self.checkpoint_dir / f"step{int(step):012d}.pt"
        atomic_torch_save(path, dict(state))
        for old in sorted(self.checkpoint_dir.glob("step*.pt"))[:-keep]:
            old.unlink(missing_ok=True)
        return path

    def latest_checkpoint(self) -> dict[str, Any] | None:
        """The newest checkpoint's state, or None when there is none."""
        ckpts = sorted(self.checkpoint_dir.glob("step*.pt"))
        if not ckpts:
            return None
        return dict(safe_torch_load(ckpts[-1]))

    def finish(self, result: Mapping[str, Any]) -> dict[str, Any]:
        """Write ``result.json`` (last, atomically) and close TensorBoard."""
        full = {**to_jsonable(result), "config_hash": self.hash}
        self.close()
        atomic_write_json(self.result_path, full)
        return full

    def close(self) -> None:
        """Flush and close the TensorBoard writer."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
