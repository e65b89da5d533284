"""Learning curves over environment steps and the project's confidence intervals, all 95%
percentile bootstraps. One method compares and summarises methods: the two-level bootstrap
over source policies and PPO seeds, :data:`REPS` resamples, seed :data:`SEED`, of one
method's mean (:func:`bootstrap_mean`) and of the difference between two methods
(:func:`bootstrap_difference`; ``pved claims``, ``pved compare``, ``pved scoreboard``,
``pved publish``). The one-level bootstrap over runs computed with rliable
(``rliable.library.get_interval_estimates``, as Agarwal et al. (2021) recommend for
few-run RL results) is kept only where that design has no place: the interquartile mean's
interval and the bands of the curve figures, both labelled one-level where printed."""

from __future__ import annotations

import hashlib
import io
import json
import math
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pved.errors import PvedError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

CI_SIZE = 0.95
"""Coverage of every interval this module reports."""
REPS = 1_000_000
"""Resamples of every two-level interval (:func:`bootstrap_mean`,
:func:`bootstrap_difference`), and so of every published one: enough that no published
verdict changes with the resampling's seed. ``benchmarks/interval_stability.py`` remade
the 310 verdicts of the generated tables under 20 seeds: 3 changed at 20,000 resamples, 1
at 200,000 (reacher's ``quick`` ``pved-align`` against PPO, p 0.05 on the edge), none at
500,000 or 1,000,000."""
SEED = 0
"""Seed of every two-level interval's resampling: a rerun gives the same bounds."""
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


def _finite(values: np.ndarray, what: str) -> np.ndarray:
    """``values`` as float64, or a PvedError if it is empty or holds NaN/inf."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        raise PvedError(f"{what}: no values to summarise")
    if not np.all(np.isfinite(values)):
        bad = int(np.size(values) - np.count_nonzero(np.isfinite(values)))
        raise PvedError(f"{what}: {bad} of {values.size} values are NaN or infinite")
    return values


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
    values = _finite(scores, "bootstrap_summary")
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


def _index(labels: Sequence[Hashable], order: Sequence[Hashable] | None = None) -> np.ndarray:
    """Each label's position in ``order`` (default: the labels in order of first
    appearance, so that singleton labels draw exactly as runs do)."""
    if order is None:
        order = list(dict.fromkeys(labels))
    where = {label: i for i, label in enumerate(order)}
    return np.asarray([where[label] for label in labels], dtype=np.int64)


def _cells(
    values: np.ndarray, seeds: np.ndarray, sources: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Per-(source, seed) cell sums and run counts, each ``shape`` (sources, seeds)."""
    flat = sources * shape[1] + seeds
    size = shape[0] * shape[1]
    sums = np.bincount(flat, weights=values, minlength=size).reshape(shape)
    counts = np.bincount(flat, minlength=size).astype(np.float64).reshape(shape)
    return sums, counts


def _picks(rng: np.random.Generator, k: int, reps: int) -> np.ndarray:
    """(reps, k): the indices of k draws with replacement from k units, per resample
    (uint8 where k allows: several times faster to draw and to gather with)."""
    return rng.integers(0, k, size=(reps, k), dtype=np.uint8 if k <= 255 else np.int64)


def _multiplicities(rng: np.random.Generator, k: int, reps: int) -> np.ndarray:
    """(reps, k): how often each of k units is drawn in a resample of k draws with
    replacement."""
    # one bincount over (resample, unit) cells: far faster than np.add.at at 10^5 resamples
    flat = (np.arange(reps, dtype=np.int64)[:, None] * k + _picks(rng, k, reps)).ravel()
    return np.bincount(flat, minlength=reps * k).reshape(reps, k).astype(np.float64)


def _stream(seed: int, *key: object) -> np.random.Generator:
    """A random stream fixed by ``seed`` and ``key`` (a stable digest, not Python's
    per-process hash): the same key draws the same resamples in every call and process."""
    digest = hashlib.blake2b(repr(key).encode(), digest_size=8).digest()
    return np.random.default_rng([seed, int.from_bytes(digest, "little")])


def _order(labels: Sequence[Hashable]) -> list[Hashable]:
    """The distinct labels in a fixed order (by repr, so that mixed types sort)."""
    return sorted(set(labels), key=repr)


