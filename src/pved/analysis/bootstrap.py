"""The project's one interval method for comparing and summarising methods: the 95%
percentile two-level bootstrap over the source policies and PPO seeds the runs were made
with, :data:`REPS` resamples, seed :data:`SEED`, of one method's mean
(:func:`bootstrap_mean`) and of the difference between two (:func:`bootstrap_difference`;
``pved claims``, ``pved compare``, ``pved scoreboard``, ``pved publish``). A method's
resamples come from streams of its own, so its interval is the same in every table and
comparison, and is the one its differences are made of."""

from __future__ import annotations

import hashlib
from collections.abc import Hashable, Sequence
from typing import Any

import numpy as np

from pved.errors import PvedError

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


def finite(values: np.ndarray, what: str) -> np.ndarray:
    """``values`` as float64, or a PvedError if it is empty or holds NaN/inf."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        raise PvedError(f"{what}: no values to summarise")
    if not np.all(np.isfinite(values)):
        bad = int(np.size(values) - np.count_nonzero(np.isfinite(values)))
        raise PvedError(f"{what}: {bad} of {values.size} values are NaN or infinite")
    return values


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
    x = finite(values, "bootstrap_mean")
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
    values = {"a": finite(a, "bootstrap_difference"), "b": finite(b, "bootstrap_difference")}
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
