"""Learning curves over environment steps, and the summaries of one method's runs. Means and
differences are compared with the project's one interval method, the two-level bootstrap
of :mod:`pved.analysis.bootstrap` (whose :data:`REPS`, :data:`SEED`, ``CI_SIZE``,
``bootstrap_mean`` and ``bootstrap_difference`` are also importable from here). The
one-level bootstrap over runs computed with rliable (``rliable.library.
get_interval_estimates``, as Agarwal et al. (2021) recommend for few-run RL results) is
kept only where that design has no place: the interquartile mean's interval and the bands
of the curve figures, both labelled one-level where printed."""

from __future__ import annotations

import io
import json
import math
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pved.analysis.bootstrap import CI_SIZE as CI_SIZE
from pved.analysis.bootstrap import REPS as REPS
from pved.analysis.bootstrap import SEED as SEED
from pved.analysis.bootstrap import bootstrap_difference as bootstrap_difference
from pved.analysis.bootstrap import bootstrap_mean, finite
from pved.errors import PvedError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

ONE_LEVEL_REPS = 2000
"""Resamples of the one-level (rliable) intervals: the IQM's and the curve bands'."""


@contextmanager
def _seeded_global_rng(seed: int) -> Iterator[None]:
    """Seed numpy's global RNG for the block and restore its previous state afterwards.

    rliable's ``StratifiedBootstrap`` draws its resampling indices with ``np.random.choice``
    (the global RNG) and ignores its ``random_state`` argument for them, so this is the only
    way to make its intervals reproducible without leaving the caller's RNG changed. (Hence
    the legacy global-RNG calls, which ruff's NPY002 would otherwise steer away from.)"""
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


