"""Issue 64's goal, judged from the records: does a method beyond the paper learn faster
than PPO on most pairs without ending behind it anywhere?

The goal, as issue 64 sets it: at the paper's budget, the method's area under the learning
curve is larger than PPO's on at least :data:`AUC_AHEAD_NEEDED` of the four pairs (the
95% interval above 0 after Holm over the pairs: a Holm-adjusted p-value of 0 below
:data:`~pved.analysis.transfer_measures.FAMILY_ALPHA` with a positive difference), and
its final score is behind on no pair: neither behind PPO nor behind the pooled runs of
the PPO algorithm (``ppo`` and its A/A set ``ppo-aa``, one code, two seed blocks: the
larger baseline a reviewer would pool). "Behind" is the unadjusted 95% interval below 0,
the stricter reading for a method that must do no harm.

The goal is judged only where it can be: every pair of the four present, each at a budget
of the paper's length (:data:`PAPER_BUDGETS`) with at least :func:`runs_needed` runs of
the method and of PPO (issue 64's counts: 45 where runs end near 0 or 1, 15 elsewhere),
an A/A set (``ppo-aa``) to pool with PPO, and no result marked exploratory (a method
evaluated without its pre-registration).
Otherwise the verdict is "not judged" and says which condition is unmet; where the only
gap is a pair not yet compared, it is "not reached" as soon as the pairs present already
miss the goal. Either way the table beside it says by how much the method stands on each
pair.

The numbers are :func:`pved.analysis.transfer_measures.method_measures`' (the two-level
bootstrap of ``pved claims``); only records are read.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from pved.analysis.judge import AA_REFERENCE, FOUR, REPS, SEED, Judge, PairSummary
from pved.analysis.transfer_measures import BASELINE, FAMILY_ALPHA, p_text

AUC_AHEAD_NEEDED = 3
"""Pairs of the four on which the method's AUC must be above PPO's (after Holm)."""
PAPER_BUDGETS = ("paper", "paper-45", "paper-wide")
"""The protocol budgets whose runs are the paper's length (``steps_of`` paper in
:data:`pved.config.BUDGETS`, not imported here: it pulls in torch; a test holds the two
together)."""
RUNS_NEEDED = {"reacher": 45, "jaco-fetch": 45}
"""Issue 64's run counts where runs end near 0 or 1; :data:`RUNS_ELSEWHERE` on the others."""
RUNS_ELSEWHERE = 15
POOLED = "ppo+ppo-aa"
"""The pooled runs of the PPO algorithm: plain PPO and its A/A set."""
NEEDS = (
    f"AUC above ppo's (95% CI > 0 after Holm) on >= {AUC_AHEAD_NEEDED} of {len(FOUR)} pairs; "
    f"final score behind ({BASELINE} or the pooled {POOLED}) on none; at the paper's budget "
    f"with >= {RUNS_NEEDED['reacher']} runs on {' and '.join(RUNS_NEEDED)}, "
    f">= {RUNS_ELSEWHERE} elsewhere; pre-registered"
)


def runs_needed(pair: str) -> int:
    """Issue 64's least number of runs of the method and of PPO on ``pair``."""
    return RUNS_NEEDED.get(pair, RUNS_ELSEWHERE)


def _runs(pair: PairSummary, method: str) -> list[dict[str, Any]]:
    runs: list[dict[str, Any]] = (pair.methods.get(method) or {}).get("runs", [])
    return runs


def pooled_final(
    pairs: dict[str, PairSummary], method: str, reps: int = REPS, seed: int = SEED
) -> dict[str, dict[str, Any]]:
    """Per pair with ``ppo-aa`` runs: ``method`` − (``ppo`` ∪ ``ppo-aa``) of the final
    score, ``{"value", "ci", "p", "runs"}`` (the pooled runs, each key once), or
    ``{"reason"}``; ``reps``, ``seed``: the bootstrap's resampling (the project's
    :data:`REPS` and :data:`SEED`).
    The pairs are copied: the caller's summaries are left as they are."""
    pooled: dict[str, PairSummary] = {}
    for name, p in pairs.items():
        if not _runs(p, AA_REFERENCE):
            continue
        seen: dict[str, dict[str, Any]] = {}
        for r in _runs(p, BASELINE) + _runs(p, AA_REFERENCE):
            seen.setdefault(str(r.get("key")), r)
        methods = {method: p.methods.get(method) or {}, POOLED: {"runs": list(seen.values())}}
        pooled[name] = dataclasses.replace(p, methods=methods, _cache={})
    judge = Judge(pooled, reps=reps, seed=seed)
    out: dict[str, dict[str, Any]] = {}
    for name in pooled:
        d = judge.difference(name, method, POOLED, "final")
        out[name] = (
            {"reason": d}
            if isinstance(d, str)
            else {"value": d["value"], "ci": d["ci"], "p": d["p"], "runs": d["b"]["runs"]}
        )
    return out


def _behind(cell: dict[str, Any]) -> bool:
    return "ci" in cell and float(cell["ci"][1]) < 0


