"""How large a difference a count of runs can decide (issue 64: "say the power").

Two answers, of which the second is the one the verdicts keep.

**Independent runs** (:func:`detectable`): for a method against PPO with ``n`` runs each,
the smallest true difference of mean scores that a two-sided test at level α finds with
probability 0.8 is, in the normal approximation with per-run standard deviation σ,

    δ = (z_{1−α/2} + z_{0.8}) · σ · √(2 / n)

(e.g. Cohen 1988, ch. 2). It treats the ``n`` runs as independent, which a shaped
method's are not: they come from a few source policies, and the verdicts ("ahead",
"behind", "beats") are the two-level bootstrap's (:mod:`pved.analysis.bootstrap`), which
resamples the source policies first. With 3 sources all three draws are the worst one in
1/27 = 3.7% of the resamples, more than the 2.5% tail of a 95% interval (and far more
than Holm's first step over four pairs, 0.625%), so the interval's lower end sits near
the worst source's gap to PPO, and more seeds per source barely move it. This δ is
printed only beside the next one, to show by how much it overstates.

**The verdicts' own procedure** (:func:`two_level_detectable`, :func:`two_level_power`):
a simulation. From a pilot record (:func:`pilot`: one shaped method's runs on a pair,
``k₀`` source policies × ``m₀`` seeds, and PPO's runs) it estimates a one-way
random-effects model: a run of the method scores ``μ + δ + u_source + e_run`` with
``u ~ N(0, τ²)`` between sources and ``e ~ N(0, σ_w²)`` within (τ² by the ANOVA moment
estimator, var(source means) − σ_w²/m₀, clipped at 0; σ_w² pooled within sources), and a
PPO run scores ``μ + e`` with ``e ~ N(0, σ_ppo²)`` (σ_ppo over the ``ppo`` and ``ppo-aa``
runs). For ``k`` sources × ``m`` seeds (PPO: ``k·m`` runs on seeds of their own, as the
protocols run it) it draws ``datasets`` data sets at δ = 0 and applies the judge's test to
each: :func:`pved.analysis.bootstrap.bootstrap_difference` (sources and seeds labelled as
the judge labels them) and "ahead at level α" when its two-sided p-value of the bar is at
most α on the low side, 2·P(d* ≤ −δ) ≤ α. At α = 0.05 this is the 95% interval lying
above 0 (up to one of the ``reps`` order statistics); at α/4 it is Holm's first step over
four pairs (``pved claims``' family-wise view). Because a shift δ of every method run
shifts every resampled difference by δ, one bootstrap of a null data set gives, for every
δ at once, whether it would be called ahead: its *critical effect*, the smallest δ that
is, found on a grid of bars. The detectable δ is the ``power`` quantile of the critical
effects, the power at δ the share of them at or below it. The share at or below 0 is how
often a method no better than PPO is called ahead: α/2 for an exact interval, more at 3
sources that differ (a resample of k sources has (k−1)/k of their spread: too narrow).

What the simulation leaves out: τ from 3 sources has 2 degrees of freedom (the true τ
may be half the pilot's or several times it), and the δ at 3 sources hinges on it; a
source whose seeds scatter far (one run far out) inflates σ_w and hides τ; a seed effect
shared by a seed's runs under every source is folded into σ_w (the bootstrap draws
seeds, so such an effect would widen the intervals further); the scores are normal here,
where a success rate's area or final is bounded in [0, 1] and often bimodal per run; a
method that helps is a pure shift (its τ and σ_w unchanged); and the source draws of one
``k`` come from one stream in every data set (the bootstrap fixes them by the source
labels, as it does for the judge).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from pved.analysis.bootstrap import bootstrap_difference
from pved.analysis.judge import PairSummary, run_scores, run_sources
from pved.errors import PvedError

POWER = 0.8
"""The probability of finding a true difference that the tables' δ are for."""
ALPHA = 0.05
"""The two-sided level of one comparison; Holm's first step over four pairs is ALPHA/4."""
ALPHAS = (ALPHA, ALPHA / 4)
"""The levels every table reports: one pair, and Holm's first step over four."""
REFERENCES = ("ppo", "ppo-aa")
"""The runs whose spread is the noise a comparison with PPO must overcome."""
RUNS = 45
"""A method's runs at the paper-45 budget (3 sources × 15 seeds), and PPO's."""
SOURCES = (3, 5, 9)
"""Source policies to split :data:`RUNS` among: the protocols' 3, and more with fewer seeds."""
DATASETS = 200
"""Simulated data sets per design: the detectable δ's Monte Carlo error is a few percent."""
SIM_REPS = 2000
"""Resamples of each simulated data set's bootstrap (the published intervals take
:data:`pved.analysis.bootstrap.REPS`; a power estimate averages over data sets)."""
SIM_SEED = 0
"""Seed of the simulated data sets (the bootstrap's own seed stays the project's)."""
_GRID = 33
"""Bars per pass of the critical-effect search (two passes: a resolution of span/512; odd,
so that the first pass tests δ = 0 itself and the share called ahead at 0 is exact)."""