def _bootstrap(
    scores: np.ndarray, func: Callable[[np.ndarray], np.ndarray], reps: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """rliable's stratified percentile bootstrap of ``func`` over the runs (axis 0) of
    ``scores`` (runs, k). Returns (point estimates (m,), intervals (2, m): row 0 the lower,
    row 1 the upper 95% bounds)."""
    if reps < 1:
        raise PvedError(f"bootstrap needs reps >= 1, got {reps}")
    # Imported here: rliable pulls in arch and pandas, which take seconds to import.
    from rliable import library as rly

    with _seeded_global_rng(seed):
        point, interval = rly.get_interval_estimates(
            {"scores": scores},
            func,
            reps=reps,
            confidence_interval_size=CI_SIZE,
        )
    return np.asarray(point["scores"], np.float64), np.asarray(interval["scores"], np.float64)


def bootstrap_summary(
    scores: np.ndarray,
    reps: int | None = None,
    seed: int = SEED,
    *,
    seeds: Sequence[Hashable] | None = None,
    sources: Sequence[Hashable] | None = None,
) -> dict[str, float | list[float] | int]:
    """Mean and interquartile mean (IQM, the 25%-trimmed mean) of per-run final scores, each
    with its 95% percentile bootstrap CI: the mean's the project's one method, the
    two-level bootstrap over the runs' ``sources`` and ``seeds`` (:func:`bootstrap_mean`;
    neither given: over runs), the IQM's one-level, over runs (rliable; a trimmed mean has
    no two-level form here). ``reps``: both intervals' resamples (default :data:`REPS`
    for the mean, :data:`ONE_LEVEL_REPS` for the IQM); reproducible for a given ``seed``;
    numpy's global RNG is left as it was.

    Returns ``{"runs": n, "mean": m, "iqm": q, "mean_ci": [lo, hi], "iqm_ci": [lo, hi]}``.
    With one run both intervals are degenerate, ``[x, x]``. Raises PvedError for an empty,
    non-1-D or non-finite ``scores``, or labels that do not match the runs."""
    values = finite(scores, "bootstrap_summary")
    if values.ndim != 1:
        raise PvedError(f"bootstrap_summary wants a 1-D array of run scores, got {values.shape}")
    n = int(values.size)
    if n == 1:
        # One run has no spread to resample; the interval is the value itself.
        x = float(values[0])
        return {"runs": 1, "mean": x, "iqm": x, "mean_ci": [x, x], "iqm_ci": [x, x]}
    from rliable import metrics

    mean = bootstrap_mean(values, seeds, sources, reps=reps or REPS, seed=seed)
    # rliable wants (runs, tasks); the final scores are one task.
    point, interval = _bootstrap(
        values[:, None],
        lambda s: np.array([metrics.aggregate_iqm(s)]),
        reps or ONE_LEVEL_REPS,
        seed,
    )
    return {
        "runs": n,
        "mean": mean["mean"],
        "iqm": float(point[0]),
        "mean_ci": mean["mean_ci"],
        "iqm_ci": [float(interval[0, 0]), float(interval[1, 0])],
    }


@dataclass
class Curve:
    """One method's curve: ``values`` (runs, points) at env ``steps`` (points,)."""

    method: str
    steps: np.ndarray
    values: np.ndarray
    seeds: list[int]

    @property
    def mean(self) -> np.ndarray:
        """Mean over runs at each evaluation step, shape (points,)."""
        return np.asarray(self.values.mean(0))

    def band(self, reps: int = ONE_LEVEL_REPS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi), each (points,): per evaluation step, the one-level 95% percentile
        bootstrap CI of the mean over runs (rliable, ``reps`` resamples, reproducible for a
        given ``seed``): a figure's band, not an interval a verdict reads.
        One run gives a zero-width band on the mean. Raises PvedError for NaN/inf values."""
        values = finite(self.values, f"curve of {self.method}")
        if values.shape[0] == 1:
            return values[0].copy(), values[0].copy()
        # Each step is one rliable "task": the stratified bootstrap resamples runs per step,
        # which gives each step's marginal interval of the mean.
        _, interval = _bootstrap(values, lambda s: np.asarray(s.mean(0)), reps, seed)
        return interval[0], interval[1]


def steps_to_reach(curve: Curve, threshold: float) -> int | None:
    """The first evaluation step at which ``curve``'s mean over runs is >= ``threshold``, or
    None if it never gets there.

    This is how "the steps each method needs to reach the plain-PPO baseline's final
    performance" is measured: pass the baseline's final mean as ``threshold``. It reads the
    evaluation schedule, so its resolution is the evaluation interval."""
    if not math.isfinite(threshold):
        raise PvedError(f"steps_to_reach needs a finite threshold, got {threshold}")
    reached = np.flatnonzero(curve.mean >= threshold)
    return int(curve.steps[reached[0]]) if reached.size else None


def steps_to_baseline_finals(
    curves: Sequence[Curve], baselines: Sequence[str]
) -> dict[str, dict[str, Any]]:
    """Per method of ``curves``, how fast it reaches each baseline's final performance.

    For each baseline among ``curves`` (e.g. plain PPO, the oracle) whose mean curve ends
    above its own first point, every method gets ``<baseline>_final`` (that last mean) and
    ``steps_to_<baseline>_final`` (:func:`steps_to_reach`; None: never reached). A baseline
    that ended at or below where it started learned nothing, and every method would
    "reach" it at its first evaluation: the methods get ``<baseline>_improved: False``
    instead, and no step count."""
    out: dict[str, dict[str, Any]] = {c.method: {} for c in curves}
    for name in baselines:
        base = next((c for c in curves if c.method == name), None)
        if base is None:
            continue
        final = float(base.mean[-1])
        improved = final > float(base.mean[0])
        for curve in curves:
            if improved:
                out[curve.method][f"{name}_final"] = final
                out[curve.method][f"steps_to_{name}_final"] = steps_to_reach(curve, final)
            else:
                out[curve.method][f"{name}_improved"] = False
    return out


def reach_cell(method_summary: Mapping[str, Any], baseline: str) -> str:
    """A summary table's cell for the steps to ``baseline``'s final performance, from a
    method's entry in ``summary.json`` (:func:`steps_to_baseline_finals`' keys)."""
    if method_summary.get(f"{baseline}_improved") is False:
        return f"– ({baseline} did not improve)"
    if f"{baseline}_final" not in method_summary:
        return "–"
    steps = method_summary.get(f"steps_to_{baseline}_final")
    return "not reached" if steps is None else f"{steps:,}"


def read_eval_points(metrics_path: Path, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values) of the records in ``metrics.jsonl`` that carry ``key``, by step
    (:func:`eval_points`)."""
    lines = Path(metrics_path).read_text().splitlines()
    return eval_points((json.loads(line) for line in lines if line.strip()), key)