def transfer_goal(
    pairs: dict[str, PairSummary],
    method: str,
    measures: dict[str, Any],
    reps: int = REPS,
    seed: int = SEED,
) -> dict[str, Any]:
    """Issue 64's goal for ``method`` over ``pairs`` (see the module's docstring), from
    its transfer ``measures`` (:func:`~pved.analysis.transfer_measures.method_measures`
    over the same pairs; ``reps``, ``seed``: the pooled comparison's resampling). Returns
    ``{"needs", "verdict" ("reached", "not reached", "not judged"), "why", "auc_ahead",
    "final_behind", "pooled_behind", "unmet" (the conditions not met), "absent" (pairs
    not compared), "rows"}``; a row per pair of the four gives by how much."""
    cells = measures["pairs"]
    pooled = pooled_final(pairs, method, reps, seed)
    rows: list[dict[str, Any]] = []
    unmet: list[str] = []  # the conditions of a judgement: budget, run counts, registration
    absent: list[str] = []  # pairs with no comparison: not run, or no curves to read
    for name in FOUR:
        auc = cells.get(name, {}).get("auc", {"reason": "no runs"})
        if "reason" in auc:
            absent.append(name)
            rows.append({"pair": name, "reason": auc["reason"]})
            continue
        p, final = pairs[name], cells[name]["final"]
        row: dict[str, Any] = {
            "pair": name,
            "budget": p.budget,
            "runs": {m: len(_runs(p, m)) for m in (method, BASELINE)},
            "auc": {k: auc[k] for k in ("value", "ci", "p", "p_holm")},
            "final": {k: final[k] for k in ("value", "ci", "p")},
            "pooled_final": pooled.get(name, {"reason": f"no {AA_REFERENCE} runs"}),
        }
        row["auc_ahead"] = auc["value"] > 0 and auc["p_holm"] < FAMILY_ALPHA
        row["final_behind"] = _behind(final)
        row["pooled_behind"] = _behind(row["pooled_final"])
        if p.budget not in PAPER_BUDGETS:
            unmet.append(f"{name}: budget {p.budget!r} is not the paper's")
        fewest = min(row["runs"].values())
        if fewest < runs_needed(name):
            unmet.append(f"{name}: {fewest} runs, needs {runs_needed(name)}")
        if "reason" in row["pooled_final"]:
            unmet.append(f"{name}: {row['pooled_final']['reason']} (no A/A set to pool)")
        if name in measures.get("exploratory", []):
            unmet.append(f"{name}: exploratory (not pre-registered)")
        rows.append(row)
    judged = [r for r in rows if "reason" not in r]
    ahead = [r["pair"] for r in judged if r["auc_ahead"]]
    behind = [r["pair"] for r in judged if r["final_behind"]]
    pooled_behind = [r["pair"] for r in judged if r["pooled_behind"]]
    counts = (
        f"AUC ahead on {len(ahead)} of {len(FOUR)} (needs {AUC_AHEAD_NEEDED}), final behind "
        f"{BASELINE} on {len(behind)} and {POOLED} on {len(pooled_behind)} (needs 0)"
    )
    # Pairs not yet compared can only add to those ahead: where all of them could not make
    # the count, or a pair is behind already, the goal is missed whatever they show.
    out_of_reach = bool(behind or pooled_behind) or len(ahead) + len(absent) < AUC_AHEAD_NEEDED
    if unmet:
        verdict, why = "not judged", f"{'; '.join(unmet)} (standing now: {counts})"
    elif absent and out_of_reach:
        verdict, why = "not reached", f"{counts}, whatever {', '.join(absent)} show(s)"
    elif absent:
        verdict, why = "not judged", f"no comparison on {', '.join(absent)} ({counts})"
    else:
        verdict, why = ("not reached" if out_of_reach else "reached"), counts
    return {
        "needs": NEEDS,
        "verdict": verdict,
        "why": why,
        "auc_ahead": ahead,
        "final_behind": behind,
        "pooled_behind": pooled_behind,
        "unmet": unmet,
        "absent": absent,
        "rows": rows,
    }


def _diff(cell: dict[str, Any]) -> str:
    if "reason" in cell:
        return str(cell["reason"])
    lo, hi = cell["ci"]
    return f"{cell['value']:+.3f} [{lo:+.3f}, {hi:+.3f}]"


def transfer_goal_markdown(method: str, goal: dict[str, Any]) -> str:
    """The goal's verdict and its by-how-much table, as markdown."""
    lines = [
        f"### {method}: issue 64's transfer goal",
        "",
        f"Needs: {goal['needs']}. **{goal['verdict']}**: {goal['why']}.",
        "",
        f"| pair | runs ({method}, ppo) | AUC − ppo [95% CI] | p (Holm) | final − ppo [95% CI] "
        f"| final − {POOLED} [95% CI] (runs) | standing |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in goal["rows"]:
        if "reason" in r:
            lines.append(f"| {r['pair']} | {r['reason']} ||||||")
            continue
        pooled = r["pooled_final"]
        pooled_cell = _diff(pooled) + (f" ({pooled['runs']})" if "runs" in pooled else "")
        marks = [
            "AUC ahead" if r["auc_ahead"] else "AUC not ahead",
            *(["final behind ppo"] if r["final_behind"] else []),
            *([f"final behind {POOLED}"] if r["pooled_behind"] else []),
        ]
        lines.append(
            f"| {r['pair']} | {r['runs'][method]}, {r['runs'][BASELINE]} | {_diff(r['auc'])} "
            f"| {p_text(r['auc']['p'])} ({p_text(r['auc']['p_holm'])}) | {_diff(r['final'])} "
            f"| {pooled_cell} | {', '.join(marks)} |"
        )
    return "\n".join(lines)
