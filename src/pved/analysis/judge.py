"""The tests a verdict is made of, for ``pved claims`` and ``pved scoreboard``: reading
finished ``pved protocol`` summaries, per-run scores, and comparisons of two methods on a
pair with three outcomes, ``holds``, ``does not hold`` or ``undecided`` (the runs cannot
tell, or there are none).

Intervals: 95% percentile two-level bootstrap of the difference of two methods' mean
scores (:func:`pved.analysis.bootstrap.bootstrap_difference`, :data:`REPS` resamples, seed
:data:`SEED`). Each resample draws the source policies with replacement (one draw for
both methods where both ran with the same source policies) and, independently, each
method's PPO seeds with replacement, and takes every run of each drawn (source, seed)
cell; plain PPO and the oracle have no source policy and draw their seeds only. The
intervals therefore carry the variation between source policies as well as between seeds.
A method's own interval, wherever a part prints it, is the same bootstrap of its mean
alone (:meth:`Judge.mean`, :func:`pved.analysis.bootstrap.bootstrap_mean`), so one method's
runs carry one interval whatever they are compared with.

Tests (A − B: the difference of the two methods' mean scores; :class:`Judge`):

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
interval: p < 0.05 where the interval decides the part).

Per run (a seed x source policy of one method on one pair):

- final score: its metric in ``summary.json`` (the protocol's final evaluation);
- early score: the mean of its evaluation points at steps <= 25% of its last evaluation
  step;
- drop: its best evaluation value minus its last one (>= 0; lower is more stable);
- the transfer measures of Taylor & Stone (2009) (:mod:`pved.analysis.transfer_measures`):
  ``auc``, ``jumpstart`` (its first evaluation point) and ``reach`` (the steps its curve
  takes to reach plain PPO's final, :func:`ppo_final_point`).

The scores off a run's curve are :mod:`pved.analysis.run_curves`': its ``metrics.jsonl``,
or in a published protocol directory its curve in the committed record; a run with
neither has "no curves", and no score that needs one.

Only files are read: ``DIR/summary.json``, each run's ``metrics.jsonl`` or the record.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pved.analysis.bootstrap import REPS as REPS
from pved.analysis.bootstrap import SEED as SEED
from pved.analysis.bootstrap import bootstrap_difference, bootstrap_mean
from pved.analysis.run_curves import EARLY_FRACTION as EARLY_FRACTION
from pved.analysis.run_curves import curve_score, run_curve, steps_to_threshold
from pved.analysis.run_curves import drop as drop
from pved.analysis.run_curves import early_score as early_score
from pved.analysis.run_curves import eval_curve as eval_curve
from pved.errors import PvedError

HOLDS, NOT_HOLD, UNDECIDED = "holds", "does not hold", "undecided"
VERDICTS = (HOLDS, NOT_HOLD, UNDECIDED)

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
AA_REFERENCE = "ppo-aa"
"""The A/A reference: plain PPO again, on seeds no other method uses
(:data:`pved.transfer.methods.AA_REFERENCE`; not imported here: it pulls in torch)."""


def num(x: float) -> str:
    """A score as the verdicts print it: 3 decimals below 10, 1 above."""
    return f"{x:.3f}" if abs(x) < 10 else f"{x:.1f}"


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


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
    _cache: dict[tuple[str, str], Any] = field(default_factory=dict)


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


def method_curves(p: PairSummary, method: str) -> list[tuple[np.ndarray, np.ndarray]] | str:
    """Every run's curve of ``method`` on ``p``
    (:func:`pved.analysis.run_curves.run_curve`), or the first run's reason for having
    none."""
    key = (method, "curves")
    if key not in p._cache:
        curves = [run_curve(p.directory, p.metric, r) for r in p.methods[method]["runs"]]
        bad = next((c for c in curves if isinstance(c, str)), None)
        p._cache[key] = bad if bad is not None else curves
    out: list[tuple[np.ndarray, np.ndarray]] | str = p._cache[key]
    return out


def ppo_final_point(pairs: dict[str, PairSummary], pair: str) -> float | str:
    """Plain PPO's final on ``pair`` as its mean curve gives it (the mean of its runs'
    last evaluation points: the threshold of ``reach``, as of ``steps_to_ppo_final`` in
    the summary), or why there is none: no PPO curves, or a PPO whose mean curve ends at
    or below its start (every curve would reach it at once)."""
    p = pairs.get(pair)
    if p is None or not (p.methods.get("ppo") or {}).get("runs"):
        return f"no runs of ppo on {pair}: no final to reach"
    curves = method_curves(p, "ppo")
    if isinstance(curves, str):
        return curves
    first = float(np.mean([v[0] for _, v in curves]))
    last = float(np.mean([v[-1] for _, v in curves]))
    if not last > first:
        return f"ppo did not improve on {pair} ({num(first)} -> {num(last)}): no final to reach"
    return last


def run_scores(
    pairs: dict[str, PairSummary], pair: str, method: str, score: str
) -> np.ndarray | str:
    """Per-run ``score`` (final, or one of
    :data:`pved.analysis.run_curves.CURVE_SCORES`) of ``method`` on ``pair`` as (runs,),
    or the reason there are none."""
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
        curves = method_curves(p, method)
        threshold = ppo_final_point(pairs, pair) if score == "reach" else 0.0
        if isinstance(curves, str) or isinstance(threshold, str):
            out = curves if isinstance(curves, str) else str(threshold)
        elif score == "reach":
            out = np.asarray([steps_to_threshold(s, v, threshold) for s, v in curves])
        else:
            out = np.asarray([curve_score(score, s, v) for s, v in curves])
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
(:func:`pved.run_layout.transfer_run_name`, not imported: it pulls in torch)."""


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