def detectable(sd: float, runs: int, alpha: float = ALPHA, power: float = POWER) -> float:
    """(z_{1−α/2} + z_power) · ``sd`` · √(2/``runs``): the smallest true difference of
    two means of ``runs`` runs each, per-run SD ``sd``, that a two-sided test at level
    ``alpha`` finds with probability ``power`` (normal approximation, runs independent:
    not what the two-level verdicts decide, see :func:`two_level_detectable`)."""
    if runs < 1 or not sd >= 0 or not 0 < alpha < 1 or not 0 < power < 1:
        raise PvedError(f"detectable: bad arguments sd={sd}, runs={runs}, α={alpha}, power={power}")
    z = NormalDist().inv_cdf
    return (z(1 - alpha / 2) + z(power)) * sd * math.sqrt(2.0 / runs)


def reference_spread(pairs: dict[str, PairSummary], pair: str, score: str) -> tuple[float, int]:
    """PPO's per-run standard deviation (ddof 1) of ``score`` (``final`` or ``auc``) on
    ``pair`` over its ``ppo`` and ``ppo-aa`` runs, and how many runs it is taken over."""
    values: list[np.ndarray] = []
    for method in REFERENCES:
        if method in pairs[pair].methods:
            got = run_scores(pairs, pair, method, score)
            if isinstance(got, str):
                raise PvedError(f"{pair}: {got}")
            values.append(got)
    if not values:
        raise PvedError(f"{pair}: no ppo runs to take the spread of")
    every = np.concatenate(values)
    if len(every) < 2:
        raise PvedError(f"{pair}: one ppo run has no spread")
    return float(np.std(every, ddof=1)), len(every)


@dataclass(frozen=True)
class Pilot:
    """The spreads a simulation draws from (module docstring): ``between`` (τ, the SD of
    the source effects), ``within`` (σ_w, a run's SD about its source's mean), ``ppo``
    (σ_ppo, a PPO run's SD); the pilot's design and each source's mean, to print."""

    between: float
    within: float
    ppo: float
    sources: int = 0
    seeds: int = 0
    source_means: tuple[float, ...] = ()


def pilot(pairs: dict[str, PairSummary], pair: str, method: str, score: str) -> Pilot:
    """:class:`Pilot` of shaped ``method``'s ``score`` on ``pair`` (its runs grouped by
    source policy, :func:`pved.analysis.judge.run_sources`) and PPO's
    (:func:`reference_spread`). PvedError for a method without source labels, with fewer
    than 2 sources, or a source with fewer than 2 runs."""
    x = run_scores(pairs, pair, method, score)
    if isinstance(x, str):
        raise PvedError(f"{pair}: {x}")
    labels = run_sources(pairs, pair, method)
    if labels is None:
        raise PvedError(f"{pair}: {method}'s runs name no source policy (not a shaped method)")
    src = np.asarray(labels)
    groups = [x[src == s] for s in np.unique(src)]
    if len(groups) < 2 or min(len(g) for g in groups) < 2:
        sizes = [len(g) for g in groups]
        raise PvedError(f"{pair}: {method} needs >= 2 sources of >= 2 runs each, has {sizes}")
    means = np.asarray([g.mean() for g in groups])
    within = sum(float(((g - g.mean()) ** 2).sum()) for g in groups)
    within_var = within / sum(len(g) - 1 for g in groups)
    seeds = len(x) / len(groups)
    between_var = max(0.0, float(np.var(means, ddof=1)) - within_var / seeds)
    return Pilot(
        between=math.sqrt(between_var),
        within=math.sqrt(within_var),
        ppo=reference_spread(pairs, pair, score)[0],
        sources=len(groups),
        seeds=round(seeds),
        source_means=tuple(float(m) for m in means),
    )


