"""How large a difference a count of runs can decide (issue 64: "say the power").

For a method against PPO with ``n`` runs each, the smallest true difference of mean
scores that a two-sided test at level α finds with probability 0.8 is, in the normal
approximation with the per-run standard deviation σ of both groups,

    δ = (z_{1−α/2} + z_{0.8}) · σ · √(2 / n)

(e.g. Cohen 1988, ch. 2). σ is PPO's per-run standard deviation on the pair (its
``ppo`` runs and, where the protocol has them, its ``ppo-aa`` runs: the same algorithm
on other seeds), for the final score and for the normalised area under the curve. Two
levels of α: 0.05, and 0.05/4, Holm's first step over four pairs (the strictest any
pair meets). What it leaves out: a method's σ may differ from PPO's; the two-level
bootstrap over source policies widens an interval where sources differ, so a δ here is
a lower bound for a shaped method; for a success rate that ends near 0 or 1 per run, σ
grows towards 0.5 as the mean moves to 0.5, so a δ at a mean near 0 or 1 understates
what is needed between them (``worst``: σ = 0.5).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from statistics import NormalDist
from typing import Any

import numpy as np

from pved.analysis.judge import PairSummary, run_scores
from pved.errors import PvedError

POWER = 0.8
"""The probability of finding a true difference that the tables' δ are for."""
ALPHA = 0.05
"""The two-sided level of one comparison; Holm's first step over four pairs is ALPHA/4."""
REFERENCES = ("ppo", "ppo-aa")
"""The runs whose spread is the noise a comparison with PPO must overcome."""


def detectable(sd: float, runs: int, alpha: float = ALPHA, power: float = POWER) -> float:
    """(z_{1−α/2} + z_power) · ``sd`` · √(2/``runs``): the smallest true difference of
    two means of ``runs`` runs each, per-run SD ``sd``, that a two-sided test at level
    ``alpha`` finds with probability ``power`` (normal approximation)."""
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


def power_rows(
    pairs: dict[str, PairSummary], runs: Sequence[int] = (15, 45, 81)
) -> list[dict[str, Any]]:
    """One row per pair and score (final, auc): PPO's σ, its runs, and δ for each count
    in ``runs`` at α and at α/4 (and, for a success rate, with the worst σ, 0.5)."""
    rows = []
    for pair, summary in pairs.items():
        for score in ("final", "auc"):
            sd, count = reference_spread(pairs, pair, score)
            row: dict[str, Any] = {
                "pair": pair,
                "metric": summary.metric,
                "score": score,
                "sd": sd,
                "reference_runs": count,
                "detectable": {n: detectable(sd, n) for n in runs},
                "detectable_holm": {n: detectable(sd, n, ALPHA / 4) for n in runs},
            }
            if summary.metric == "success_rate":
                row["detectable_worst"] = {n: detectable(0.5, n) for n in runs}
            rows.append(row)
    return rows


def power_table(rows: Sequence[dict[str, Any]]) -> str:
    """:func:`power_rows` as a markdown table."""
    counts = list(rows[0]["detectable"]) if rows else []
    header = ["pair (metric)", "score", "PPO runs", "per-run SD"]
    header += [f"δ at {n} runs: α 0.05 / α 0.0125" for n in counts]
    lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    for row in rows:
        cells = [
            f"{row['pair']} ({row['metric']})",
            "area" if row["score"] == "auc" else "final",
            str(row["reference_runs"]),
            f"{row['sd']:.3f}",
        ]
        for n in counts:
            cell = f"{row['detectable'][n]:.3f} / {row['detectable_holm'][n]:.3f}"
            if "detectable_worst" in row:
                cell += f" (σ 0.5: {row['detectable_worst'][n]:.2f})"
            cells.append(cell)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


__all__ = [
    "ALPHA",
    "POWER",
    "REFERENCES",
    "detectable",
    "power_rows",
    "power_table",
    "reference_spread",
]
