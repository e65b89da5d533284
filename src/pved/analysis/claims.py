"""Verdicts on the paper's seven claims about Fig. 3 (section IV.B), from finished
``pved protocol`` output directories.

Every claim is made of parts, each a test on one source-target pair
(:mod:`pved.analysis.judge`: the intervals, tests and per-run scores) with three
outcomes: ``holds``, ``does not hold`` or ``undecided``. A claim holds only if every part
holds, does not hold if any part does not, and is undecided otherwise.

Beside the per-part verdict a family-wise one: Holm–Bonferroni (:func:`holm`) at family
α = 0.05 over every distinct test of one judgement; a verdict whose test Holm does not
reject becomes ``undecided`` in the family-wise column (the ``definitions`` of
:func:`judge_claims` say each test's p-value).

Beside each part its A/A check (ppo-aa − ppo on the part's score and pair; "inside A/A
noise" where the part's |difference| is no larger, :mod:`pved.analysis.transfer_measures`),
and after the claims every method against PPO by the field's transfer measures (AUC,
jumpstart, steps to PPO's final, final; Holm over the pairs).

Only files are read: ``DIR/summary.json`` and each run's ``metrics.jsonl`` (or a
published protocol's committed record of its curves).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pved.analysis.curves import CI_SIZE
from pved.analysis.judge import (
    EARLY_FRACTION,
    FAIL_FRACTION,
    FOUR,
    HOLDS,
    MARGIN_FRACTION,
    MIN_RUNS,
    NOT_HOLD,
    PAIR_TITLES,
    REPS,
    SEED,
    UNDECIDED,
    VERDICTS,
    Judge,
    PairSummary,
    load_pairs,
    num,
)
from pved.analysis.transfer_measures import (
    DEFINITIONS,
    FAMILY_ALPHA,
    INSIDE_AA,
    aa_entry,
    beside_aa,
    holm_adjusted,
    judged_methods,
    measures_markdown,
    method_measures,
)
from pved.provenance import UNKNOWN, fingerprint_mismatch
from pved.record_paths import record_path


def combine(verdicts: Sequence[str]) -> str:
    """A claim's verdict from its parts': ``holds`` if every part holds, ``does not hold``
    if any part does not, else (and for no parts) ``undecided``."""
    if verdicts and all(v == HOLDS for v in verdicts):
        return HOLDS
    if any(v == NOT_HOLD for v in verdicts):
        return NOT_HOLD
    return UNDECIDED


@dataclass(frozen=True)
class Claim:
    """One of the paper's claims: its statement and how to build its parts."""

    number: int
    statement: str
    parts: Callable[[Judge], list[dict[str, Any]]]


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


