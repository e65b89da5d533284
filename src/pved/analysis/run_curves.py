"""One run's evaluation curve, wherever it is kept, and the per-run scores read off it
(:mod:`pved.analysis.judge` judges with them, :mod:`pved.analysis.compare` compares them).

Where a run's curve is: its ``metrics.jsonl`` (next to its ``result.json``, or under
``DIR/runs/KEY`` when the protocol directory has moved), or, for a published protocol
directory (``docs/protocol/...``), its ``curve`` in the committed record
:data:`RECORD_FILE` (``pved archive summary``). A run with neither has "no curves", and no
score that needs one: nothing is guessed from the summary's mean curve.

Per-run scores off a curve (steps, values):

- early: the mean of its points at steps <= :data:`EARLY_FRACTION` of its last step;
- drop: its best point minus its last (>= 0; lower is more stable);
- auc, jumpstart and steps to a threshold: Taylor & Stone (2009)'s measures of transfer
  (:func:`auc`, :func:`steps_to_threshold`; the jumpstart is the first point).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import numpy as np

from pved.analysis.curves import eval_points, read_eval_points
from pved.errors import PvedError
from pved.record_paths import resolve_record_path

EARLY_FRACTION = 0.25
"""Early score: evaluation points at steps <= this fraction of the run's last step."""
RECORD_FILE = "finished-transfer-runs.json"
"""A published protocol's committed record of its finished transfer runs, curves included
(:data:`pved.protocol.archive.SUMMARY_FILE`; not imported: it pulls in torch)."""
CURVE_SCORES = ("early", "drop", "auc", "jumpstart", "reach")
"""The per-run scores read off a curve (``reach``: steps to a threshold)."""


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def metrics_file(directory: Path, run: dict[str, Any]) -> Path | None:
    """A run's metrics.jsonl: next to its result.json, or under ``directory/runs/KEY``
    when the protocol directory has moved since."""
    candidates = []
    if isinstance(run.get("result"), str):
        # relative to the protocol directory; an older summary's absolute path as it is
        candidates.append(resolve_record_path(run["result"], directory).parent / "metrics.jsonl")
    if isinstance(run.get("key"), str):
        candidates.append(directory / "runs" / run["key"] / "metrics.jsonl")
    return next((p for p in candidates if p.is_file()), None)


@functools.lru_cache(maxsize=8)
def _record(path: Path, mtime_ns: int) -> dict[str, Any]:
    """The committed record at ``path`` as of ``mtime_ns`` (read once per change: a pair's
    methods all read the one file)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise PvedError(f"{path}: unreadable or not JSON ({_one_line(exc)})") from exc
    return data if isinstance(data, dict) else {}


def run_record(directory: Path, run: dict[str, Any]) -> dict[str, Any] | None:
    """``run``'s ``config.json`` (its config and the code that made it) wherever it is
    kept, as :func:`run_curve` finds the curve: beside its ``metrics.jsonl``, else its
    ``config`` in ``directory``'s :data:`RECORD_FILE`; None where neither holds one."""
    path = metrics_file(directory, run)
    config = path.with_name("config.json") if path is not None else None
    if config is not None and config.is_file():
        try:
            data = json.loads(config.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise PvedError(f"{config}: unreadable or not JSON ({_one_line(exc)})") from exc
        return data if isinstance(data, dict) else None
    where = directory / RECORD_FILE
    record = _record(where, where.stat().st_mtime_ns) if where.is_file() else {}
    entry = record.get(str(run.get("key")))
    found = entry.get("config") if isinstance(entry, dict) else None
    return found if isinstance(found, dict) else None


def eval_curve(metrics_path: Path, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values) of a run's ``eval/<metric>`` points, one per step
    (:func:`pved.analysis.curves.read_eval_points`); PvedError if unreadable."""
    try:
        return read_eval_points(metrics_path, f"eval/{metric}")
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise PvedError(f"{metrics_path}: unreadable metrics ({_one_line(exc)})") from exc


def run_curve(
    directory: Path, metric: str, run: dict[str, Any]
) -> tuple[np.ndarray, np.ndarray] | str:
    """(steps, values) of the finite ``eval/<metric>`` points of ``run`` (a summary's run
    entry) of the protocol ``directory``: from its ``metrics.jsonl`` (:func:`metrics_file`)
    or else from its ``curve`` in ``directory``'s :data:`RECORD_FILE`; or the reason
    there is none (``no curves ...``, no points, non-finite points). PvedError for a file
    that is there but unreadable."""
    path = metrics_file(directory, run)
    where: Path
    if path is not None:
        steps, values = eval_curve(path, metric)
        where = path
    else:
        where = directory / RECORD_FILE
        record = _record(where, where.stat().st_mtime_ns) if where.is_file() else {}
        entry = record.get(str(run.get("key")))
        rows = entry.get("curve") if isinstance(entry, dict) else None
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            return f"no curves of run {run.get('key')} (no metrics.jsonl, no curve in {where})"
        try:
            steps, values = eval_points(rows, f"eval/{metric}")
        except (ValueError, KeyError, TypeError) as exc:
            raise PvedError(f"{where}: unreadable curve of {run.get('key')} ({exc})") from exc
    if not steps.size:
        return f"no eval/{metric} points in {where}"
    if not np.all(np.isfinite(values)):
        return f"NaN or infinite eval/{metric} in {where}"
    return steps, values


def early_score(steps: np.ndarray, values: np.ndarray) -> float:
    """Mean of the evaluation values at steps <= 25% of the last evaluation step."""
    return float(values[steps <= EARLY_FRACTION * steps[-1]].mean())


def drop(values: np.ndarray) -> float:
    """Best evaluation value minus the last one (>= 0)."""
    return float(values.max() - values[-1])


def auc(steps: np.ndarray, values: np.ndarray) -> float:
    """The area under a run's evaluation curve, normalised: the trapezoid area over its
    evaluation steps divided by the step span (last step − first), so that it is on the
    metric's scale (the curve's mean height: a success rate's lies in [0, 1]) and runs
    of different lengths compare; a curve of one point: its value. Taylor & Stone
    (2009)'s "area under the curve" (total reward) measure of transfer, per run."""
    if steps.size < 2:
        return float(values[0])
    return float(np.trapezoid(values, steps) / (steps[-1] - steps[0]))


def steps_to_threshold(steps: np.ndarray, values: np.ndarray, threshold: float) -> float:
    """The first evaluation step at which a run's curve is >= ``threshold`` (Taylor &
    Stone's "time to threshold", per run). A run that never gets there counts as one
    evaluation interval past its last step, the earliest it could have: a mean over
    runs that include such runs is a lower bound (the transfer measures count them)."""
    hit = np.flatnonzero(values >= threshold)
    if hit.size:
        return float(steps[hit[0]])
    interval = steps[-1] - steps[-2] if steps.size > 1 else 0
    return float(steps[-1] + interval)


def curve_score(score: str, steps: np.ndarray, values: np.ndarray) -> float:
    """One run's ``score`` (one of :data:`CURVE_SCORES` but ``reach``, which needs a
    threshold) off its curve."""
    if score == "early":
        return early_score(steps, values)
    if score == "drop":
        return drop(values)
    if score == "auc":
        return auc(steps, values)
    if score == "jumpstart":
        return float(values[0])
    raise PvedError(f"unknown score {score!r}; known: final, {', '.join(CURVE_SCORES)}")
