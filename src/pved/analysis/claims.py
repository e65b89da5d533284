"""Verdicts on the paper's seven claims about Fig. 3 (section IV.B), from finished
``pved protocol`` output directories.

Every claim is made of parts, each a statistical test on one source-target pair with
three outcomes: ``holds``, ``does not hold`` or ``undecided`` (the runs cannot tell, or
there are none). A claim holds only if every part holds, does not hold if any part does
not, and is undecided otherwise. All intervals are 95% percentile bootstraps over PPO
seeds (:func:`pved.analysis.curves.bootstrap_difference`, 2000 resamples, seed 0): the
runs of one seed, a shaped method's three source policies, are drawn together.

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
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pved.analysis.curves import CI_SIZE, bootstrap_difference, read_eval_points
from pved.errors import PvedError

HOLDS, NOT_HOLD, UNDECIDED = "holds", "does not hold", "undecided"
VERDICTS = (HOLDS, NOT_HOLD, UNDECIDED)

REPS = 2000
"""Bootstrap resamples per interval."""
SEED = 0
"""Seed of every interval's resampling (each comparison is reproducible on its own)."""
EARLY_FRACTION = 0.25
"""Early score: evaluation points at steps <= this fraction of the run's last step."""
FAIL_FRACTION = 0.10
"""PPO "fails completely" below, and "still learns" above, this fraction of the oracle."""
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
    """``part`` with the verdict of its difference's sign (:func:`_sign_verdict`), when
    there is a difference (``d``) to judge."""
    if d is not None:
        part["verdict"] = _sign_verdict(d["diff_ci"], d["tol"])
        if part["verdict"] == UNDECIDED:
            part["reason"] = "no significant difference at these runs"
    return part


# ---------------------------------------------------------------------------- inputs


@dataclass
class _Pair:
    """One pair of one protocol directory's summary."""

    name: str
    metric: str
    directory: Path
    budget: str
    methods: dict[str, dict[str, Any]]
    _cache: dict[tuple[str, str], np.ndarray | str] = field(default_factory=dict)


def _load_summary(directory: Path) -> dict[str, Any]:
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


def _check_pair(path: Path, name: str, entry: Any) -> tuple[str, dict[str, dict[str, Any]]]:
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


def load_pairs(dirs: Sequence[Path]) -> dict[str, _Pair]:
    """Every pair of the protocol directories ``dirs``. Raises PvedError (one line) for no
    DIR, a DIR without a (valid) summary.json, or a pair found in two DIRs."""
    if not dirs:
        raise PvedError("claims needs at least one protocol directory")
    seen = [Path(d).resolve() for d in dirs]
    twice = next((d for i, d in enumerate(seen) if d in seen[:i]), None)
    if twice is not None:
        raise PvedError(f"{twice} is given twice: give each protocol directory once")
    pairs: dict[str, _Pair] = {}
    for directory in map(Path, dirs):
        summary = _load_summary(directory)
        budget = str(summary.get("budget", "?"))
        for name, entry in summary["pairs"].items():
            metric, methods = _check_pair(directory / "summary.json", name, entry)
            if name in pairs:
                raise PvedError(
                    f"pair {name!r} is in both {pairs[name].directory} and {directory}: "
                    "give each pair once"
                )
            pairs[name] = _Pair(name, metric, directory, budget, methods)
    return pairs


def _run_metrics(pair: _Pair, run: dict[str, Any]) -> Path | None:
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


def _scores(pairs: dict[str, _Pair], pair: str, method: str, score: str) -> np.ndarray | str:
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


def _seeds(pairs: dict[str, _Pair], pair: str, method: str) -> list[Hashable]:
    """The PPO seed of each of ``method``'s runs on ``pair``, in ``_scores``' order: the
    bootstrap's clusters (a shaped method runs each evaluation seed with every source
    policy). A run without a recorded seed is a cluster of its own."""
    runs = pairs[pair].methods[method]["runs"]
    return [r["seed"] if "seed" in r else ("run", i) for i, r in enumerate(runs)]


# ---------------------------------------------------------------------------- tests