def judge_claims(dirs: Sequence[Path], *, reps: int = REPS, seed: int = SEED) -> dict[str, Any]:
    """Verdicts on the seven claims from the protocol directories ``dirs`` (JSON-able);
    ``reps`` and ``seed``: the resampling (others than the project's only to measure how
    the verdicts depend on them).

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
    judge = Judge(pairs, reps=reps, seed=seed)
    claims = []
    for claim in CLAIMS:
        parts = claim.parts(judge)
        for part in parts:
            if "difference" in part:
                aa = aa_entry(judge, part["pair"], part["score"])
                part.update(beside_aa(part["difference"]["value"], aa))
        claims.append(
            {
                "claim": claim.number,
                "statement": claim.statement,
                "verdict": combine([p["verdict"] for p in parts]),
                "parts": parts,
            }
        )
    family = family_wise(claims)
    made_under, warnings = _fingerprints(pairs, claims)
    inputs: dict[str, dict[str, Any]] = {}
    for p in pairs.values():
        where = record_path(p.directory)
        inputs.setdefault(where, {"dir": where, "budget": p.budget})
        inputs[where].setdefault("pairs", []).append(p.name)
    return {
        "inputs": list(inputs.values()),
        "pairs": {
            p.name: {
                "metric": p.metric,
                "dir": record_path(p.directory),
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
            f"have no source and draw seeds only; {reps} resamples, seed {seed}",
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
            f"(1 + count) / (1 + {reps}) over the resampled differences d* (PPO against "
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
            "transfer measures and A/A": DEFINITIONS,
        },
        "family": family,
        "claims": claims,
        "transfer_measures": [method_measures(pairs, m, judge) for m in judged_methods(pairs)],
        # the numeric fingerprints each method's runs were made under (pved.provenance),
        # and a line for each compared pair of methods not all made under one known one
        "fingerprints": made_under,
        "fingerprint_warnings": warnings,
    }


def _fingerprints(
    pairs: Mapping[str, PairSummary], claims: Sequence[dict[str, Any]]
) -> tuple[dict[str, dict[str, dict[str, int]]], list[str]]:
    """Each pair's methods' fingerprint counts, from summary.json (a summary written
    before fingerprints: all its runs unknown), and the warnings of the parts whose two
    methods were not all made under one known fingerprint; each such part gets its
    ``fingerprint_warning``."""
    made_under = {
        p.name: {m: _made_under(e or {}) for m, e in p.methods.items()} for p in pairs.values()
    }
    warnings: list[str] = []
    for claim in claims:
        for part in claim["parts"]:
            if len(part.get("groups") or []) != 2:
                continue
            a, b = (g["method"] for g in part["groups"])
            counts = made_under.get(part["pair"], {})
            mismatch = fingerprint_mismatch(counts.get(a, {}), counts.get(b, {}))
            if mismatch is not None:
                part["fingerprint_warning"] = mismatch
                line = f"{part['pair']}: {a} and {b} were {mismatch}"
                if line not in warnings:
                    warnings.append(line)
    return made_under, warnings


def _made_under(method_summary: Mapping[str, Any]) -> dict[str, int]:
    """A method's fingerprint counts in summary.json; its runs all unknown where the
    summary was written before fingerprints."""
    counts = method_summary.get("fingerprints")
    if isinstance(counts, dict) and counts:
        return {str(fp): int(n) for fp, n in counts.items()}
    runs = len(method_summary.get("runs") or [])
    return {UNKNOWN: runs} if runs else {}


# ---------------------------------------------------------------------------- report


def _ci(ci: Sequence[float]) -> str:
    return f"[{num(ci[0])}, {num(ci[1])}]"


def _p(p: float | None) -> str:
    return "–" if p is None else f"{p:.3f}" if p >= 0.001 else f"{p:.1e}"


def _group_cell(g: dict[str, Any]) -> str:
    runs = f"n={g['runs']}"
    if g.get("sources"):
        runs += f": {g['sources']} sources × {g['seeds']} seeds"
    elif "seeds" in g and g["seeds"] != g["runs"]:
        runs += f": {g['seeds']} seeds"
    return f"{g['method']} {num(g['mean'])} {_ci(g['mean_ci'])} ({runs})"


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
            cells.append(f"bar {num(part['bar'])} ({part['bar_of']})")
        else:
            diff = part["difference"]
            cell = f"{num(diff['value'])} {_ci(diff['ci'])}"
            if "margin" in part:
                cell += f"; margin ±{num(part['margin'])} ({part['margin_of']})"
            cells.append(f"{cell}; A/A: {_aa(part)}")
        cells.append(f"{_p(part.get('p'))} ({_p(part.get('p_holm'))})")
        cells.append(_steps_cell(part))
    else:
        cells += ["–"] * 5
    return "| " + " | ".join(c.replace("|", "/") for c in cells) + " |"


def _aa(part: dict[str, Any]) -> str:
    """A part's A/A check: ppo-aa − ppo [CI] and the flag, or why there is none."""
    aa = part.get("aa", "–")
    if isinstance(aa, str):
        return aa
    flag = f", **{INSIDE_AA}**" if part.get("inside_aa") else ""
    return f"{num(aa['value'])} {_ci(aa['ci'])}{flag}"


def _matrix_cell(part: dict[str, Any] | None) -> str:
    if part is None:
        return ""
    cell = part["verdict"]
    if "difference" in part:
        cell += f" ({num(part['difference']['value'])})"
    if part.get("inside_aa"):
        cell += "; inside A/A noise"
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
    for warning in result.get("fingerprint_warnings", []):
        lines.append(f"- Warning: {warning}")
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
        "| part | pair | verdict | family-wise | A | B | difference [95% CI]; A/A: ppo-aa − "
        "ppo | p (Holm) | steps to PPO's final |\n|---|---|---|---|---|---|---|---|---|"
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
    if result.get("transfer_measures"):
        lines += ["", "## Transfer measures against plain PPO", ""]
        lines.append(result["definitions"]["transfer measures and A/A"])
        for table in result["transfer_measures"]:
            lines += ["", measures_markdown(table)]
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
