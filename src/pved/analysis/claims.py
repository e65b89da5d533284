"""Verdicts on the paper's seven claims about Fig. 3 (section IV.B), from finished
``pved protocol`` output directories.

Every claim is made of parts, each a statistical test on one source-target pair with
three outcomes: ``holds``, ``does not hold`` or ``undecided`` (the runs cannot tell, or
there are none). A claim holds only if every part holds, does not hold if any part does
not, and is undecided otherwise.

Intervals: 95% percentile two-level bootstrap of the difference of two methods' mean
scores (:func:`pved.analysis.curves.bootstrap_difference`, 2000 resamples, seed 0). Each
resample draws the source policies with replacement (one draw for both methods where both
ran with the same source policies) and, independently, each method's PPO seeds with
replacement, and takes every run of each drawn (source, seed) cell; plain PPO and the
oracle have no source policy and draw their seeds only. The intervals therefore carry the
variation between source policies as well as between seeds.

Tests (A − B: the difference of the two methods' mean scores):

- beats, faster early, more stable: the CI lies above 0 (holds), below 0 (does not hold),
  or contains 0 (undecided);
- does not beat, similar: against an equivalence margin m stated in advance,
  :data:`MARGIN_FRACTION` of |the oracle's mean final score| on the pair (no oracle runs:
  undecided). "A does not beat B" holds when the CI's upper end is below +m, does not
  hold when its lower end is at or above +m; "A similar to B" holds when the whole CI
  lies inside (−m, +m), does not hold when it lies wholly outside (lower end >= +m or
  upper end <= −m); anything else is undecided. A CI that merely contains 0 proves no
  similarity;
- PPO fails completely / still learns: PPO's mean final CI against 10% of the oracle's
  mean final score.

Per part, a bootstrap p-value of its own test (two-sided, on the scale of the 95%
interval: p < 0.05 where the interval decides the part; see the ``definitions`` of
:func:`judge_claims`), and beside the per-part verdict a family-wise one:
Holm–Bonferroni (:func:`holm`) at family α = 0.05 over every distinct test of one
judgement; a verdict whose test Holm does not reject becomes ``undecided`` in the
family-wise column.

Per run (a seed x source policy of one method on one pair):

- final score: its metric in ``summary.json`` (the protocol's final evaluation);
- early score: the mean of its evaluation points (``metrics.jsonl``) at steps <= 25% of
  its last evaluation step;
- drop: its best evaluation value minus its last one (>= 0; lower is more stable).

Only files are read: ``DIR/summary.json`` and each run's ``metrics.jsonl``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pved.analysis.curves import CI_SIZE, bootstrap_difference, read_eval_points
from pved.errors import PvedError

HOLDS, NOT_HOLD, UNDECIDED = "holds", "does not hold", "undecided"
VERDICTS = (HOLDS, NOT_HOLD, UNDECIDED)

REPS = 20000
"""Bootstrap resamples per interval."""
SEED = 0
"""Seed of every interval's resampling (each comparison is reproducible on its own)."""
EARLY_FRACTION = 0.25
"""Early score: evaluation points at steps <= this fraction of the run's last step."""
FAIL_FRACTION = 0.10
"""PPO "fails completely" below, and "still learns" above, this fraction of the oracle."""
MARGIN_FRACTION = 0.10
"""The equivalence margin of "does not beat" and "similar", as a fraction of |the oracle's
mean final score| on the pair: two methods whose final means differ by less than a tenth
of what the task allows (the oracle is the target agent trained with the full reward)
are not told apart. Stated before the protocols were rejudged with it, and the yardstick
``pved claims`` already used for "PPO fails completely" (:data:`FAIL_FRACTION`), so one
scale reads every part: on a success rate (oracle near 1) the margin is about 0.1, on
the curved planes a tenth of the oracle's distance. Without such a margin a "similar" or
"does not beat" part would hold whenever the interval contains 0, so a lack of evidence
would count as support; with it, such a part holds only where the runs show the
difference to be smaller than the margin. Without oracle runs there is no scale, and
those parts are undecided."""
FAMILY_ALPHA = 0.05
"""Family-wise error rate of the Holm–Bonferroni view over one judgement's tests."""
MIN_RUNS = 2
"""Fewest runs in a group for a test to decide anything."""

PAIR_TITLES = {
    "reacher": "Reacher3 → Reacher4 (button pushing)",
    "walker-hopper": "Walker2d → Hopper (curved plane)",
    "jaco-fetch": "Jaco → Fetch (peg insertion)",
    "humanoid-ant": "Humanoid → Ant (curved plane)",
}
FOUR = tuple(PAIR_TITLES)
"""The paper's four pairs, in Fig. 3's order."""

SCORES = ("final", "early", "drop")


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def combine(verdicts: Sequence[str]) -> str:
    """A claim's verdict from its parts': ``holds`` if every part holds, ``does not hold``
    if any part does not, else (and for no parts) ``undecided``."""
    if verdicts and all(v == HOLDS for v in verdicts):
        return HOLDS
    if any(v == NOT_HOLD for v in verdicts):
        return NOT_HOLD
    return UNDECIDED


def holm_adjusted(pvalues: Sequence[float]) -> list[float]:
    """Holm–Bonferroni adjusted p-values, in the order given: with the m p-values sorted
    ascending, p_(i) becomes max over j <= i of min(1, (m − j + 1) p_(j))."""
    m = len(pvalues)
    adjusted = [1.0] * m
    running = 0.0
    for rank, i in enumerate(sorted(range(m), key=lambda j: pvalues[j])):
        running = max(running, min(1.0, (m - rank) * float(pvalues[i])))
        adjusted[i] = running
    return adjusted