def _steps_to_ppo_final(
    pairs: dict[str, _Pair], pair: str, methods: Sequence[str]
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

    def __init__(self, pairs: dict[str, _Pair]) -> None:
        self.pairs = pairs
        self._diffs: dict[tuple[str, str, str, str], dict[str, Any] | str] = {}

    def _diff(self, pair: str, a: str, b: str, score: str) -> dict[str, Any] | str:
        """mean score(a) − mean score(b) with CIs (bootstrap_difference), plus ``tol``; or
        the reason it cannot be computed."""
        key = (pair, a, b, score)
        if key not in self._diffs:
            xa, xb = _scores(self.pairs, pair, a, score), _scores(self.pairs, pair, b, score)
            if isinstance(xa, str) or isinstance(xb, str):
                self._diffs[key] = xa if isinstance(xa, str) else str(xb)
            else:
                d = bootstrap_difference(
                    xa,
                    xb,
                    reps=REPS,
                    seed=SEED,
                    clusters_a=_seeds(self.pairs, pair, a),
                    clusters_b=_seeds(self.pairs, pair, b),
                )
                d["tol"] = _tolerance(xa, xb)
                self._diffs[key] = d
        return self._diffs[key]

    def _part(
        self, text: str, test: str, pair: str, a: str, b: str, score: str
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
        d = self._diff(pair, a, b, score)
        if isinstance(d, str):
            part["reason"] = d
            return part, None
        part["groups"] = [{"method": a, **d["a"]}, {"method": b, **d["b"]}]
        part["difference"] = {
            "of": f"mean {score}({a}) − mean {score}({b})",
            "value": d["diff"],
            "ci": d["diff_ci"],
        }
        return part, d

    def beats(self, pair: str, a: str, b: str) -> dict[str, Any]:
        """``a`` beats ``b``: the CI of mean final(a) − mean final(b) lies above 0."""
        part, d = self._part(f"{a} beats {b}", "beats", pair, a, b, "final")
        part["steps_to_ppo_final"] = _steps_to_ppo_final(self.pairs, pair, (a, b))
        return _by_sign(part, d)

    def does_not_beat(self, pair: str, a: str, b: str) -> dict[str, Any]:
        """``a`` does not beat ``b``: holds if "a beats b" is not ``holds`` (decided by
        the data), does not hold if it holds."""
        part = self.beats(pair, a, b)
        part["part"], part["test"] = f"{a} does not beat {b}", "does not beat"
        if "difference" in part:
            part["verdict"] = NOT_HOLD if part["verdict"] == HOLDS else HOLDS
            part["reason"] = None
        return part

    def similar(self, pair: str, a: str, b: str) -> dict[str, Any]:
        """``a`` and ``b`` similar: the CI of the final difference contains 0."""
        part, d = self._part(f"{a} similar to {b}", "similar", pair, a, b, "final")
        part["steps_to_ppo_final"] = _steps_to_ppo_final(self.pairs, pair, (a, b))
        if d is not None:
            separated = _sign_verdict(d["diff_ci"], d["tol"]) != UNDECIDED
            part["verdict"] = NOT_HOLD if separated else HOLDS
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
        part, d = self._part(text, text.removeprefix("ppo "), pair, "ppo", "oracle", "final")
        if d is None:
            return part
        oracle = d["b"]["mean"]
        part["bar"] = FAIL_FRACTION * oracle
        part["bar_of"] = f"{FAIL_FRACTION:.0%} of oracle's mean final"
        if not oracle > 0:
            part["reason"] = f"oracle's mean final score is {oracle:.3g}: no scale for a bar"
            return part
        lo, hi = d["a"]["mean_ci"]
        below, above = hi < part["bar"], lo > part["bar"]
        if below or above:
            part["verdict"] = HOLDS if (above if learns else below) else NOT_HOLD
        else:
            part["reason"] = "ppo's CI contains the bar"
        return part

    def ppo_fails(self, pair: str) -> dict[str, Any]:
        """PPO fails completely: its final mean's CI lies below 10% of the oracle's mean
        (does not hold: above it; undecided: the CI contains it)."""
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


def judge_claims(dirs: Sequence[Path]) -> dict[str, Any]:
    """Verdicts on the seven claims from the protocol directories ``dirs`` (JSON-able).

    Returns ``{"inputs": [{"dir", "budget", "pairs"}...], "pairs": {pair: {"metric",
    "dir", "budget", "runs": {method: n}}}, "definitions": {...}, "claims": [{"claim": k,
    "statement", "verdict", "parts": [part...]}]}``; a part has ``part``, ``test``,
    ``pair``, ``score``, ``verdict``, ``reason`` (why undecided) and, where computed,
    ``groups`` (each method's runs, mean and mean_ci), ``difference`` (``of``, ``value``,
    ``ci``), ``steps_to_ppo_final`` and, for PPO against the oracle, ``bar``. Raises
    PvedError (one line) for bad input (see :func:`load_pairs`)."""
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
            "ci": f"{CI_SIZE:.0%} percentile bootstrap over PPO seeds (the runs of one "
            f"seed drawn together), groups resampled independently, {REPS} resamples, "
            f"seed {SEED}",
            "final": "a run's metric in summary.json",
            "early": f"mean of a run's evaluation points at steps <= {EARLY_FRACTION:.0%} "
            "of its last evaluation step",
            "drop": "a run's best evaluation value minus its last",
            "beats": "CI of mean final(A) − mean final(B): holds above 0, does not hold "
            "below 0, else undecided",
            "does not beat": "holds unless 'beats' holds",
            "similar": "holds if the CI of the final difference contains 0",
            "faster early": "CI of mean early(A) − mean early(B) above 0",
            "more stable": "CI of mean drop(B) − mean drop(A) above 0",
            "fails completely": f"PPO's final mean CI below {FAIL_FRACTION:.0%} of the "
            "oracle's mean (above: does not hold)",
            "still learns": f"PPO's final mean CI above {FAIL_FRACTION:.0%} of the "
            "oracle's mean (below: does not hold)",
            "claim": "holds if every part holds, does not hold if any part does not, "
            "else undecided",
            "min_runs": MIN_RUNS,
        },
        "claims": claims,
    }