def eval_points(records: Iterable[Mapping[str, Any]], key: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values) of the ``records`` (``metrics.jsonl``'s rows, or a committed
    record's ``curve``) that carry ``key``, by step.

    A step logged twice keeps its last record: runs resumed by pved before 0de3764 logged
    the steps they redid again (``Run.drop_metrics_after`` prevents it now)."""
    last: dict[int, float] = {}
    for record in records:
        if record.get(key) is not None:
            last[int(record["step"])] = float(record[key])
    steps = sorted(last)
    return np.asarray(steps, dtype=np.int64), np.asarray([last[s] for s in steps], np.float64)


SHAPING_KEY = "rollout/reward_shaping"
"""The Eq. 10 term, −β·D per step, averaged over a PPO rollout (logged by transfer runs)."""
ENV_REWARD_KEY = "rollout/env_reward"
"""The env's own reward per step, averaged over a PPO rollout."""


def reward_scale(
    run_dirs: Sequence[Path], last_share: float = 0.0
) -> dict[str, float | int] | None:
    """How large the shaping term is against the env's reward, at the start and the end of
    training: each run's first and last logged rollout means of :data:`SHAPING_KEY` and
    :data:`ENV_REWARD_KEY`, averaged over ``run_dirs``. With ``last_share`` > 0 a run's
    "last" is the mean over its last ``last_share`` of rollouts (at least one), where one
    rollout is too noisy to say what the policy settled on.

    Returns ``{"shaping_first", "shaping_last", "env_reward_first", "env_reward_last",
    "runs"}`` (``runs``: how many runs logged both), or None when none did: plain PPO and
    the oracle have no shaping term, and a run restored from an archive keeps only its
    evaluation rows."""
    if not 0.0 <= last_share <= 1.0:
        raise PvedError(f"last_share must be in [0, 1], got {last_share}")
    first: list[tuple[float, float]] = []
    last: list[tuple[float, float]] = []
    for run_dir in run_dirs:
        metrics = Path(run_dir) / "metrics.jsonl"
        if not metrics.exists():
            continue
        shaping = read_eval_points(metrics, SHAPING_KEY)[1]
        env_reward = read_eval_points(metrics, ENV_REWARD_KEY)[1]
        if len(shaping) == 0 or len(shaping) != len(env_reward):
            continue
        first.append((shaping[0], env_reward[0]))
        # the guard: a product such as 0.29 * 100 is 28.999999999999996, not 29
        n = max(1, int(len(shaping) * last_share + 1e-9))
        last.append((float(shaping[-n:].mean()), float(env_reward[-n:].mean())))
    if not first:
        return None
    start, end = np.mean(first, axis=0), np.mean(last, axis=0)
    return {
        "shaping_first": float(start[0]),
        "shaping_last": float(end[0]),
        "env_reward_first": float(start[1]),
        "env_reward_last": float(end[1]),
        "runs": len(first),
    }


def load_curve(method: str, run_dirs: list[Path], seeds: list[int], key: str) -> Curve:
    """Stack the evaluation points of several seeds' runs (same schedule) into a curve."""
    series = [read_eval_points(d / "metrics.jsonl", key) for d in run_dirs]
    if not series or any(len(s[0]) == 0 for s in series):
        raise PvedError(f"no {key!r} evaluation points in the runs of {method}")
    n = min(len(s[0]) for s in series)
    steps = series[0][0][:n]
    values = np.stack([s[1][:n] for s in series])
    return Curve(method, steps, values, list(seeds))


@dataclass
class Panel:
    """One subplot of a curves figure (e.g. one source-target pair). ``bounds``: the
    metric's range (e.g. (0, 1) for a success rate); bands are clipped to it."""

    title: str
    ylabel: str
    curves: list[Curve]
    bounds: tuple[float, float] | None = None


def _run_counts(counts: set[int]) -> str:
    """Legend text for a method's run counts over panels: ``n=5``, or ``n=3-5`` if they differ."""
    lo, hi = min(counts), max(counts)
    return f"n={lo}" if lo == hi else f"n={lo}-{hi}"


def panels_figure(panels: list[Panel], reps: int = ONE_LEVEL_REPS) -> Figure:
    """The paper's Fig. 3 layout as a matplotlib Figure (not saved, not closed): one subplot
    per panel side by side (two rows if there are more than 3), x = environment steps; per
    method its mean over runs, a shaded 95% bootstrap band of the mean (``reps`` resamples,
    clipped to the panel's bounds) and each run faintly; one colour per method name in every
    panel; one shared legend with each method's run count. Returns the figure; its
    ``axes`` are exactly the panels' subplots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not panels:
        raise PvedError("plot_panels needs at least one panel")
    methods: list[str] = []
    counts: dict[str, set[int]] = {}
    for panel in panels:
        for curve in panel.curves:
            if curve.method not in counts:
                methods.append(curve.method)
                counts[curve.method] = set()
            counts[curve.method].add(int(curve.values.shape[0]))
    # Colours are fixed by the order methods first appear, so a method keeps its colour in
    # every panel even where another method is missing.
    palette = matplotlib.colormaps["tab10"]
    colour = {m: palette(i % palette.N) for i, m in enumerate(methods)}

    rows = 1 if len(panels) <= 3 else 2
    cols = math.ceil(len(panels) / rows)
    fig, grid = plt.subplots(
        rows,
        cols,
        figsize=(4.6 * cols, 3.6 * rows + 0.6),
        dpi=120,
        squeeze=False,
        layout="constrained",
    )
    axes = list(grid.flat)
    for ax in axes[len(panels) :]:
        fig.delaxes(ax)  # the odd empty cell when wrapping to two rows
    handles: dict[str, Any] = {}  # method -> its mean line, for the shared legend
    for ax, panel in zip(axes, panels, strict=False):
        for curve in panel.curves:
            c = colour[curve.method]
            low, high = curve.band(reps=reps)
            if panel.bounds is not None:
                # The bootstrap of a mean stays within the data's range, but clip anyway so
                # a band never draws outside a bounded metric's range.
                low, high = np.clip(low, *panel.bounds), np.clip(high, *panel.bounds)
            for run_values in curve.values:
                ax.plot(curve.steps, run_values, color=c, alpha=0.25, lw=0.7)
            ax.fill_between(curve.steps, low, high, color=c, alpha=0.2, lw=0)
            (handles[curve.method],) = ax.plot(curve.steps, curve.mean, color=c, lw=1.6)
        if panel.bounds is not None:
            margin = 0.03 * (panel.bounds[1] - panel.bounds[0])
            ax.set_ylim(panel.bounds[0] - margin, panel.bounds[1] + margin)
        ax.set_xlabel("environment steps")
        ax.set_ylabel(panel.ylabel)
        ax.set_title(panel.title)
        ax.grid(alpha=0.3)
    if methods:
        fig.legend(
            [handles[m] for m in methods],
            [f"{m} ({_run_counts(counts[m])})" for m in methods],
            loc="outside lower center",
            # about two entries per panel width, so the legend wraps rather than
            # running past the figure's edges (8 methods under one panel)
            ncol=max(1, min(len(methods), 2 * cols)),
            frameon=False,
        )
    return fig


def plot_panels(panels: list[Panel], path: Path, reps: int = ONE_LEVEL_REPS) -> Path:
    """Draw ``panels`` as in :func:`panels_figure` and save the PNG atomically (readers see
    the old file or the whole new one). Returns ``path``."""
    fig = panels_figure(panels, reps=reps)  # first: it selects the Agg backend
    import matplotlib.pyplot as plt

    # Imported here: pved.runs imports torch, which plotting alone does not otherwise need.
    from pved.runs import atomic_write_bytes

    buffer = io.BytesIO()
    try:
        fig.savefig(buffer, format="png", bbox_inches="tight")  # nothing clipped
    finally:
        plt.close(fig)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def plot_curves(
    curves: list[Curve],
    path: Path,
    ylabel: str,
    title: str,
    bounds: tuple[float, float] | None = None,
) -> Path:
    """One-panel :func:`plot_panels`: mean and 95% bootstrap band per method over env steps,
    each run faintly behind it, saved as PNG. Returns ``path``."""
    return plot_panels([Panel(title, ylabel, curves, bounds)], path)