def _check_design(p: Pilot, sources: int, seeds: int, datasets: int, reps: int) -> None:
    if sources < 2 or seeds < 1 or datasets < 1 or reps < 1:
        raise PvedError(
            f"power: bad design sources={sources}, seeds={seeds}, datasets={datasets}, "
            f"reps={reps} (the two-level bootstrap needs >= 2 sources)"
        )
    if min(p.between, p.within, p.ppo) < 0 or not p.within + p.ppo > 0:
        raise PvedError(f"power: bad pilot spreads {p}")


def _low_tails(
    shaped: np.ndarray, ppo: np.ndarray, sources: int, effects: np.ndarray, reps: int
) -> np.ndarray:
    """Per shift δ in ``effects``, 2·P(d* <= −δ) in the judge's bootstrap of null data
    ``shaped`` (``sources`` × seeds, source-major) − ``ppo``: the shifted method's
    two-sided p-value where it is ahead (its resampled differences are the null's + δ)."""
    seeds = shaped.size // sources
    tests = bootstrap_difference(
        shaped,
        ppo,
        reps=reps,
        seeds_a=np.tile(np.arange(seeds), sources).tolist(),
        sources_a=np.repeat(np.arange(sources), seeds).tolist(),
        seeds_b=list(range(ppo.size)),
        bars=tuple(float(-e) for e in effects),
        labels=("method", "ppo"),
    )["tests"]
    return np.asarray([2.0 * t["le"] for t in tests])


def critical_effects(
    p: Pilot,
    sources: int,
    seeds: int,
    alphas: Sequence[float] = ALPHAS,
    datasets: int = DATASETS,
    reps: int = SIM_REPS,
    seed: int = SIM_SEED,
) -> dict[float, np.ndarray]:
    """Per level α in ``alphas``, (datasets,): each simulated null data set's critical
    effect, the smallest shift of the method's runs that the judge's test would call
    ahead of PPO at α (module docstring); ``inf`` where none up to the search's span
    (four times σ_ppo + τ + σ_w) would."""
    _check_design(p, sources, seeds, datasets, reps)
    rng = np.random.default_rng([seed, sources, seeds])
    span = 4.0 * (p.ppo + p.between + p.within)
    out = {a: np.empty(datasets) for a in alphas}
    for d in range(datasets):
        shaped = np.repeat(rng.normal(0.0, p.between, sources), seeds)
        shaped += rng.normal(0.0, p.within, sources * seeds)
        ppo = rng.normal(0.0, p.ppo, sources * seeds)
        coarse = np.linspace(-span, span, _GRID)
        low = _low_tails(shaped, ppo, sources, coarse, reps)
        first = {a: np.flatnonzero(low <= a) for a in alphas}
        # one more bootstrap call refines every level's bracket (its draws are cached)
        refine = [a for a in alphas if first[a].size and first[a][0] > 0]
        fines = [np.linspace(coarse[first[a][0] - 1], coarse[first[a][0]], _GRID) for a in refine]
        lows = _low_tails(shaped, ppo, sources, np.concatenate(fines), reps) if fines else low
        for a in alphas:
            if not first[a].size:
                out[a][d] = math.inf
            elif a not in refine:
                out[a][d] = coarse[0]
            else:
                j = refine.index(a)
                fine_low = lows[j * _GRID : (j + 1) * _GRID]
                out[a][d] = fines[j][int(np.flatnonzero(fine_low <= a)[0])]
    return out


def two_level_detectable(
    p: Pilot,
    sources: int,
    seeds: int,
    alpha: float = ALPHA,
    power: float = POWER,
    datasets: int = DATASETS,
    reps: int = SIM_REPS,
    seed: int = SIM_SEED,
) -> float:
    """The smallest true gain over PPO that the judge's two-level test at ``alpha`` calls
    ahead with probability ``power``, for ``sources`` × ``seeds`` runs of the method and
    as many of PPO, by simulation from pilot ``p`` (module docstring); inf beyond the
    search's span."""
    crit = critical_effects(p, sources, seeds, (alpha,), datasets, reps, seed)[alpha]
    return float(np.quantile(crit, power, method="higher"))


def two_level_power(
    p: Pilot,
    sources: int,
    seeds: int,
    effects: Sequence[float],
    alpha: float = ALPHA,
    datasets: int = DATASETS,
    reps: int = SIM_REPS,
    seed: int = SIM_SEED,
) -> list[float]:
    """Per true gain in ``effects``, the probability that the judge's two-level test at
    ``alpha`` calls the method ahead of PPO, for ``sources`` × ``seeds`` runs of it and as
    many of PPO, by simulation from pilot ``p``."""
    crit = critical_effects(p, sources, seeds, (alpha,), datasets, reps, seed)[alpha]
    return [float(np.mean(crit <= e)) for e in effects]