# ---------------------------------------------------------------------------- report


def _num(x: float) -> str:
    return f"{x:.3f}" if abs(x) < 10 else f"{x:.1f}"


def _ci(ci: Sequence[float]) -> str:
    return f"[{_num(ci[0])}, {_num(ci[1])}]"


def _group_cell(g: dict[str, Any]) -> str:
    return f"{g['method']} {_num(g['mean'])} {_ci(g['mean_ci'])} (n={g['runs']})"


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
    cells = [part["part"], part["pair"], verdict]
    if "groups" in part:
        a, b = part["groups"]
        score = part["score"]
        cells += [f"{score}: {_group_cell(a)}", f"{score}: {_group_cell(b)}"]
        if "bar" in part:
            cells.append(f"bar {_num(part['bar'])} ({part['bar_of']})")
        else:
            diff = part["difference"]
            cells.append(f"{_num(diff['value'])} {_ci(diff['ci'])}")
        cells.append(_steps_cell(part))
    else:
        cells += ["–"] * 4
    return "| " + " | ".join(c.replace("|", "/") for c in cells) + " |"


def _matrix_cell(part: dict[str, Any] | None) -> str:
    if part is None:
        return ""
    cell = part["verdict"]
    if "difference" in part:
        cell += f" ({_num(part['difference']['value'])})"
    return cell


def verdict_matrix(result: dict[str, Any]) -> str:
    """Markdown table of every part's verdict, one row per claim part and one column per
    pair (Fig. 3's order), the difference A − B beside each decided or measured part, so
    that a claim's fate on all four pairs reads along one row."""
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


def claims_markdown(result: dict[str, Any]) -> str:
    """``claims.md``: the inputs (budgets, run counts), the verdicts by claim and by pair,
    then one table per claim."""
    lines = ["# The paper's claims (IV.B, Fig. 3) against these runs", ""]
    for entry in result["inputs"]:
        lines.append(
            f"- `{entry['dir']}`: budget **{entry['budget']}**, pairs {', '.join(entry['pairs'])}"
        )
    for name, p in result["pairs"].items():
        runs = ", ".join(f"{m} {n}" for m, n in p["runs"].items()) or "none"
        title = f" — {PAIR_TITLES[name]}" if name in PAIR_TITLES else ""
        lines.append(f"- {name}{title} ({p['metric']}): runs per method: {runs}")
    lines += [
        "",
        "Intervals: 95% percentile bootstrap over PPO seeds, the runs of one seed (a "
        "shaped method's source policies) drawn together (2000 resamples). A part holds or "
        "does not hold only where its interval excludes the bar; a claim holds if every "
        "part holds, does not hold if any part does not. Scores: final (the protocol's "
        f"final evaluation), early (evaluations at steps <= {EARLY_FRACTION:.0%} of the "
        "last), drop (best evaluation − last). Difference: A − B (for stability: drop(B) "
        "− drop(A)).",
    ]
    lines += ["", "| claim | verdict | parts: holds / does not hold / undecided |", "|---|---|---|"]
    for claim in result["claims"]:
        counts = " / ".join(str(sum(p["verdict"] == v for p in claim["parts"])) for v in VERDICTS)
        lines.append(f"| {claim['claim']} | **{claim['verdict']}** | {counts} |")
    lines += ["", "Every part by pair (difference A − B in brackets; blank: not a part there):"]
    lines += ["", verdict_matrix(result)]
    header = (
        "| part | pair | verdict | A | B | difference [95% CI] | steps to PPO's final |\n"
        "|---|---|---|---|---|---|---|"
    )
    for claim in result["claims"]:
        lines += [
            "",
            f"## Claim {claim['claim']}: {claim['verdict']}",
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
    result = judge_claims(dirs)
    # Imported here: pved.runs imports torch, which judging does not need.
    from pved.runs import atomic_write_bytes, atomic_write_json

    out = Path(out) if out is not None else Path(dirs[0])
    atomic_write_json(out / "claims.json", result)
    md = out / "claims.md"
    atomic_write_bytes(md, claims_markdown(result).encode())
    return md
