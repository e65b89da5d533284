"""A finished protocol's shaped methods read by source policy, and their tuning score
against their evaluation runs.

The protocol scores every β candidate on source policy 0 only (its tuning seeds), then
evaluates the chosen one on every source policy. This analysis says what that hides:

* per method and source policy, the evaluation runs' mean final score, and the Eq. 10
  term over the last tenth of each run's training rollouts: D (the logged shaping term
  over −β, so KL nats a step for the Gaussian-code methods, a squared distance for the
  point-code ones) and the term as a share of the env's own reward a step (mean term over
  mean env reward, over the source's runs). A source whose bank costs more shows there;
* per method, the chosen candidate's tuning runs (source 0) against its source-0
  evaluation runs, which share the model, β and source and differ only in the seed: in
  how many of the pairings the tuning run scored higher, and the exact two-sided
  Mann-Whitney p. It does not count that the candidate was picked for its tuning mean, so
  it says how far the tuning score over-rates the evaluation, not why.

    pved analyze source-reading reports/humanoid-ant-paper

Prints two Markdown tables and writes ``PROTOCOL_DIR/subspaces/source_reading.json``
(:func:`protocol_source_reading`; part of `make subspaces`). Runs restored from an archive
keep no rollout rows; a source whose runs have none gets no D.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import mannwhitneyu

from pved.analysis.curves import reward_scale
from pved.analysis.judge import load_summary
from pved.errors import PvedError
from pved.runs import atomic_write_json

TAIL = 0.1
"""The share of a run's rollout records, its last ones, that D is averaged over: one
rollout is noisy, and the end of training is where the term's cost is what the policy
settled on."""


def term_by_source(
    runs_root: Path, runs: list[dict[str, Any]], metric: str, beta: float
) -> dict[int, dict[str, Any]]:
    """Per source policy of a method's evaluation runs (``summary.json``'s ``runs``): the
    runs, their mean final ``metric``, and over the runs that logged rollouts (each
    averaged over its last :data:`TAIL` of rollouts, :func:`reward_scale`) the mean D
    (term / −β) and the term's share of the env reward (mean term / mean env reward)."""
    out: dict[int, dict[str, Any]] = {}
    for source in sorted({int(r["source_policy"]) for r in runs}):
        mine = [r for r in runs if int(r["source_policy"]) == source]
        scale = reward_scale([runs_root / r["key"] for r in mine], last_share=TAIL)
        entry: dict[str, Any] = {
            "runs": len(mine),
            "final_mean": float(np.mean([r[metric] for r in mine])),
            "runs_with_rollouts": 0 if scale is None else scale["runs"],
        }
        if scale is not None:
            term, env = scale["shaping_last"], scale["env_reward_last"]
            entry["d_tail"] = -term / beta
            entry["term_share_of_env_reward"] = -term / env if env != 0 else None
        out[source] = entry
    return out


def tuning_against_evaluation(tuning: list[float], evaluation: list[float]) -> dict[str, Any]:
    """How often a tuning score beats an evaluation score over all pairings (ties count
    half), with the two-sided Mann-Whitney p (scipy's "auto": exact for small samples
    without ties; None when either side is empty)."""
    t, e = np.asarray(tuning, dtype=float), np.asarray(evaluation, dtype=float)
    wins = float((t[:, None] > e[None, :]).sum() + 0.5 * (t[:, None] == e[None, :]).sum())
    p = None
    if len(t) and len(e):
        p = float(mannwhitneyu(t, e, alternative="two-sided").pvalue)
    return {
        "tuning_mean": float(t.mean()) if len(t) else None,
        "evaluation_mean": float(e.mean()) if len(e) else None,
        "tuning_wins": wins,
        "pairings": int(len(t) * len(e)),
        "p_two_sided": p,
    }


def _cells(
    sources: dict[int, dict[str, Any]], key: str, fmt: str, scale: float = 1.0, unit: str = ""
) -> str:
    """One table cell: ``key`` of every source, " / " between, "–" where it is missing."""
    return " / ".join(
        "–" if s.get(key) is None else format(scale * s[key], fmt) + unit for s in sources.values()
    )


def protocol_source_reading(protocol: Path) -> tuple[dict[str, Any], str]:
    """Both tables of the module docstring for every shaped method of the finished
    protocol directory ``protocol``.

    Writes ``protocol/subspaces/source_reading.json`` and returns its content with the
    tables as Markdown; a directory that is no finished protocol, a missing evaluation run,
    a foreign ``metrics.jsonl`` or a chosen candidate not once in the selection raises
    :class:`PvedError`, and nothing is written."""
    summary = load_summary(protocol)
    runs_root = protocol / "runs"
    result: dict[str, Any] = {"tail": TAIL, "pairs": {}}
    by_source_lines, tuning_lines = [], []
    for pair, entry in summary["pairs"].items():
        metric = entry["metric"]
        for method, state in entry["methods"].items():
            beta = state.get("beta")
            if beta is None:  # plain PPO and the oracle have no term and no source
                continue
            runs = state["runs"]
            missing = [
                r["key"] for r in runs if not (runs_root / r["key"] / "metrics.jsonl").is_file()
            ]
            if missing:
                raise PvedError(
                    f"{runs_root / missing[0]}: an evaluation run is not in this directory"
                )
            try:
                sources = term_by_source(runs_root, runs, metric, float(beta))
            except (ValueError, KeyError) as exc:  # json's decode error is a ValueError
                raise PvedError(
                    f"{pair}/{method}: a run's metrics.jsonl is not pved's ({exc})"
                ) from exc
            chosen = [
                c
                for c in summary["selection"][pair][method]["candidates"]
                if c["beta"] == beta and c["init"] == state["init"]
            ]
            if len(chosen) != 1:
                raise PvedError(
                    f"{pair}/{method}: the chosen candidate is not once in the selection"
                )
            check = tuning_against_evaluation(
                chosen[0]["scores"], [r[metric] for r in runs if int(r["source_policy"]) == 0]
            )
            result["pairs"].setdefault(pair, {})[method] = {
                "beta": beta,
                "init": state["init"],
                "by_source": sources,
                "tuning_against_source0_evaluation": check,
            }

            by_source_lines.append(
                f"| {pair} | {method} | {beta:g} | {_cells(sources, 'final_mean', '.2f')} | "
                f"{_cells(sources, 'd_tail', '.3g')} | "
                f"{_cells(sources, 'term_share_of_env_reward', '.2g', 100, '%')} |"
            )
            p = "–" if check["p_two_sided"] is None else f"{check['p_two_sided']:.3f}"
            tuning_lines.append(
                f"| {pair} | {method} | {check['tuning_mean']:.2f} | "
                f"{check['evaluation_mean']:.2f} | {check['tuning_wins']:g} of "
                f"{check['pairings']} | {p} |"
            )
    lines = [
        f"| pair | method | β | final mean by source | D, last {TAIL:.0%} of "
        "rollouts, by source | term / env reward, by source |",
        "|---|---|---|---|---|---|",
        *by_source_lines,
        "",
        "| pair | method | tuning mean (source 0) | evaluation mean, source 0 "
        "| tuning run ahead | Mann-Whitney p (two-sided) |",
        "|---|---|---|---|---|---|",
        *tuning_lines,
    ]
    out = protocol / "subspaces" / "source_reading.json"
    atomic_write_json(out, result)
    return result, "\n".join(lines)