def holm(pvalues: Sequence[float], alpha: float = FAMILY_ALPHA) -> list[bool]:
    """Holm–Bonferroni's step-down decisions at family-wise error rate ``alpha``, in the
    order given: sorted ascending, p_(1), p_(2), ... are rejected while p_(i) <= alpha /
    (m − i + 1), and none after the first that is not (the same as adjusted p <= alpha)."""
    return [p <= alpha for p in holm_adjusted(pvalues)]


def _tolerance(*groups: np.ndarray) -> float:
    """Bounds this close to 0 count as 0: the means of equal values over groups of
    different sizes differ by rounding (1e-17), which must not decide a test."""
    scale = max((float(np.max(np.abs(g))) for g in groups if g.size), default=1.0)
    return 1e-9 * max(1.0, scale)


def _sign_verdict(ci: Sequence[float], tol: float) -> str:
    """``holds`` if the interval lies above 0, ``does not hold`` if below, else undecided."""
    lo, hi = ci
    if lo > tol:
        return HOLDS
    if hi < -tol:
        return NOT_HOLD
    return UNDECIDED


def _by_sign(part: dict[str, Any], d: dict[str, Any] | None) -> dict[str, Any]:
    """``part`` with the verdict of its difference's sign (:func:`_sign_verdict`) and the
    two-sided p-value of 0, when there is a difference (``d``) to judge."""
    if d is not None:
        part["verdict"] = _sign_verdict(d["diff_ci"], d["tol"])
        part["p"] = _tail(d["tests"], 0.0)["p"]
        if part["verdict"] == UNDECIDED:
            part["reason"] = "no significant difference at these runs"
    return part


def _tail(tests: Sequence[dict[str, float]], bar: float) -> dict[str, float]:
    """The bootstrap tails of ``bar`` among a bootstrap's ``tests``."""
    return next(t for t in tests if t["bar"] == bar)


def similar_verdict(ci: Sequence[float], margin: float) -> str:
    """The verdict of "similar" against the margin m: ``holds`` if the CI lies inside
    (−m, +m), ``does not hold`` if it lies wholly outside (lo >= m or hi <= −m), else
    ``undecided``."""
    lo, hi = ci
    if -margin < lo and hi < margin:
        return HOLDS
    if lo >= margin or hi <= -margin:
        return NOT_HOLD
    return UNDECIDED


def not_beat_verdict(ci: Sequence[float], margin: float) -> str:
    """The verdict of "A does not beat B" against the margin m: ``holds`` if the CI of
    A − B lies below +m (A is not better by the margin), ``does not hold`` if it lies at
    or above +m, else ``undecided``."""
    lo, hi = ci
    if hi < margin:
        return HOLDS
    if lo >= margin:
        return NOT_HOLD
    return UNDECIDED


def similar_pvalue(minus: dict[str, float], plus: dict[str, float], verdict: str) -> float:
    """The p-value of a "similar" part from the bootstrap tails of −m (``minus``) and +m
    (``plus``), doubled to the 95% interval's two-sided scale. Similar (TOST): 2 max(P(d*
    <= −m), P(d* >= +m)); not similar: 2 min(P(d* <= +m), P(d* >= −m)), the side the CI
    lies on; undecided: the smaller of the two."""
    similar = min(1.0, 2.0 * max(minus["le"], plus["ge"]))
    different = min(1.0, 2.0 * min(plus["le"], minus["ge"]))
    if verdict == HOLDS:
        return similar
    if verdict == NOT_HOLD:
        return different
    return min(similar, different)


# ---------------------------------------------------------------------------- inputs


@dataclass
class PairSummary:
    """One pair of one protocol directory's summary."""

    name: str
    metric: str
    directory: Path
    budget: str
    methods: dict[str, dict[str, Any]]
    _cache: dict[tuple[str, str], np.ndarray | str] = field(default_factory=dict)


def load_summary(directory: Path) -> dict[str, Any]:
    """A finished ``pved protocol`` directory's ``summary.json``, checked to be one; a
    :class:`PvedError` naming the problem otherwise."""
    path = Path(directory) / "summary.json"
    if not Path(directory).is_dir():
        raise PvedError(f"{directory}: not a directory (want a `pved protocol` output)")
    if not path.is_file():
        raise PvedError(f"{directory}: no summary.json (not a finished `pved protocol` output)")
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise PvedError(f"{path}: unreadable or not JSON ({_one_line(exc)})") from exc
    if not isinstance(summary, dict) or not isinstance(summary.get("pairs"), dict):
        raise PvedError(f"{path}: no 'pairs' mapping (not a `pved protocol` summary)")
    return summary


def check_pair(path: Path, name: str, entry: Any) -> tuple[str, dict[str, dict[str, Any]]]:
    """(metric, methods) of one pair's summary entry, checked for the fields read here."""
    if not isinstance(entry, dict):
        raise PvedError(f"{path}: pair {name!r} is not a mapping")
    metric, methods = entry.get("metric"), entry.get("methods")
    if not isinstance(metric, str) or not isinstance(methods, dict):
        raise PvedError(f"{path}: pair {name!r} lacks a 'metric' name or a 'methods' mapping")
    for method, m in methods.items():
        runs = m.get("runs", []) if isinstance(m, dict) else None
        if not isinstance(runs, list) or not all(isinstance(r, dict) for r in runs):
            raise PvedError(f"{path}: {name}/{method}: 'runs' is not a list of runs")
        for r in runs:
            value = r.get(metric)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise PvedError(f"{path}: {name}/{method}: a run has no number {metric!r}")
            if not math.isfinite(value):
                raise PvedError(f"{path}: {name}/{method}: run {r.get('key')} has {value}")
    return metric, methods


