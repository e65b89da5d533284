"""A transfer method against plain PPO judged the way the transfer-learning literature
does (Taylor & Stone 2009, "Transfer learning for reinforcement learning domains: a
survey", section 2.1), and every comparison's own noise floor, the A/A check.

The measures, each per run and then as the difference of the two methods' means, A −
PPO, with the 95% two-level bootstrap over source policies and PPO seeds of ``pved
claims`` (:meth:`pved.analysis.judge.Judge.difference`: resamples
:data:`pved.analysis.judge.REPS`, seed :data:`pved.analysis.judge.SEED`) and its
two-sided p-value of 0, Holm-adjusted over the pairs (one family per method and
measure, :func:`holm_adjusted`):

- ``auc``: the area under the run's evaluation curve, normalised by its step span, so
  on the metric's scale (:func:`pved.analysis.run_curves.auc`): the "total reward"
  measure, which rewards learning early as well as ending high;
- ``jumpstart``: the run's first evaluation point. The protocol evaluates at step 0,
  before any update, and no method here transfers a policy, so a jumpstart other than 0
  is noise between initial networks; it is reported because the field reports it;
- ``reach``: the steps the run's curve takes to reach plain PPO's final (the mean of
  PPO's last evaluation points on the pair; "time to threshold"), a run that never
  reaches it counted one evaluation interval past its last step (a lower bound; the
  runs that reach it are counted). Lower is faster;
- ``final``: the run's final score (the protocol's final evaluation; ``pved claims``'
  "beats").

A/A: the protocol's ``ppo-aa`` reference is plain PPO again, the same code and reward,
on a block of seeds no other method uses; ppo-aa − PPO is a difference that is 0 in
truth, so its interval shows how large a difference these runs produce by chance. Its
noise floor is the largest |difference| that interval admits, max(|lo|, |hi|)
(:func:`aa_noise`); a comparison whose |A − B| is no larger is flagged
:data:`INSIDE_AA` ("inside A/A noise"): its difference is no bigger than two identical
methods' can be. Where the pair has no ppo-aa runs the output says :data:`NO_AA`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pved.analysis.judge import (
    AA_REFERENCE,
    FOUR,
    REPS,
    SEED,
    Judge,
    PairSummary,
    method_curves,
    num,
    ppo_final_point,
)

FAMILY_ALPHA = 0.05
"""Family-wise error rate of the Holm–Bonferroni view over one judgement's tests."""


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


MEASURES = ("auc", "jumpstart", "reach", "final")
"""Taylor & Stone's measures, in the order the tables give them."""
MEASURE_NAMES = {
    "auc": "AUC (normalised)",
    "jumpstart": "jumpstart",
    "reach": "steps to ppo's final",
    "final": "final score",
}
BASELINE = "ppo"
REFERENCES = ("ppo", AA_REFERENCE, "oracle")
"""The references of a protocol: not methods judged against PPO."""
INSIDE_AA = "inside A/A noise"
NO_AA = "no A/A set"
EXPLORATORY = "exploratory"
"""The label of a method beyond the paper evaluated at the paper's budget without a valid
pre-registration (``pved protocol --exploratory``; docs/decisions/protocol.md)."""

DEFINITIONS = (
    "Transfer measures (Taylor & Stone 2009), per run, then the difference of means "
    "A − ppo with its 95% two-level bootstrap interval (source policies and seeds, "
    f"{REPS} resamples, seed {SEED}) and p-value of 0, Holm-adjusted over the pairs per "
    "measure: AUC = the trapezoid area under the evaluation curve divided by its step "
    "span (on the metric's scale); jumpstart = the first evaluation point (step 0: no "
    "method here transfers a policy, so this is noise between initial networks); steps "
    "to ppo's final = the first evaluation step at which the run reaches ppo's final "
    "(the mean of ppo's last evaluation points), a run that never does counted one "
    "evaluation past its last (a lower bound; lower is faster); final = the final "
    "evaluation. A/A: ppo-aa (plain PPO again on seeds no other method uses) − ppo, "
    "the same bootstrap; a difference whose magnitude is at most the A/A interval's "
    "largest magnitude, max(|lo|, |hi|), is flagged 'inside A/A noise'; 'no A/A set' "
    "where the pair has no ppo-aa runs."
)


def aa_noise(ci: Sequence[float]) -> float:
    """The A/A noise floor of an A/A interval ``ci``: the largest |difference| it
    admits, max(|lo|, |hi|)."""
    return max(abs(float(ci[0])), abs(float(ci[1])))


def aa_entry(judge: Judge, pair: str, score: str) -> dict[str, Any] | str:
    """ppo-aa − ppo of ``score`` on ``pair``: ``{"value", "ci", "noise"}`` (:func:`aa_noise`),
    or :data:`NO_AA` (with why, where there are runs that cannot be compared)."""
    p = judge.pairs.get(pair)
    if p is None or not (p.methods.get(AA_REFERENCE) or {}).get("runs"):
        return NO_AA
    d = judge.difference(pair, AA_REFERENCE, BASELINE, score)
    if isinstance(d, str):
        return f"{NO_AA} for this score ({d})"
    return {"value": d["value"], "ci": d["ci"], "noise": aa_noise(d["ci"])}


def beside_aa(value: float, aa: dict[str, Any] | str) -> dict[str, Any]:
    """``{"aa": aa, "inside_aa": whether |value| is at most the A/A noise (None: no A/A
    set)}``: what a comparison of difference ``value`` carries beside its verdict."""
    inside = abs(value) <= aa["noise"] if isinstance(aa, dict) else None
    return {"aa": aa, "inside_aa": inside}


