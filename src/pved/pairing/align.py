"""Time alignment of a pair of episodes.

- ``subsample`` (paper IV.A: "we align the trajectories between the two agents by
  subsampling the longer trajectories along the timesteps"): by time alone.
- ``time``: by physical time, for agents whose control periods differ (Humanoid 0.015 s,
  Ant 0.05 s): the step of each agent at the same moment of the episode.
- ``dtw``: dynamic time warping of the two episodes' embeddings in a learned shared
  space, as Gupta et al. (2017) align their agents; :func:`dtw_indices` aligns one pair
  given the embeddings, and :func:`pved.pairing.rounds.dtw_rounds` runs the rounds
  (subsample → train → embed → warp → retrain).
- ``phase``: by gait phase, for walkers whose strides take different times: each pair of
  the time alignment (``time`` where both control periods are known, else
  ``subsample``) keeps its target step and takes, among the source steps near its time
  partner, the one whose gait phase is nearest (:func:`phase_indices`). A gait's phase
  is read off each agent's first principal component of its standardised robot state
  (:func:`gait_phase`); :func:`pved.pairing.rounds.phase_alignment` fits the components
  on all episodes.
"""

from __future__ import annotations

import numpy as np

from pved.errors import PvedError

ALIGNMENTS = ("subsample", "time", "dtw", "phase")
#: Alignments that need a learned shared space (run by the collect-pairs stage).
LEARNED_ALIGNMENTS = ("dtw",)
#: Alignments fitted to the collected episodes (run by the collect-pairs stage).
DATA_ALIGNMENTS = ("dtw", "phase")
#: ``phase``: how many pairs of the time alignment to either side a step's phase partner
#: may come from (10 Ant steps are 0.5 s, about one Ant stride on the Slope).
PHASE_WINDOW = 10


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


def time_indices(
    length_source: int, length_target: int, dt_source: float, dt_target: float
) -> tuple[np.ndarray, np.ndarray]:
    """Row indices pairing the steps of two episodes taken at the same physical time.

    Step k of an agent with control period dt happens at t = k·dt. The agent with the
    longer period keeps each of its steps up to the end of the shorter episode (in
    seconds), and is paired with the other agent's step nearest in time; so both sides
    cover the same stretch of the climb, and the finer agent is subsampled.

    Returns:
        (idx_source, idx_target), each (P,) int64, non-decreasing.
    """
    if length_source < 1 or length_target < 1:
        raise PvedError(f"cannot align empty episodes ({length_source}, {length_target})")
    if not (dt_source > 0 and dt_target > 0):
        raise PvedError(f"control periods must be positive, got {dt_source}, {dt_target}")
    duration = min(length_source * dt_source, length_target * dt_target)

    def pair(
        dt_coarse: float, len_coarse: int, dt_fine: float, len_fine: int
    ) -> tuple[np.ndarray, np.ndarray]:
        # the coarse agent's steps that start within both episodes (step 0 always does)
        coarse = np.arange(len_coarse, dtype=np.int64)
        coarse = coarse[coarse * dt_coarse < duration * (1.0 - 1e-9)]
        fine = np.rint(coarse * dt_coarse / dt_fine).astype(np.int64)
        # a coarse step near the end of the shorter episode may round to a fine step
        # just past it: drop it rather than pair it with a step further away in time
        keep = fine <= len_fine - 1
        return coarse[keep], fine[keep]

    if dt_source >= dt_target:
        return pair(dt_source, length_source, dt_target, length_target)
    i_t, i_s = pair(dt_target, length_target, dt_source, length_source)
    return i_s, i_t