def load_pairs(dirs: Sequence[Path]) -> dict[str, PairSummary]:
    """Every pair of the protocol directories ``dirs``. Raises PvedError (one line) for no
    DIR, a DIR without a (valid) summary.json, or a pair found in two DIRs."""
    if not dirs:
        raise PvedError("claims needs at least one protocol directory")
    seen = [Path(d).resolve() for d in dirs]
    twice = next((d for i, d in enumerate(seen) if d in seen[:i]), None)
    if twice is not None:
        raise PvedError(f"{twice} is given twice: give each protocol directory once")
    pairs: dict[str, PairSummary] = {}
    for directory in map(Path, dirs):
        summary = load_summary(directory)
        budget = str(summary.get("budget", "?"))
        for name, entry in summary["pairs"].items():
            metric, methods = check_pair(directory / "summary.json", name, entry)
            if name in pairs:
                raise PvedError(
                    f"pair {name!r} is in both {pairs[name].directory} and {directory}: "
                    "give each pair once"
                )
            pairs[name] = PairSummary(name, metric, directory, budget, methods)
    return pairs


def _run_metrics(pair: PairSummary, run: dict[str, Any]) -> Path | None:
    """A run's metrics.jsonl: next to its result.json, or under DIR/runs/KEY when the
    protocol directory has moved since."""
    candidates = []
    if isinstance(run.get("result"), str):
        candidates.append(Path(run["result"]).parent / "metrics.jsonl")
    if isinstance(run.get("key"), str):
        candidates.append(pair.directory / "runs" / run["key"] / "metrics.jsonl")
    return next((p for p in candidates if p.is_file()), None)


def eval_curve(metrics_path: Path, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values) of a run's ``eval/<metric>`` points, one per step
    (:func:`pved.analysis.curves.read_eval_points`); PvedError if unreadable."""
    try:
        return read_eval_points(metrics_path, f"eval/{metric}")
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise PvedError(f"{metrics_path}: unreadable metrics ({_one_line(exc)})") from exc


def early_score(steps: np.ndarray, values: np.ndarray) -> float:
    """Mean of the evaluation values at steps <= 25% of the last evaluation step."""
    return float(values[steps <= EARLY_FRACTION * steps[-1]].mean())


def drop(values: np.ndarray) -> float:
    """Best evaluation value minus the last one (>= 0)."""
    return float(values.max() - values[-1])


def _scores(pairs: dict[str, PairSummary], pair: str, method: str, score: str) -> np.ndarray | str:
    """Per-run ``score`` (final, early or drop) of ``method`` on ``pair`` as (runs,), or
    the reason there are none."""
    p = pairs.get(pair)
    runs = (p.methods.get(method) or {}).get("runs", []) if p is not None else []
    if p is None or not runs:
        return f"no runs of {method} on {pair}"
    if (method, score) in p._cache:
        return p._cache[(method, score)]
    out: np.ndarray | str
    if len(runs) < MIN_RUNS:
        out = f"needs >= {MIN_RUNS} runs ({method} on {pair} has {len(runs)})"
    elif score == "final":
        out = np.asarray([float(r[p.metric]) for r in runs])
    else:
        values = []
        for r in runs:
            path = _run_metrics(p, r)
            if path is None:
                out = f"no metrics.jsonl of run {r.get('key')} of {method} on {pair}"
                break
            steps, curve = eval_curve(path, p.metric)
            if not steps.size:
                out = f"no eval/{p.metric} points in {path}"
                break
            if not np.all(np.isfinite(curve)):
                out = f"NaN or infinite eval/{p.metric} in {path}"
                break
            values.append(early_score(steps, curve) if score == "early" else drop(curve))
        else:
            out = np.asarray(values)
    p._cache[(method, score)] = out
    return out


def run_seeds(pairs: dict[str, PairSummary], pair: str, method: str) -> list[Hashable]:
    """The PPO seed of each of ``method``'s runs on ``pair``, in ``_scores``' order: one
    level of the bootstrap (a shaped method runs each evaluation seed with every source
    policy). A run without a recorded seed is a seed of its own."""
    runs = pairs[pair].methods[method]["runs"]
    return [r["seed"] if "seed" in r else ("run", i) for i, r in enumerate(runs)]


_SHAPED_RUN = re.compile(r"^.+-beta[^/]+-init\d+-src(?P<source>\d+)$")
"""A shaped method's transfer run directory name,
``<method>-beta<β>-init<model init>-src<source policy>``
(:func:`pved.experiments.protocol_plan.transfer_run_name`, not imported: it pulls in torch)."""


def run_sources(pairs: dict[str, PairSummary], pair: str, method: str) -> list[Hashable] | None:
    """The source policy of each of ``method``'s runs on ``pair`` (in ``_scores``' order),
    read from its run key ``PAIR/transfer/<run name>/seed<k>``; None where the method
    has none: plain PPO and the oracle (whose ``source_policy`` tag only numbers their
    extra seeds s+1, s+2), or a run whose key does not name a source."""
    labels: list[Hashable] = []
    for r in pairs[pair].methods[method]["runs"]:
        key = r.get("key")
        parts = key.split("/") if isinstance(key, str) else []
        match = _SHAPED_RUN.match(parts[-2]) if len(parts) >= 2 else None
        if match is None:
            return None
        labels.append(int(match["source"]))
    return labels


# ---------------------------------------------------------------------------- tests


def _steps_to_ppo_final(
    pairs: dict[str, PairSummary], pair: str, methods: Sequence[str]
) -> dict[str, int | None]:
    """From the summary: per method, the first evaluation step at which its mean curve
    reaches plain PPO's final mean (None: not reached); methods without the entry left out."""
    p = pairs.get(pair)
    out: dict[str, int | None] = {}
    for method in methods:
        m = p.methods.get(method) if p is not None else None
        if isinstance(m, dict) and "steps_to_ppo_final" in m:
            out[method] = m["steps_to_ppo_final"]
    return out


