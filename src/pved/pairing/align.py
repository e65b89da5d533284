"""Time alignment of a pair of episodes (paper IV.A: "we align the trajectories between
the two agents by subsampling the longer trajectories along the timesteps")."""

from __future__ import annotations

import numpy as np

from pved.errors import PvedError

ALIGNMENTS = ("subsample",)


def subsample_indices(length_source: int, length_target: int) -> tuple[np.ndarray, np.ndarray]:
    """Row indices pairing two episodes of different lengths.

    The shorter episode keeps every step; the longer one is subsampled at evenly spaced
    steps (first and last step kept), so both sequences span the same phase of the task.

    Returns:
        (idx_source, idx_target), each (min(L_S, L_T),) int64, non-decreasing.
    """
    if length_source < 1 or length_target < 1:
        raise PvedError(f"cannot align empty episodes ({length_source}, {length_target})")
    n = min(length_source, length_target)

    def spread(length: int) -> np.ndarray:
        if length == n:
            return np.arange(n, dtype=np.int64)
        return np.rint(np.linspace(0, length - 1, n)).astype(np.int64)

    return spread(length_source), spread(length_target)


def align(method: str, length_source: int, length_target: int) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch on the alignment ``method``; an unknown one raises :class:`PvedError`."""
    if method == "subsample":
        return subsample_indices(length_source, length_target)
    raise PvedError(f"unknown alignment {method!r}; known: {', '.join(ALIGNMENTS)}")