def dtw_indices(
    embedding_source: np.ndarray, embedding_target: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The DTW warping path between two episodes' embeddings (Euclidean local cost).

    Every step of both episodes appears at least once, the path is monotone and starts
    and ends with both episodes' first and last steps; a step may be paired with several
    steps of the other episode. Computed by ``dtaidistance`` (C implementation).

    Args:
        embedding_source: (L_S, K) e.g. the source's shared means per step.
        embedding_target: (L_T, K) the target's, in the same space.

    Returns:
        (idx_source, idx_target), each (P,) int64 with max(L_S, L_T) <= P < L_S + L_T.
    """
    from dtaidistance import dtw_ndim

    a = np.ascontiguousarray(embedding_source, dtype=np.float64)
    b = np.ascontiguousarray(embedding_target, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1] or not (len(a) and len(b)):
        raise PvedError(
            f"DTW needs two non-empty (L, K) embeddings of equal K, got {a.shape} and {b.shape}"
        )
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise PvedError("DTW embeddings contain NaN or inf")
    path = np.asarray(dtw_ndim.warping_path(a, b, use_c=True), dtype=np.int64)
    return path[:, 0].copy(), path[:, 1].copy()


def gait_phase(signal: np.ndarray) -> np.ndarray:
    """The wrapped phase (radians, (L,)) of one episode's 1-D gait signal (L,): the angle
    of its analytic signal (Hilbert transform) after removing its mean."""
    from scipy.signal import hilbert

    x = np.asarray(signal, dtype=np.float64)
    if x.ndim != 1 or not len(x) or not np.isfinite(x).all():
        raise PvedError(f"a gait signal must be a finite 1-D array, got shape {x.shape}")
    return np.angle(hilbert(x - x.mean()))


def first_component(states: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The first principal component of ``states`` (M, D) after standardising each
    coordinate (one that never moves keeps scale 1: it carries no gait).

    Returns:
        (mean (D,), scale (D,), direction (D,) unit, share of the standardised variance
        it explains); an agent's gait signal is ``((x - mean) / scale) @ direction``.
    """
    x = np.asarray(states, dtype=np.float64)
    mean, scale = x.mean(0), x.std(0)
    scale[scale < 1e-8] = 1.0
    _, singular, vt = np.linalg.svd((x - mean) / scale, full_matrices=False)
    return mean, scale, vt[0], float(singular[0] ** 2 / (singular**2).sum())


def phase_indices(
    phase_source: np.ndarray,
    phase_target: np.ndarray,
    base: tuple[np.ndarray, np.ndarray],
    window: int = PHASE_WINDOW,
) -> tuple[np.ndarray, np.ndarray]:
    """Re-pair the time alignment ``base`` = (idx_source, idx_target) by gait phase.

    Pair k keeps its target step and takes the source step, among those from the time
    partner of pair k - ``window`` to that of pair k + ``window`` (every source step in
    that stretch, not only the paired ones), whose wrapped phase in ``phase_source``
    (L_S,) is nearest on the circle to its target step's in ``phase_target`` (L_T,);
    ties go to the earliest. So a source step of the same moment of the stride stands in
    for the one of the same moment of the episode, at most ``window`` pairs away.

    Returns:
        (idx_source, idx_target), each (P,) int64, P = len(base[0]).
    """
    i_s, i_t = (np.asarray(i, dtype=np.int64) for i in base)
    if i_s.shape != i_t.shape or i_s.ndim != 1 or not len(i_s):
        raise PvedError(f"a base alignment is two equal non-empty index arrays, got {i_s.shape}")
    if window < 0:
        raise PvedError(f"the phase window must be at least 0, got {window}")
    new_s = np.empty_like(i_s)
    for k in range(len(i_s)):
        lo, hi = i_s[max(0, k - window)], i_s[min(len(i_s) - 1, k + window)]
        candidates = np.arange(min(lo, hi), max(lo, hi) + 1)
        gap = np.angle(np.exp(1j * (phase_source[candidates] - phase_target[i_t[k]])))
        new_s[k] = candidates[int(np.argmin(np.abs(gap)))]
    return new_s, i_t.copy()


def align(
    method: str,
    length_source: int,
    length_target: int,
    dt_source: float | None = None,
    dt_target: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch on a time-only alignment ``method`` (``time`` needs both control periods);
    an unknown one raises :class:`PvedError`, a learned one (``dtw``) says where it runs."""
    if method == "subsample":
        return subsample_indices(length_source, length_target)
    if method == "time":
        if dt_source is None or dt_target is None:
            raise PvedError("alignment 'time' needs both agents' control periods")
        return time_indices(length_source, length_target, dt_source, dt_target)
    if method in DATA_ALIGNMENTS:
        raise PvedError(f"alignment {method!r} is fitted to the collected episodes; use the stage")
    raise PvedError(f"unknown alignment {method!r}; known: {', '.join(ALIGNMENTS)}")