def reached(pairs: dict[str, PairSummary], pair: str, method: str) -> int | None:
    """How many of ``method``'s runs on ``pair`` reach PPO's final (None: not known)."""
    p, threshold = pairs.get(pair), ppo_final_point(pairs, pair)
    curves = method_curves(p, method) if p is not None and method in p.methods else "none"
    if isinstance(threshold, str) or isinstance(curves, str):
        return None
    return sum(bool(np.any(v >= threshold)) for _, v in curves)


def is_exploratory(pair: PairSummary, method: str) -> bool:
    """Whether the protocol's summary marks ``method``'s results on ``pair`` exploratory."""
    return bool((pair.methods.get(method) or {}).get(EXPLORATORY))


def method_measures(
    pairs: dict[str, PairSummary], method: str, judge: Judge | None = None
) -> dict[str, Any]:
    """``method`` against PPO on every pair of ``pairs`` (Fig. 3's order first), by
    :data:`MEASURES`. Returns ``{"method", "against", "exploratory": [pairs whose
    results are exploratory], "pairs": {pair: {measure: cell}}}``; a cell is ``{"reason"}``
    where it cannot be computed (no runs, "no curves ...", a PPO that did not improve),
    else ``{"value", "ci", "p", "p_holm", "method_mean", "ppo_mean", "runs", "aa",
    "inside_aa"}`` (``reach``: also ``reached``, the runs that got there)."""
    judge = judge if judge is not None else Judge(pairs)
    order = [p for p in FOUR if p in pairs] + sorted(set(pairs) - set(FOUR))
    table: dict[str, dict[str, dict[str, Any]]] = {pair: {} for pair in order}
    for measure in MEASURES:
        for pair in order:
            d = judge.difference(pair, method, BASELINE, measure)
            if isinstance(d, str):
                table[pair][measure] = {"reason": d}
                continue
            cell: dict[str, Any] = {
                "value": d["value"],
                "ci": d["ci"],
                "p": d["p"],
                "method_mean": d["a"]["mean"],
                "ppo_mean": d["b"]["mean"],
                "runs": d["a"]["runs"],
            }
            if measure == "reach":
                cell["reached"] = reached(pairs, pair, method)
                cell["threshold"] = ppo_final_point(pairs, pair)
            cell.update(beside_aa(d["value"], aa_entry(judge, pair, measure)))
            table[pair][measure] = cell
        tested = [pair for pair in order if "p" in table[pair][measure]]
        adjusted = holm_adjusted([table[pair][measure]["p"] for pair in tested])
        for pair, p_holm in zip(tested, adjusted, strict=True):
            table[pair][measure]["p_holm"] = p_holm
    return {
        "method": method,
        "against": BASELINE,
        "exploratory": [p for p in order if is_exploratory(pairs[p], method)],
        "pairs": table,
    }


def judged_methods(pairs: dict[str, PairSummary]) -> list[str]:
    """The methods of ``pairs`` that are not references, in the order first met."""
    found: dict[str, None] = {}
    for p in pairs.values():
        for m, entry in p.methods.items():
            if m not in REFERENCES and (entry or {}).get("runs"):
                found.setdefault(m)
    return list(found)


def _value(measure: str, x: float, signed: bool = False) -> str:
    if measure == "reach":
        return f"{x:+,.0f}" if signed else f"{x:,.0f}"
    return f"{x:+.3f}" if signed else num(x)


def _interval(measure: str, ci: Sequence[float]) -> str:
    return f"[{_value(measure, ci[0], True)}, {_value(measure, ci[1], True)}]"


def aa_cell(measure: str, aa: dict[str, Any] | str, inside: bool | None) -> str:
    """The A/A cell beside a comparison: ppo-aa − ppo [CI], and the flag."""
    if isinstance(aa, str):
        return aa
    cell = f"{_value(measure, aa['value'], True)} {_interval(measure, aa['ci'])}"
    return cell + (f"; **{INSIDE_AA}**" if inside else "")


def p_text(p: float) -> str:
    """A p-value as the tables print it: 3 decimals, or 1.2e-04 below 0.001."""
    return f"{p:.3f}" if p >= 0.001 else f"{p:.1e}"


def measures_markdown(result: dict[str, Any]) -> str:
    """One method's :func:`method_measures` as a markdown table (a row per pair and
    measure), with its exploratory label where it has one."""
    method = result["method"]
    label = ""
    if result["exploratory"]:
        label = f" — **{EXPLORATORY}** on {', '.join(result['exploratory'])} (not pre-registered)"
    lines = [
        f"### {method} against {result['against']}: transfer measures{label}",
        "",
        f"| pair | measure | {method} | ppo | {method} − ppo [95% CI] | p (Holm over pairs) "
        "| A/A: ppo-aa − ppo [95% CI] |",
        "|---|---|---|---|---|---|---|",
    ]
    for pair, cells in result["pairs"].items():
        for measure in MEASURES:
            c = cells[measure]
            name = MEASURE_NAMES[measure]
            if "reason" in c:
                lines.append(f"| {pair} | {name} | {c['reason']} | – | – | – | – |")
                continue
            mine = _value(measure, c["method_mean"])
            if measure == "reach" and c.get("reached") is not None:
                mine += f" ({c['reached']} of {c['runs']} reach it)"
            diff = f"{_value(measure, c['value'], True)} {_interval(measure, c['ci'])}"
            lines.append(
                f"| {pair} | {name} | {mine} | {_value(measure, c['ppo_mean'])} | {diff} | "
                f"{p_text(c['p'])} ({p_text(c['p_holm'])}) | "
                f"{aa_cell(measure, c['aa'], c['inside_aa'])} |"
            )
    return "\n".join(lines)