class _Judge:
    """The tests a claim's parts are made of; differences are cached (claims share them)."""

    def __init__(self, pairs: dict[str, PairSummary]) -> None:
        self.pairs = pairs
        self._diffs: dict[tuple[Any, ...], dict[str, Any] | str] = {}

    def _diff(
        self,
        pair: str,
        a: str,
        b: str,
        score: str,
        bars: tuple[float, ...] = (0.0,),
        group_bars: tuple[float, ...] = (),
    ) -> dict[str, Any] | str:
        """mean score(a) − mean score(b) with CIs and the p-values of ``bars``
        (bootstrap_difference over source policies and seeds), plus ``tol``; or the
        reason it cannot be computed."""
        key = (pair, a, b, score, bars, group_bars)
        if key not in self._diffs:
            xa, xb = _scores(self.pairs, pair, a, score), _scores(self.pairs, pair, b, score)
            if isinstance(xa, str) or isinstance(xb, str):
                self._diffs[key] = xa if isinstance(xa, str) else str(xb)
            else:
                tol = _tolerance(xa, xb)
                d = bootstrap_difference(
                    xa,
                    xb,
                    reps=REPS,
                    seed=SEED,
                    seeds_a=run_seeds(self.pairs, pair, a),
                    seeds_b=run_seeds(self.pairs, pair, b),
                    sources_a=run_sources(self.pairs, pair, a),
                    sources_b=run_sources(self.pairs, pair, b),
                    bars=bars,
                    group_bars=group_bars,
                    tol=tol,
                )
                d["tol"] = tol
                self._diffs[key] = d
        return self._diffs[key]

    def margin(self, pair: str) -> tuple[float, float] | str:
        """(margin, oracle's mean final) of ``pair``: :data:`MARGIN_FRACTION` of |the
        oracle's mean final score|; or the reason there is none."""
        oracle = _scores(self.pairs, pair, "oracle", "final")
        if isinstance(oracle, str):
            return f"{oracle}: no scale for the margin"
        mean = float(oracle.mean())
        if not abs(mean) > 0:
            return f"oracle's mean final score is {mean:.3g}: no scale for the margin"
        return MARGIN_FRACTION * abs(mean), mean

    def _part(
        self,
        text: str,
        test: str,
        pair: str,
        a: str,
        b: str,
        score: str,
        bars: tuple[float, ...] = (0.0,),
        group_bars: tuple[float, ...] = (),
    ) -> tuple[dict[str, Any], dict[str, Any] | None]:
        """The common fields of a comparison part, and the difference (None: undecided,
        with the reason filled in)."""
        part: dict[str, Any] = {
            "part": text,
            "test": test,
            "pair": pair,
            "score": score,
            "verdict": UNDECIDED,
            "reason": None,
        }
        d = self._diff(pair, a, b, score, bars, group_bars)
        if isinstance(d, str):
            part["reason"] = d
            return part, None
        part["groups"] = [
            {"method": m, **{k: v for k, v in d[g].items() if k != "tests"}}
            for m, g in ((a, "a"), (b, "b"))
        ]
        part["difference"] = {
            "of": f"mean {score}({a}) − mean {score}({b})",
            "value": d["diff"],
            "ci": d["diff_ci"],
        }
        return part, d

    def _margin_part(
        self, text: str, test: str, pair: str, a: str, b: str
    ) -> tuple[dict[str, Any], dict[str, Any] | None, float]:
        """A part judged against the pair's margin: the part, its difference with the
        tails of −m, 0 and +m (None: undecided, reason filled in), and m."""
        margin = self.margin(pair)
        if isinstance(margin, str):
            part, _ = self._part(text, test, pair, a, b, "final")
            part["reason"] = part["reason"] or margin
            part["steps_to_ppo_final"] = _steps_to_ppo_final(self.pairs, pair, (a, b))
            return part, None, math.nan
        m, oracle = margin
        part, d = self._part(text, test, pair, a, b, "final", bars=(-m, 0.0, m))
        part["margin"] = m
        size = "" if oracle > 0 else " in magnitude"
        part["margin_of"] = f"{MARGIN_FRACTION:.0%} of oracle's mean final {_num(oracle)}{size}"
        part["steps_to_ppo_final"] = _steps_to_ppo_final(self.pairs, pair, (a, b))
        return part, d, m

    def beats(self, pair: str, a: str, b: str) -> dict[str, Any]:
        """``a`` beats ``b``: the CI of mean final(a) − mean final(b) lies above 0."""
        part, d = self._part(f"{a} beats {b}", "beats", pair, a, b, "final")
        part["steps_to_ppo_final"] = _steps_to_ppo_final(self.pairs, pair, (a, b))
        return _by_sign(part, d)

    def does_not_beat(self, pair: str, a: str, b: str) -> dict[str, Any]:
        """``a`` does not beat ``b`` by the margin m (:data:`MARGIN_FRACTION`): the CI of
        mean final(a) − mean final(b) lies below +m (holds) or at or above it (does not
        hold; :func:`not_beat_verdict`); p: two-sided of +m."""
        part, d, m = self._margin_part(f"{a} does not beat {b}", "does not beat", pair, a, b)
        if d is not None:
            part["verdict"] = not_beat_verdict(d["diff_ci"], m)
            part["p"] = _tail(d["tests"], m)["p"]
            if part["verdict"] == UNDECIDED:
                part["reason"] = "the CI contains the margin +m: cannot tell at these runs"
        return part

    def similar(self, pair: str, a: str, b: str) -> dict[str, Any]:
        """``a`` and ``b`` similar: the CI of the final difference lies inside (−m, +m)
        (holds) or wholly outside it (does not hold; :func:`similar_verdict`)."""
        part, d, m = self._margin_part(f"{a} similar to {b}", "similar", pair, a, b)
        if d is not None:
            part["verdict"] = similar_verdict(d["diff_ci"], m)
            part["p"] = similar_pvalue(_tail(d["tests"], -m), _tail(d["tests"], m), part["verdict"])
            if part["verdict"] == UNDECIDED:
                part["reason"] = "the CI is neither inside ±m nor outside it"
        return part

    def faster_early(self, pair: str, a: str, b: str) -> dict[str, Any]:
        """``a`` learns faster early than ``b``: CI of mean early(a) − mean early(b) > 0."""
        part, d = self._part(f"{a} faster early than {b}", "faster early", pair, a, b, "early")
        return _by_sign(part, d)

    def more_stable(self, pair: str, a: str, b: str) -> dict[str, Any]:
        """``a`` more stable than ``b``: CI of mean drop(b) − mean drop(a) > 0."""
        part, d = self._part(f"{a} more stable than {b}", "more stable", pair, b, a, "drop")
        return _by_sign(part, d)

    def _ppo_vs_oracle(self, pair: str, learns: bool) -> dict[str, Any]:
        text = "ppo still learns" if learns else "ppo fails completely"
        oracle = _scores(self.pairs, pair, "oracle", "final")
        bar = FAIL_FRACTION * float(oracle.mean()) if not isinstance(oracle, str) else 0.0
        part, d = self._part(
            text, text.removeprefix("ppo "), pair, "ppo", "oracle", "final", group_bars=(bar,)
        )
        if d is None:
            return part
        part["bar"] = bar
        part["bar_of"] = f"{FAIL_FRACTION:.0%} of oracle's mean final"
        if not d["b"]["mean"] > 0:
            oracle_mean = d["b"]["mean"]
            part["reason"] = f"oracle's mean final score is {oracle_mean:.3g}: no scale for a bar"
            return part
        part["p"] = _tail(d["a"]["tests"], bar)["p"]
        lo, hi = d["a"]["mean_ci"]
        below, above = hi < bar, lo > bar
        if below or above:
            part["verdict"] = HOLDS if (above if learns else below) else NOT_HOLD
        else:
            part["reason"] = "ppo's CI contains the bar"
        return part

    def ppo_fails(self, pair: str) -> dict[str, Any]:
        """PPO fails completely: its final mean's CI lies below 10% of the oracle's mean
        (does not hold: above it; undecided: the CI contains it); p: two-sided of the bar
        from PPO's resampled means."""
        return self._ppo_vs_oracle(pair, learns=False)

    def ppo_learns(self, pair: str) -> dict[str, Any]:
        """PPO still learns: its final mean's CI lies above 10% of the oracle's mean."""
        return self._ppo_vs_oracle(pair, learns=True)