def _drawn_sums(table: np.ndarray, weights: np.ndarray | None, picks: np.ndarray) -> np.ndarray:
    """(reps,): per resample, the sum over its drawn seeds (``picks``, (reps, m)) of the
    drawn sources' cells, ``table`` (k, m) weighted by ``weights`` (reps, k; None: one
    source). In blocks of rows, and a 1-D gather per source: several times faster than
    a gather over a (reps, m) matrix, which leaves the CPU's cache."""
    out = np.empty(picks.shape[0])
    for start in range(0, picks.shape[0], 1 << 16):
        block = picks[start : start + (1 << 16)]
        if weights is None:
            out[start : start + len(block)] = table[0][block].sum(axis=1)
            continue
        acc = np.zeros(len(block))
        for i in range(table.shape[0]):
            acc += weights[start : start + len(block), i] * table[i][block].sum(axis=1)
        out[start : start + len(block)] = acc
    return out


_CACHE: dict[tuple[Any, ...], tuple[np.ndarray, list[float]]] = {}
_CACHE_SIZE = 64
"""A group's resampled means are kept for its next comparison (a judgement compares one
method many times; at 10^6 resamples an entry is 8 MB, and the oldest goes first)."""


def _group_draws(
    x: np.ndarray,
    seeds: Sequence[Hashable] | None,
    sources: Sequence[Hashable] | None,
    reps: int,
    seed: int,
    label: Hashable = None,
) -> tuple[np.ndarray, list[float]]:
    """(reps,): a group's mean in each resample of the two-level bootstrap (NaN where a
    resample drew only empty cells), and its 95% interval. Its sources are drawn from a
    stream fixed by the set of source labels (so groups with the same sources share the
    draw) and its seeds from one fixed by the group's runs and ``label`` (so its draws are
    its own, whatever it is compared with)."""
    seed_labels: Sequence[Hashable] = seeds or list(range(x.size))
    runs = (x.tobytes(), tuple(map(repr, seed_labels)), tuple(map(repr, sources or ())))
    key = (*runs, repr(label), reps, seed)
    if key in _CACHE:
        return _CACHE[key]
    if sources is None:
        weights, src_index = np.ones((reps, 1)), np.zeros(x.size, dtype=np.int64)
    else:
        order = _order(sources)
        source_rng = _stream(seed, "sources", tuple(map(repr, order)))
        weights, src_index = _multiplicities(source_rng, len(order), reps), _index(sources, order)
    seed_order = list(dict.fromkeys(seed_labels))
    shape = (weights.shape[1], len(seed_order))
    sums, counts = _cells(x, _index(seed_labels, seed_order), src_index, shape)
    picks = _picks(_stream(seed, "seeds", *runs, repr(label)), shape[1], reps)  # by index
    drawn = None if sources is None else weights
    total = _drawn_sums(sums, drawn, picks)
    if np.all(counts == counts[0, 0]):  # every cell alike: k x m cells drawn, c runs each
        n = np.full(reps, counts[0, 0] * shape[0] * shape[1], dtype=np.float64)
    else:
        n = _drawn_sums(counts, drawn, picks)
    with np.errstate(invalid="ignore", divide="ignore"):
        draws = np.asarray(total / n)
    draws.flags.writeable = False  # shared by every comparison of the group
    if len(_CACHE) >= _CACHE_SIZE:
        del _CACHE[next(iter(_CACHE))]
    _CACHE[key] = (draws, _percentile_ci(draws))
    return _CACHE[key]


def _check_labels(
    x: np.ndarray,
    seeds: Sequence[Hashable] | None,
    sources: Sequence[Hashable] | None,
    what: str,
) -> None:
    """PvedError for non-1-D scores or labels that do not match the runs."""
    if x.ndim != 1:
        raise PvedError(f"{what} wants 1-D run scores, got {x.shape}")
    for kind, labels in (("seed", seeds), ("source", sources)):
        if labels is not None and len(labels) != x.size:
            raise PvedError(f"{len(labels)} {kind} labels for {x.size} runs")
    if sources is not None and seeds is None:
        raise PvedError("runs with source labels need seed labels (sources x seeds)")


def _percentile_ci(draws: np.ndarray) -> list[float]:
    """The central :data:`CI_SIZE` of the finite ``draws`` (the percentile method)."""
    tail = 100.0 * (1.0 - CI_SIZE) / 2.0
    lo, hi = np.percentile(draws[np.isfinite(draws)], [tail, 100.0 - tail])
    return [float(lo), float(hi)]