def shaped_methods(pairs: dict[str, PairSummary], pair: str) -> list[str]:
    """The methods on ``pair`` whose runs name their source policies."""
    return [m for m in pairs[pair].methods if run_sources(pairs, pair, m) is not None]


def power_rows(
    pairs: dict[str, PairSummary],
    runs: int = RUNS,
    sources: Sequence[int] = SOURCES,
    methods: Sequence[str] | None = None,
    datasets: int = DATASETS,
    reps: int = SIM_REPS,
    seed: int = SIM_SEED,
) -> list[dict[str, Any]]:
    """One row per pair, shaped method (``methods``, default every one on the pair) and
    score (final, auc): its :class:`Pilot`, the independent-runs δ at ``runs`` (PPO's σ,
    at α and α/4) and, per count of ``sources`` (``runs`` split evenly among them), the
    two-level detectable δ at α and α/4 (``{k: (δ_α, δ_α/4)}``) and the share of null data
    sets called ahead at α (``false_ahead``, ``{k: share}``). PvedError where a count
    does not divide ``runs`` or a named method has no runs on a pair."""
    if runs < 1 or any(k < 2 or runs % k for k in sources):
        raise PvedError(f"power: {runs} runs do not split evenly among {list(sources)} sources")
    rows = []
    for pair, summary in pairs.items():
        chosen = shaped_methods(pairs, pair) if methods is None else list(methods)
        for method in chosen:
            if method not in summary.methods:
                raise PvedError(f"{pair}: no runs of {method}")
            for score in ("final", "auc"):
                p = pilot(pairs, pair, method, score)
                two_level, size = {}, {}
                for k in sources:
                    crit = critical_effects(p, k, runs // k, ALPHAS, datasets, reps, seed)
                    two_level[k] = tuple(
                        float(np.quantile(crit[a], POWER, method="higher")) for a in ALPHAS
                    )
                    size[k] = float(np.mean(crit[ALPHA] <= 0.0))
                rows.append(
                    {
                        "pair": pair,
                        "metric": summary.metric,
                        "method": method,
                        "score": score,
                        "pilot": p,
                        "runs": runs,
                        "independent": tuple(detectable(p.ppo, runs, a) for a in ALPHAS),
                        "two_level": two_level,
                        "false_ahead": size,
                    }
                )
    return rows


def _delta(x: float) -> str:
    return "none" if math.isinf(x) else f"{x:.3f}" if abs(x) < 10 else f"{x:.1f}"


def power_table(rows: Sequence[dict[str, Any]]) -> str:
    """:func:`power_rows` as a markdown table: δ at 80% power, α 0.05 / α 0.0125, and in
    brackets how often a method no better than PPO is called ahead at α 0.05 (2.5% if the
    interval were exact; more where few sources make it too narrow)."""
    counts = list(rows[0]["two_level"]) if rows else []
    runs = rows[0]["runs"] if rows else RUNS
    header = [
        "pair (metric)",
        "method",
        "score",
        "pilot source means",
        "SD: between / within / PPO",
    ]
    header += [f"δ, {runs} runs as if independent"]
    header += [f"δ, {k} sources × {runs // k} seeds" for k in counts]
    lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    for row in rows:
        p: Pilot = row["pilot"]
        cells = [
            f"{row['pair']} ({row['metric']})",
            row["method"],
            "area" if row["score"] == "auc" else "final",
            " / ".join(_delta(m) for m in p.source_means),
            " / ".join(_delta(s) for s in (p.between, p.within, p.ppo)),
            " / ".join(_delta(d) for d in row["independent"]),
        ]
        cells += [
            " / ".join(_delta(d) for d in row["two_level"][k])
            + f" ({100 * row['false_ahead'][k]:.1f}%)"
            for k in counts
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


__all__ = [
    "ALPHA",
    "ALPHAS",
    "DATASETS",
    "POWER",
    "REFERENCES",
    "RUNS",
    "SIM_REPS",
    "SIM_SEED",
    "SOURCES",
    "Pilot",
    "critical_effects",
    "detectable",
    "pilot",
    "power_rows",
    "power_table",
    "reference_spread",
    "shaped_methods",
    "two_level_detectable",
    "two_level_power",
]