@dataclass(frozen=True)
class Claim:
    """One of the paper's claims: its statement and how to build its parts."""

    number: int
    statement: str
    parts: Callable[[_Judge], list[dict[str, Any]]]


_ABLATIONS_NOT_ON_ANT = ("pved-state-only", "pved-shared-only", "pved-det-shared", "gupta2017")

CLAIMS = (
    Claim(
        1,
        "PVED beats plain PPO on all four target tasks; PPO fails completely on peg "
        "insertion and on Hopper's curved plane, and still learns button pushing.",
        lambda j: [
            *(j.beats(p, "pved", "ppo") for p in FOUR),
            j.ppo_fails("jaco-fetch"),
            j.ppo_fails("walker-hopper"),
            j.ppo_learns("reacher"),
        ],
    ),
    Claim(
        2,
        "PVED beats Gupta et al. 2017 on all four.",
        lambda j: [j.beats(p, "pved", "gupta2017") for p in FOUR],
    ),
    Claim(
        3,
        "On Humanoid → Ant only PVED and PVED-VAE beat plain PPO.",
        lambda j: [
            j.beats("humanoid-ant", "pved", "ppo"),
            j.beats("humanoid-ant", "pved-vae", "ppo"),
            *(j.does_not_beat("humanoid-ant", m, "ppo") for m in _ABLATIONS_NOT_ON_ANT),
        ],
    ),
    Claim(
        4,
        "PVED beats PVED-state-only on all four; state-only does worse than Gupta et al.",
        lambda j: [
            part
            for p in FOUR
            for part in (
                j.beats(p, "pved", "pved-state-only"),
                j.beats(p, "gupta2017", "pved-state-only"),
            )
        ],
    ),
    Claim(
        5,
        "PVED beats PVED-shared-only on all four.",
        lambda j: [j.beats(p, "pved", "pved-shared-only") for p in FOUR],
    ),
    Claim(
        6,
        "PVED against PVED-det-shared is mixed: PVED does better on button pushing and "
        "Ant's curved plane, det-shared learns faster early on peg insertion and does "
        "better on Hopper; PVED is more stable.",
        lambda j: [
            j.beats("reacher", "pved", "pved-det-shared"),
            j.beats("humanoid-ant", "pved", "pved-det-shared"),
            j.faster_early("jaco-fetch", "pved-det-shared", "pved"),
            j.beats("walker-hopper", "pved-det-shared", "pved"),
            *(j.more_stable(p, "pved", "pved-det-shared") for p in FOUR),
        ],
    ),
    Claim(
        7,
        "PVED beats PVED-VAE on three of four tasks and is similar on Humanoid → Ant.",
        lambda j: [
            *(j.beats(p, "pved", "pved-vae") for p in ("reacher", "walker-hopper", "jaco-fetch")),
            j.similar("humanoid-ant", "pved", "pved-vae"),
        ],
    ),
)