class Judge:
    """The tests a claim's parts are made of; differences are cached (claims share them).
    ``reps`` and ``seed``: the resampling (the project's :data:`REPS` and :data:`SEED`;
    others only to measure how the verdicts depend on them)."""

    def __init__(self, pairs: dict[str, PairSummary], reps: int = REPS, seed: int = SEED) -> None:
        self.pairs = pairs
        self.reps, self.seed = reps, seed
        self._diffs: dict[tuple[Any, ...], dict[str, Any] | str] = {}
        self._means: dict[tuple[str, str, str], dict[str, Any] | str] = {}

    def mean(self, pair: str, method: str, score: str = "final") -> dict[str, Any] | str:
        """``method``'s mean ``score`` on ``pair`` with its own 95% interval (the two-level
        bootstrap of its runs alone, :func:`pved.analysis.bootstrap.bootstrap_mean`): ``{"runs",
        "seeds", "sources", "mean", "mean_ci"}``, or the reason there is none."""
        key = (pair, method, score)
        if key not in self._means:
            x = run_scores(self.pairs, pair, method, score)
            self._means[key] = (
                x
                if isinstance(x, str)
                else bootstrap_mean(
                    x,
                    run_seeds(self.pairs, pair, method),
                    run_sources(self.pairs, pair, method),
                    reps=self.reps,
                    seed=self.seed,
                    label=(pair, method),
                )
            )
        return self._means[key]

    def _groups(self, pair: str, score: str, **named: str) -> dict[str, dict[str, Any]]:
        """Each named method's own interval (:meth:`mean`), for a difference that exists."""
        out: dict[str, dict[str, Any]] = {}
        for g, method in named.items():
            mean = self.mean(pair, method, score)
            if isinstance(mean, str):  # cannot be: the difference had its scores
                raise PvedError(mean)
            out[g] = dict(mean)
        return out

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
            xa, xb = run_scores(self.pairs, pair, a, score), run_scores(self.pairs, pair, b, score)
            if isinstance(xa, str) or isinstance(xb, str):
                self._diffs[key] = xa if isinstance(xa, str) else str(xb)
            else:
                tol = _tolerance(xa, xb)
                d = bootstrap_difference(
                    xa,
                    xb,
                    reps=self.reps,
                    seed=self.seed,
                    seeds_a=run_seeds(self.pairs, pair, a),
                    seeds_b=run_seeds(self.pairs, pair, b),
                    sources_a=run_sources(self.pairs, pair, a),
                    sources_b=run_sources(self.pairs, pair, b),
                    bars=bars,
                    group_bars=group_bars,
                    tol=tol,
                    labels=((pair, a), (pair, b)),  # each method's own draws, as in mean()
                )
                d["tol"] = tol
                self._diffs[key] = d
        return self._diffs[key]

    def difference(self, pair: str, a: str, b: str, score: str) -> dict[str, Any] | str:
        """mean score(a) − mean score(b) on ``pair`` (the same two-level bootstrap as the
        tests): ``{"value", "ci", "p" (two-sided, of 0), "a", "b" (each group's runs,
        seeds, sources, mean and mean_ci)}``, or the reason there is none."""
        d = self._diff(pair, a, b, score)
        if isinstance(d, str):
            return d
        groups = self._groups(pair, score, a=a, b=b)
        return {"value": d["diff"], "ci": d["diff_ci"], "p": _tail(d["tests"], 0.0)["p"], **groups}

    def margin(self, pair: str) -> tuple[float, float] | str:
        """(margin, oracle's mean final) of ``pair``: :data:`MARGIN_FRACTION` of |the
        oracle's mean final score|; or the reason there is none."""
        oracle = run_scores(self.pairs, pair, "oracle", "final")
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
        groups = self._groups(pair, score, a=a, b=b)
        part["groups"] = [{"method": m, **groups[g]} for m, g in ((a, "a"), (b, "b"))]
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
        part["margin_of"] = f"{MARGIN_FRACTION:.0%} of oracle's mean final {num(oracle)}{size}"
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
        oracle = run_scores(self.pairs, pair, "oracle", "final")
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
        # PPO's own interval (drawn first and without sources, the draws of its p too)
        lo, hi = part["groups"][0]["mean_ci"]
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