def bootstrap_mean(
    values: np.ndarray,
    seeds: Sequence[Hashable] | None = None,
    sources: Sequence[Hashable] | None = None,
    reps: int = REPS,
    seed: int = SEED,
    *,
    label: Hashable = None,
) -> dict[str, Any]:
    """One method's mean score with its 95% interval from the two-level bootstrap of
    :func:`bootstrap_difference` (the resamples draw the ``sources`` with replacement,
    then, independently, the ``seeds``, and take every run of each drawn (source, seed)
    cell; no sources: the seeds only; no seeds either: the runs). The interval a table
    prints beside a method, the same on every page and whatever it is compared with: the
    resamples are the ones the method's differences are made of.

    ``label``: the group's name (say its pair and method), so that two groups of equal
    scores draw apart; without one, equal runs draw alike.

    Returns ``{"runs", "seeds", "sources" (0: none), "mean", "mean_ci": [lo, hi]}``.
    Reproducible for a given ``seed``. Raises PvedError for empty, non-1-D or non-finite
    scores, labels that do not match the runs, sources without seeds, or ``reps`` < 1."""
    if reps < 1:
        raise PvedError(f"bootstrap needs reps >= 1, got {reps}")
    x = _finite(values, "bootstrap_mean")
    _check_labels(x, seeds, sources, "bootstrap_mean")
    _, ci = _group_draws(x, seeds, sources, reps, seed, label)
    return {
        "runs": int(x.size),
        "seeds": len(dict.fromkeys(seeds or range(x.size))),
        "sources": 0 if sources is None else len(set(sources)),
        "mean": float(x.mean()),
        "mean_ci": list(ci),
    }


def _tails(draws: np.ndarray, bar: float, tol: float) -> dict[str, float]:
    """The bootstrap p-values of ``bar`` from resampled statistics ``draws``: ``le`` =
    (1 + #{d* <= bar}) / (1 + reps), ``ge`` the same for d* >= bar (draws within ``tol``
    of the bar count on both sides), and the two-sided ``p`` = min(1, 2 min(le, ge))."""
    n = draws.size
    le = (1.0 + float(np.count_nonzero(draws <= bar + tol))) / (1.0 + n)
    ge = (1.0 + float(np.count_nonzero(draws >= bar - tol))) / (1.0 + n)
    return {"bar": float(bar), "le": le, "ge": ge, "p": min(1.0, 2.0 * min(le, ge))}