def family_wise(claims: Sequence[dict[str, Any]], alpha: float = FAMILY_ALPHA) -> dict[str, Any]:
    """Holm–Bonferroni over every distinct test among ``claims``' parts (a part with a
    p-value; the same part and pair in two claims is one test), in place: each part gets
    ``p_holm`` (its Holm-adjusted p-value; None without a p) and ``family_verdict`` (its
    verdict if Holm rejects its test at ``alpha``, else undecided), each claim its
    ``family_verdict`` (:func:`combine` of those). Returns the family's size: ``{"alpha",
    "tests", "parts", "parts_tested"}``."""
    tests: dict[tuple[str, str], float] = {}
    parts = [part for claim in claims for part in claim["parts"]]
    for part in parts:
        if part.get("p") is not None:
            tests.setdefault((part["part"], part["pair"]), float(part["p"]))
    adjusted = dict(zip(tests, holm_adjusted(list(tests.values())), strict=True))
    for part in parts:
        p_holm = adjusted.get((part["part"], part["pair"])) if part.get("p") is not None else None
        part["p_holm"] = p_holm
        survives = p_holm is not None and p_holm <= alpha
        part["family_verdict"] = part["verdict"] if survives else UNDECIDED
    for claim in claims:
        claim["family_verdict"] = combine([p["family_verdict"] for p in claim["parts"]])
    return {
        "alpha": alpha,
        "tests": len(tests),
        "parts": len(parts),
        "parts_tested": sum(p.get("p") is not None for p in parts),
    }


def judge_claims(dirs: Sequence[Path]) -> dict[str, Any]:
    """Verdicts on the seven claims from the protocol directories ``dirs`` (JSON-able).

    Returns ``{"inputs": [{"dir", "budget", "pairs"}...], "pairs": {pair: {"metric",
    "dir", "budget", "runs": {method: n}}}, "definitions": {...}, "family": {"alpha",
    "tests", "parts", "parts_tested"}, "claims": [{"claim": k, "statement", "verdict",
    "family_verdict", "parts": [part...]}]}``; a part has ``part``, ``test``, ``pair``,
    ``score``, ``verdict``, ``reason`` (why undecided), ``family_verdict`` and ``p_holm``
    (:func:`family_wise`) and, where computed, ``groups`` (each method's runs, seeds,
    sources, mean and mean_ci), ``difference`` (``of``, ``value``, ``ci``), ``p`` (the
    bootstrap p-value of its test), ``steps_to_ppo_final``, for PPO against the oracle
    ``bar``, and for "does not beat" and "similar" ``margin``. Raises PvedError (one
    line) for bad input (see :func:`load_pairs`)."""
    pairs = load_pairs(dirs)
    judge = _Judge(pairs)
    claims = []
    for claim in CLAIMS:
        parts = claim.parts(judge)
        claims.append(
            {
                "claim": claim.number,
                "statement": claim.statement,
                "verdict": combine([p["verdict"] for p in parts]),
                "parts": parts,
            }
        )
    family = family_wise(claims)
    inputs: dict[str, dict[str, Any]] = {}
    for p in pairs.values():
        inputs.setdefault(str(p.directory), {"dir": str(p.directory), "budget": p.budget})
        inputs[str(p.directory)].setdefault("pairs", []).append(p.name)
    return {
        "inputs": list(inputs.values()),
        "pairs": {
            p.name: {
                "metric": p.metric,
                "dir": str(p.directory),
                "budget": p.budget,
                "runs": {m: len((e or {}).get("runs", [])) for m, e in p.methods.items()},
            }
            for p in pairs.values()
        },
        "definitions": {
            "ci": f"{CI_SIZE:.0%} percentile two-level bootstrap of the difference of "
            "means: each resample draws the source policies with replacement (one draw for "
            "both methods where both ran with the same ones) and, independently, each "
            "method's PPO seeds with replacement (seeds are not paired between methods), "
            "and takes every run of each drawn (source, seed) cell; PPO and the oracle "
            f"have no source and draw seeds only; {REPS} resamples, seed {SEED}",
            "final": "a run's metric in summary.json",
            "early": f"mean of a run's evaluation points at steps <= {EARLY_FRACTION:.0%} "
            "of its last evaluation step",
            "drop": "a run's best evaluation value minus its last",
            "beats": "CI of mean final(A) − mean final(B): holds above 0, does not hold "
            "below 0, else undecided",
            "margin": f"m = {MARGIN_FRACTION:.0%} of |the oracle's mean final score| on the "
            "pair, stated in advance (no oracle runs: undecided)",
            "does not beat": "CI of mean final(A) − mean final(B): holds below +m, does not "
            "hold at or above +m, else undecided",
            "similar": "CI of mean final(A) − mean final(B): holds inside (−m, +m), does "
            "not hold wholly outside it (lower end >= +m or upper end <= −m), else "
            "undecided",
            "faster early": "CI of mean early(A) − mean early(B) above 0",
            "more stable": "CI of mean drop(B) − mean drop(A) above 0",
            "fails completely": f"PPO's final mean CI below {FAIL_FRACTION:.0%} of the "
            "oracle's mean (above: does not hold)",
            "still learns": f"PPO's final mean CI above {FAIL_FRACTION:.0%} of the "
            "oracle's mean (below: does not hold)",
            "p": "bootstrap p-value of the part's test, P(d* <= c) and P(d* >= c) taken as "
            f"(1 + count) / (1 + {REPS}) over the resampled differences d* (PPO against "
            "the oracle: PPO's resampled means); beats, faster early, more stable: "
            "2 min(P(d* <= 0), P(d* >= 0)); does not beat: the same of +m; similar: "
            "2 max(P(d* <= −m), P(d* >= +m)) (TOST) where it holds, 2 min(P(d* <= +m), "
            "P(d* >= −m)) where it does not, the smaller of the two where undecided; PPO "
            "fails / learns: the same of the bar; capped at 1. Doubled one-sided "
            "p-values put every part on the 95% interval's scale (p < 0.05 where the "
            "interval decides it)",
            "family": f"Holm–Bonferroni at family-wise α = {FAMILY_ALPHA} over every "
            "distinct test of this judgement (a part in two claims is one test); a "
            "part's family-wise verdict is its verdict where Holm rejects its test, else "
            "undecided; a claim's family-wise verdict combines its parts' the same way",
            "claim": "holds if every part holds, does not hold if any part does not, "
            "else undecided",
            "min_runs": MIN_RUNS,
        },
        "family": family,
        "claims": claims,
    }


