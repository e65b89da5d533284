"""Alignments fitted to the collected episode pairs (``dtw``, ``phase``; see ``align.py``).

Both start from a time-only alignment of every episode pair (:func:`base_alignment`) and
re-pair it with what the episodes show:

- :func:`dtw_rounds`: Gupta et al. (2017)'s alternation of training a shared-space model
  on the current alignment and re-aligning by DTW in its shared space. The model is
  trained by the caller's ``fit`` (the collect-pairs stage passes the pair's model and
  config), so pairing needs no model code.
- :func:`phase_alignment`: re-pairing by gait phase around the same moment.

Each returns the new alignment and statistics of what moved, for the dataset's header.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pved.pairing.align import (
    LEARNED_ALIGNMENTS,
    PHASE_WINDOW,
    dtw_indices,
    first_component,
    gait_phase,
    phase_indices,
)
from pved.pairing.collect import EpisodePair, pairs_to_dataset

#: One episode pair's alignment: equal-length source and target step indices.
Alignment = tuple[np.ndarray, np.ndarray]
#: Rows ``[robot state, action]`` of the source and of the target -> their shared means.
Embedder = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
#: Model inputs ``(x_source, x_target)`` of aligned rows -> a trained model's embedder.
SharedFit = Callable[[np.ndarray, np.ndarray], Embedder]


def base_alignment(align: str, dt_source: float | None, dt_target: float | None) -> str:
    """The time-only alignment that ``align`` starts from: ``subsample`` for a learned
    one (Gupta et al.'s first round), ``time`` for ``phase`` where both control periods
    are known (else ``subsample``), ``align`` itself otherwise."""
    if align in LEARNED_ALIGNMENTS:
        return "subsample"
    if align == "phase":  # re-paired by phase around the same moment
        return "time" if dt_source is not None and dt_target is not None else "subsample"
    return align


def model_rows(pairs: list[EpisodePair], header: dict[str, Any]) -> list[np.ndarray]:
    """Per episode pair, the model inputs ``[robot state, action]`` of both agents
    (source then target, so episode ``e``'s are at ``2e`` and ``2e + 1``)."""
    idx_s = np.asarray(header["robot_state_indices_source"])
    idx_t = np.asarray(header["robot_state_indices_target"])
    rows = []
    for e_s, e_t in pairs:
        rows.append(np.concatenate([e_s.obs[:, idx_s], e_s.act], 1).astype(np.float32))
        rows.append(np.concatenate([e_t.obs[:, idx_t], e_t.act], 1).astype(np.float32))
    return rows


def dtw_rounds(
    pairs: list[EpisodePair],
    alignment: list[Alignment],
    header: dict[str, Any],
    rounds: int,
    fit: SharedFit,
) -> tuple[list[Alignment], list[dict[str, float]]]:
    """Gupta et al. (2017)'s alternation: ``fit`` a model on the current alignment,
    re-align each episode pair by DTW on the two agents' shared means, repeat ``rounds``
    times. Returns the last alignment and per-round statistics (the share of source
    steps whose partner changed)."""
    rows = model_rows(pairs, header)
    stats: list[dict[str, float]] = []
    for round_index in range(rounds):
        data = pairs_to_dataset(pairs, alignment, shared_task_keys=(), header=header)
        embed = fit(*data.model_inputs())
        new_alignment = []
        for e in range(len(pairs)):
            emb_s, emb_t = embed(rows[2 * e], rows[2 * e + 1])
            new_alignment.append(dtw_indices(emb_s, emb_t))
        changed = [
            float(np.mean(partner(old, len(pairs[e][0].obs)) != partner(new, len(pairs[e][0].obs))))
            for e, (old, new) in enumerate(zip(alignment, new_alignment, strict=True))
        ]
        stats.append({"round": float(round_index + 1), "moved_fraction": float(np.mean(changed))})
        alignment = new_alignment
    return alignment, stats


def phase_alignment(
    pairs: list[EpisodePair],
    alignment: list[Alignment],
    header: dict[str, Any],
) -> tuple[list[Alignment], dict[str, Any]]:
    """Re-pair every episode pair of the time alignment by gait phase
    (:func:`pved.pairing.align.phase_indices`). Each agent's gait signal is the first
    principal component of its robot state, standardised over all its episodes' steps;
    its phase is taken per episode. Returns the new alignment and what it did: the share
    of the components' variance, and how far (in source steps) a pair's source step moved
    (mean, and the share of pairs that moved)."""
    stats: dict[str, Any] = {"window": PHASE_WINDOW}
    phases: dict[str, list[np.ndarray]] = {}
    for side, key, column in (("source", "robot_state_indices_source", 0),
                              ("target", "robot_state_indices_target", 1)):  # fmt: skip
        idx = np.asarray(header[key])
        states = [np.asarray(pair[column].obs, dtype=np.float64)[:, idx] for pair in pairs]
        mean, scale, direction, share = first_component(np.concatenate(states))
        stats[f"pc1_variance_{side}"] = share
        phases[side] = [gait_phase(((x - mean) / scale) @ direction) for x in states]
    new_alignment = [
        phase_indices(phases["source"][e], phases["target"][e], base)
        for e, base in enumerate(alignment)
    ]
    moved = np.concatenate(
        [np.abs(new[0] - old[0]) for old, new in zip(alignment, new_alignment, strict=True)]
    )
    stats["moved_fraction"] = float(np.mean(moved > 0))
    stats["mean_source_steps_moved"] = float(moved.mean())
    return new_alignment, stats


def partner(alignment: Alignment, length_source: int) -> np.ndarray:
    """For each source step, the mean target step it is paired with (NaN if unpaired)."""
    i_s, i_t = alignment
    total = np.bincount(i_s, weights=i_t, minlength=length_source)
    count = np.bincount(i_s, minlength=length_source)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)