def bootstrap_difference(
    a: np.ndarray,
    b: np.ndarray,
    reps: int = REPS,
    seed: int = SEED,
    *,
    seeds_a: Sequence[Hashable] | None = None,
    seeds_b: Sequence[Hashable] | None = None,
    sources_a: Sequence[Hashable] | None = None,
    sources_b: Sequence[Hashable] | None = None,
    bars: Sequence[float] = (0.0,),
    group_bars: Sequence[float] = (),
    tol: float = 0.0,
    labels: tuple[Hashable, Hashable] = (None, None),
) -> dict[str, Any]:
    """The difference of means between two groups of runs, mean(a) − mean(b), with its 95%
    percentile bootstrap CI, bootstrap p-values against ``bars``, and each group's mean
    with its own CI from the same resamples: a two-level (hierarchical) bootstrap over the
    source policies and the PPO seeds the runs were made with. A group's resamples are its
    own (:func:`bootstrap_mean`'s): its CI here is the one it has alone, whatever it is
    compared with, and the difference's resamples are the two groups' own, subtracted.

    ``a`` (n_a,) and ``b`` (n_b,) are per-run scores (e.g. final success rates of two
    methods on one pair). ``seeds_a`` / ``seeds_b``: each run's PPO seed; ``sources_a`` /
    ``sources_b``: each run's source policy, or None for a group without one (plain PPO,
    the oracle). The design is crossed: a shaped method runs every evaluation seed once
    with every source policy, so each run is one (source, seed) cell. Each of the
    ``reps`` resamples of a group draws its k source policies with replacement and,
    independently, its m seeds with replacement, and takes every run of every drawn
    (source, seed) cell, as often as the cell was drawn (source draws times seed draws);
    the resample's statistic is the mean over those runs. A group without sources draws
    its seeds only: the runs of one seed are one unit (a cluster bootstrap), and unique
    seed labels, or None, give the plain run bootstrap. Drawing only seeds would make the
    interval conditional on the few source policies at hand, which differ a lot (on
    humanoid-ant PVED's three sources end at 5.5, 6.4 and 26.9 m); drawing runs apart
    would treat a seed's runs as independent, which they are not.

    What is paired. Sources: when both groups have sources with the same labels (two
    shaped methods of one protocol run with the same source policies), one source draw
    serves both, so a source that helps or hurts both methods alike moves both means
    together and does not widen the interval of their difference; otherwise each group
    draws its own. Seeds: never paired; each group draws its seeds from a stream of its
    own, fixed by its runs and its entry of ``labels`` (its name: without names, two
    groups of the very same runs draw alike and differ by 0 in every resample). Plain PPO
    and the oracle run seeds s, s+1, s+2 that no shaped run shares, and two shaped methods
    with the same seed share only its initial network before their rewards differ; with
    seed effects that correlate positively, independent draws make the interval wider,
    never narrower, than a paired draw.

    The interval holds the central 95% of the resampled differences (the percentile
    method, as rliable's). The p-value of a bar c is ``p`` = min(1, 2 min(P(d* <= c),
    P(d* >= c))) with P estimated as (1 + count) / (1 + reps), the usual +1 correction
    (so never below 2 / (reps + 1), 0.0010 at 2000 resamples); d* within ``tol`` of c
    counts on both sides. ``p`` < 0.05 matches, up to the percentile's interpolation, an
    interval that excludes c. ``le`` and ``ge`` are the one-sided parts (for equivalence
    tests). ``group_bars``: the same for each group's own mean.

    Returns ``{"diff": d, "diff_ci": [lo, hi], "tests": [{"bar", "le", "ge", "p"}...]
    (one per bar), "a": {"runs": n_a, "seeds": m, "sources": k (0: none), "mean": x,
    "mean_ci": [lo, hi], "tests": [...] (group_bars; only if given)}, "b": {...}}``. A
    group of one run contributes its value without spread. A resample that draws only
    empty cells (possible only where runs are missing) has no mean and is left out.
    Reproducible for a given ``seed``; numpy's global RNG is not touched. Raises PvedError
    for an empty, non-1-D or non-finite group, labels that do not match the runs, sources
    without seeds, or ``reps`` < 1.

    Why numpy rather than rliable: rliable has no two-level bootstrap, and its
    ``StratifiedIndependentBootstrap`` runs its resamples in a Python loop (~0.2 s a call,
    and judging the paper's claims needs dozens of intervals); this draws all resamples at
    once (from ``np.random.default_rng`` streams fixed by ``seed`` and each group's source
    labels and runs), with the same percentile rule."""
    if reps < 1:
        raise PvedError(f"bootstrap needs reps >= 1, got {reps}")
    values = {"a": _finite(a, "bootstrap_difference"), "b": _finite(b, "bootstrap_difference")}
    seeds = {"a": seeds_a, "b": seeds_b}
    sources = {"a": sources_a, "b": sources_b}
    for name, x in values.items():
        _check_labels(x, seeds[name], sources[name], "bootstrap_difference")
    result: dict[str, Any] = {}
    resampled: dict[str, np.ndarray] = {}
    for name, x in values.items():
        label = labels[0 if name == "a" else 1]
        resampled[name], ci = _group_draws(x, seeds[name], sources[name], reps, seed, label)
        result[name] = {
            "runs": int(x.size),
            "seeds": len(dict.fromkeys(seeds[name] or range(x.size))),
            "sources": 0 if sources[name] is None else len(set(sources[name] or ())),
            "mean": float(x.mean()),
            "mean_ci": list(ci),
        }
        if group_bars:
            draws = resampled[name][np.isfinite(resampled[name])]
            result[name]["tests"] = [_tails(draws, c, tol) for c in group_bars]
    diffs = resampled["a"] - resampled["b"]
    diffs = diffs[np.isfinite(diffs)]
    result["diff"] = float(values["a"].mean() - values["b"].mean())
    result["diff_ci"] = _percentile_ci(diffs)
    result["tests"] = [_tails(diffs, c, tol) for c in bars]
    return result


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
        values = _finite(self.values, f"curve of {self.method}")
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