# ---------------------------------------------------------------------------- report


def _num(x: float) -> str:
    return f"{x:.3f}" if abs(x) < 10 else f"{x:.1f}"


def _ci(ci: Sequence[float]) -> str:
    return f"[{_num(ci[0])}, {_num(ci[1])}]"


def _p(p: float | None) -> str:
    return "–" if p is None else f"{p:.3f}" if p >= 0.001 else f"{p:.1e}"


def _group_cell(g: dict[str, Any]) -> str:
    runs = f"n={g['runs']}"
    if g.get("sources"):
        runs += f": {g['sources']} sources × {g['seeds']} seeds"
    elif "seeds" in g and g["seeds"] != g["runs"]:
        runs += f": {g['seeds']} seeds"
    return f"{g['method']} {_num(g['mean'])} {_ci(g['mean_ci'])} ({runs})"


def _steps_cell(part: dict[str, Any]) -> str:
    steps = part.get("steps_to_ppo_final")
    if not steps:
        return "–"

    def one(m: str) -> str:
        if m not in steps:
            return "–"
        return "not reached" if steps[m] is None else f"{steps[m]:,}"

    return " / ".join(f"{m}: {one(m)}" for m in (g["method"] for g in part["groups"]))


def _part_row(part: dict[str, Any]) -> str:
    verdict = f"**{part['verdict']}**"
    if part["reason"]:
        verdict += f" ({part['reason']})"
    cells = [part["part"], part["pair"], verdict, f"**{part['family_verdict']}**"]
    if "groups" in part:
        a, b = part["groups"]
        score = part["score"]
        cells += [f"{score}: {_group_cell(a)}", f"{score}: {_group_cell(b)}"]
        if "bar" in part:
            cells.append(f"bar {_num(part['bar'])} ({part['bar_of']})")
        else:
            diff = part["difference"]
            cell = f"{_num(diff['value'])} {_ci(diff['ci'])}"
            if "margin" in part:
                cell += f"; margin ±{_num(part['margin'])} ({part['margin_of']})"
            cells.append(cell)
        cells.append(f"{_p(part.get('p'))} ({_p(part.get('p_holm'))})")
        cells.append(_steps_cell(part))
    else:
        cells += ["–"] * 5
    return "| " + " | ".join(c.replace("|", "/") for c in cells) + " |"


def _matrix_cell(part: dict[str, Any] | None) -> str:
    if part is None:
        return ""
    cell = part["verdict"]
    if "difference" in part:
        cell += f" ({_num(part['difference']['value'])})"
    if part["family_verdict"] != part["verdict"]:
        cell += f"; Holm: {part['family_verdict']}"
    return cell


def verdict_matrix(result: dict[str, Any]) -> str:
    """Markdown table of every part's verdict, one row per claim part and one column per
    pair (Fig. 3's order), the difference A − B beside each decided or measured part and
    the family-wise verdict where it differs, so that a claim's fate on all four pairs
    reads along one row."""
    pairs = list(FOUR) + [p for p in result["pairs"] if p not in FOUR]
    rows: dict[tuple[int, str], dict[str, dict[str, Any]]] = {}
    for claim in result["claims"]:
        for part in claim["parts"]:
            rows.setdefault((claim["claim"], part["part"]), {})[part["pair"]] = part
    lines = [
        "| claim | part | " + " | ".join(pairs) + " |",
        "|---|---|" + "---|" * len(pairs),
    ]
    for (number, name), by_pair in rows.items():
        cells = [str(number), name, *(_matrix_cell(by_pair.get(p)) for p in pairs)]
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(lines)


def _counts(parts: Sequence[dict[str, Any]], key: str) -> str:
    return " / ".join(str(sum(p[key] == v for p in parts)) for v in VERDICTS)


def claims_markdown(result: dict[str, Any]) -> str:
    """``claims.md``: the inputs (budgets, run counts), how the parts are judged, the
    verdicts by claim (per part and family-wise) and by pair, then one table per claim."""
    lines = ["# The paper's claims (IV.B, Fig. 3) against these runs", ""]
    for entry in result["inputs"]:
        lines.append(
            f"- `{entry['dir']}`: budget **{entry['budget']}**, pairs {', '.join(entry['pairs'])}"
        )
    for name, p in result["pairs"].items():
        runs = ", ".join(f"{m} {n}" for m, n in p["runs"].items()) or "none"
        title = f" — {PAIR_TITLES[name]}" if name in PAIR_TITLES else ""
        lines.append(f"- {name}{title} ({p['metric']}): runs per method: {runs}")
    family = result["family"]
    lines += [
        "",
        f"Intervals: {CI_SIZE:.0%} percentile two-level bootstrap of the difference of "
        f"two methods' means ({REPS} resamples): each resample draws the source policies "
        "with replacement (one draw for both methods where both ran with the same source "
        "policies) and, independently, each method's PPO seeds with replacement, and takes "
        "every run of each drawn (source, seed) cell; plain PPO and the oracle have no "
        "source and draw their seeds only. Scores: final (the protocol's final "
        f"evaluation), early (evaluations at steps <= {EARLY_FRACTION:.0%} of the last), "
        "drop (best evaluation − last). Difference: A − B (for stability: drop(B) − "
        "drop(A)).",
        "",
        'Tests: a "beats", "faster early" or "more stable" part holds where the '
        'interval lies above 0 and does not hold where it lies below 0. "Does not beat" '
        'and "similar" are judged against an equivalence margin m stated in advance, '
        f"{MARGIN_FRACTION:.0%} of |the oracle's mean final score| on the pair (printed in "
        'each such row): "A does not beat B" holds where the interval lies below +m and '
        'does not hold where it lies at or above +m; "A similar to B" holds where the '
        "interval lies inside (−m, +m) and does not hold where it lies wholly outside it. "
        "An interval that merely contains 0 decides neither. PPO fails completely / "
        f"still learns: PPO's mean final interval below / above {FAIL_FRACTION:.0%} of "
        "the oracle's mean final. Anything else is undecided. A claim holds if every part "
        "holds, does not hold if any part does not.",
        "",
        f"Family-wise: each part's test has a bootstrap p-value (p < 0.05 where its "
        "interval decides it); Holm–Bonferroni at family-wise α = "
        f"{family['alpha']} over the {family['tests']} distinct "
        f"test{'s' if family['tests'] != 1 else ''} of this judgement "
        f"({family['parts_tested']} of the {family['parts']} parts had the runs to be "
        "tested; a part in two claims is one test). A verdict whose test Holm does not "
        "reject is undecided in the family-wise column. The smallest p-value "
        f"{REPS} resamples give is 2 / {REPS + 1} (every resample beyond the bar), so Holm "
        f"keeps a verdict only where p times the tests still open is <= {family['alpha']}.",
    ]
    lines += [
        "",
        "| claim | verdict per part | family-wise (Holm) | parts per part: holds / does not "
        "hold / undecided | family-wise |",
        "|---|---|---|---|---|",
    ]
    for claim in result["claims"]:
        parts = claim["parts"]
        lines.append(
            f"| {claim['claim']} | **{claim['verdict']}** | **{claim['family_verdict']}** | "
            f"{_counts(parts, 'verdict')} | {_counts(parts, 'family_verdict')} |"
        )
    lines += [
        "",
        "Every part by pair (difference A − B in brackets; the family-wise verdict where "
        "it differs; blank: not a part there):",
    ]
    lines += ["", verdict_matrix(result)]
    header = (
        "| part | pair | verdict | family-wise | A | B | difference [95% CI] | p (Holm) | "
        "steps to PPO's final |\n|---|---|---|---|---|---|---|---|---|"
    )
    for claim in result["claims"]:
        lines += [
            "",
            f"## Claim {claim['claim']}: {claim['verdict']} (family-wise: "
            f"{claim['family_verdict']})",
            "",
            claim["statement"],
            "",
            header,
            *(_part_row(p) for p in claim["parts"]),
        ]
    return "\n".join(lines) + "\n"


def write_claims(dirs: Sequence[Path], out: Path | None = None) -> Path:
    """Judge the claims on ``dirs`` and write ``OUT/claims.json`` and ``OUT/claims.md``
    atomically (OUT defaults to the first DIR). Returns the path of claims.md."""
    from pved.checks import check_writable

    if out is not None or dirs:  # where the verdicts go, found before the judging
        out = check_writable("--out", out if out is not None else dirs[0])
    result = judge_claims(dirs)
    # Imported here: pved.runs imports torch, which judging does not need.
    from pved.runs import atomic_write_bytes, atomic_write_json

    out = Path(out) if out is not None else Path(dirs[0])
    atomic_write_json(out / "claims.json", result)
    md = out / "claims.md"
    atomic_write_bytes(md, claims_markdown(result).encode())
    return md
