"""One transfer method against plain PPO across pairs: does it pay off on every pair?

The table a researcher asks for before trusting a method: per pair, the final score of
plain PPO, the paper's PVED, the method and the oracle, each a mean with its 95% CI; the
method's difference from PPO with its CI and p-value; and the steps the method's mean
curve takes to reach PPO's final mean, against PPO's own steps. Beneath it, the verdict
of the goal the project set itself (issue 51): the method is ahead of PPO (CI of the
difference above 0) on at least :data:`AHEAD_NEEDED` of the four pairs and behind it (CI
below 0) on none, and on those pairs its mean curve reaches PPO's final mean within
:data:`SPEED_FRACTION` of PPO's steps. With fewer pairs than four the goal is not judged,
unless it is already out of reach (a pair behind, or too few left to be ahead on).

The comparison is ``pved claims``' test "beats" (:meth:`pved.analysis.judge.Judge.beats`:
the same two-level bootstrap over source policies and PPO seeds, resamples and seed), so
the intervals carry the variation between source policies as well as between seeds. A
column's CI is the method's own (:meth:`pved.analysis.judge.Judge.mean`), the same on
every pair's row and every page.

The inputs are finished ``pved protocol`` directories (``summary.json``): a pair may come
from several, say the method's screen and the protocol that ran PVED and the oracle,
provided they were run at one budget and any method found in two of them is the same
runs (a screen reusing another protocol's PPO runs through ``--stages-from`` is). The
steps to PPO's final are the protocols' own (``steps_to_ppo_final`` in each summary,
against the PPO runs checked to be the same).

Beside each pair's standing its A/A check, ppo-aa − ppo on the final score ("inside A/A
noise" where the method's |difference| is no larger; "no A/A set" without ppo-aa runs),
and after the goal issue 64's goal (the area under the learning curve ahead on three
pairs after Holm, the final score behind PPO and the pooled PPO runs on none, at the
paper's budget: :mod:`pved.analysis.transfer_goal`) with its table of by how much, then
the method against PPO by the field's transfer measures (AUC, jumpstart, steps to PPO's
final, final; Holm over the pairs; :mod:`pved.analysis.transfer_measures`). A method
whose results the protocol marks exploratory (evaluated at the paper's budget without a
pre-registration) is labelled so.

Only ``summary.json`` files are read, and for the measures off the curves each run's
``metrics.jsonl`` or, in a published directory, the committed record of its curves.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pved.analysis.judge import (
    FOUR,
    HOLDS,
    NOT_HOLD,
    Judge,
    PairSummary,
    check_pair,
    load_summary,
)
from pved.analysis.transfer_goal import transfer_goal, transfer_goal_markdown
from pved.analysis.transfer_measures import (
    DEFINITIONS,
    EXPLORATORY,
    aa_cell,
    aa_entry,
    beside_aa,
    is_exploratory,
    measures_markdown,
    method_measures,
)
from pved.errors import PvedError

AHEAD_NEEDED = 3
"""Pairs of the four on which the method must be ahead of PPO (the goal)."""
SPEED_FRACTION = 0.5
"""On those pairs its mean curve must reach PPO's final mean within this fraction of PPO's
steps (the goal)."""
BASELINES = ("ppo", "pved", "oracle")
"""The columns beside the method: plain PPO (the reference), the paper's PVED, the oracle."""

AHEAD, BEHIND, LEVEL = "ahead", "behind", "level"


def parse_input(text: str | Path) -> tuple[Path, str | None]:
    """A DIR argument: ``DIR`` (every method of it) or ``METHOD=DIR`` (only METHOD's runs,
    e.g. the oracle of a protocol whose PVED runs predate a fix). An existing path is
    always a DIR."""
    path = Path(text)
    if path.exists() or "=" not in str(text):
        return path, None
    method, _, directory = str(text).partition("=")
    if not method or not directory:
        raise PvedError(f"{text}: want DIR or METHOD=DIR")
    return Path(directory), method


def load_merged(inputs: Sequence[str | Path]) -> dict[str, PairSummary]:
    """Every pair of the protocol directories ``inputs`` (:func:`parse_input`), a pair's
    methods gathered from all the directories that ran it. Raises PvedError (one line) for
    no input, one given twice, a DIR without a valid summary.json, a ``METHOD=DIR`` whose
    DIR has no runs of METHOD, a pair found at two budgets, or a method of one pair found
    in two inputs with different runs."""
    if not inputs:
        raise PvedError("scoreboard needs at least one protocol directory")
    parsed = [parse_input(i) for i in inputs]
    seen = [(d.resolve(), m) for d, m in parsed]
    twice = next((d for i, (d, m) in enumerate(seen) if (d, m) in seen[:i]), None)
    if twice is not None:
        raise PvedError(f"{twice} is given twice: give each protocol directory once")
    pairs: dict[str, PairSummary] = {}
    origin: dict[tuple[str, str], Path] = {}
    for directory, only in parsed:
        summary = load_summary(directory)
        budget = str(summary.get("budget", "?"))
        taken = 0
        for name, entry in summary["pairs"].items():
            metric, methods = check_pair(directory / "summary.json", name, entry)
            if only is not None:
                methods = {k: v for k, v in methods.items() if k == only}
                if not methods:
                    continue
            taken += 1
            pair = pairs.setdefault(name, PairSummary(name, metric, directory, budget, {}))
            if pair.budget != budget or pair.metric != metric:
                raise PvedError(
                    f"pair {name!r}: {pair.directory} is at the {pair.budget!r} budget "
                    f"({pair.metric}), {directory} at {budget!r} ({metric}): "
                    "give one budget per pair"
                )
            for method, m in methods.items():
                if method in pair.methods and _run_values(pair.methods[method], metric) != (
                    _run_values(m, metric)
                ):
                    raise PvedError(
                        f"{name}/{method} has different runs in {origin[(name, method)]} "
                        f"and {directory}: take each method from one (METHOD=DIR)"
                    )
                pair.methods.setdefault(method, m)
                origin.setdefault((name, method), directory)
        if only is not None and not taken:
            raise PvedError(f"{only}={directory}: no runs of {only} there")
    return pairs


def _run_values(m: dict[str, Any], metric: str) -> list[tuple[Any, float]]:
    """A method's runs as (key, score), sorted: what makes two summaries' runs the same."""
    return sorted((str(r.get("key")), float(r[metric])) for r in m.get("runs", []))


def _ppo_steps(pair: PairSummary) -> int | None:
    """PPO's steps: the last step of its mean curve in the summary."""
    steps = (pair.methods.get("ppo") or {}).get("curve_steps")
    return int(steps[-1]) if isinstance(steps, list) and steps else None


def _baseline_columns(judge: Judge, pair: PairSummary) -> dict[str, Any]:
    """The columns of PVED and the oracle (each from its own comparison with PPO) and of
    PPO (from the first of those, or from PPO against itself when neither ran)."""
    columns: dict[str, Any] = {}
    for m in BASELINES[1:]:
        if not (pair.methods.get(m) or {}).get("runs"):
            continue
        for group in judge.beats(pair.name, m, "ppo").get("groups", []):
            columns.setdefault(group["method"], {k: group[k] for k in ("runs", "mean", "mean_ci")})
    if "ppo" not in columns and (pair.methods.get("ppo") or {}).get("runs"):
        for group in judge.beats(pair.name, "ppo", "ppo").get("groups", [])[:1]:
            columns["ppo"] = {k: group[k] for k in ("runs", "mean", "mean_ci")}
    return columns


def pair_row(
    pairs: dict[str, PairSummary], name: str, method: str, judge: Judge | None = None
) -> dict[str, Any]:
    """One pair's row: each column's runs, mean and CI; the method's difference from PPO,
    its standing (ahead, behind, level) and its speed; or the reason it is missing.
    ``judge``: one over ``pairs`` to share (default: a new one, the project's resampling)."""
    pair = pairs[name]
    row: dict[str, Any] = {"pair": name, "metric": pair.metric, "budget": pair.budget}
    missing = [m for m in (method, "ppo") if not (pair.methods.get(m) or {}).get("runs")]
    judge = judge if judge is not None else Judge(pairs)
    if missing:
        row["reason"] = f"no runs of {' or '.join(missing)} on {name}"
        if missing == [method]:  # the baselines still give the pair's scale
            row["columns"] = _baseline_columns(judge, pair)
        return row
    # the method against PPO as `pved claims` tests "beats": its groups, difference, p
    beats = judge.beats(name, method, "ppo")
    if "difference" not in beats:
        row["reason"] = beats["reason"]
        return row
    columns: dict[str, Any] = {}
    for group in beats["groups"]:  # PPO's CI from the resamples of the method's difference
        columns[group["method"]] = {k: group[k] for k in ("runs", "mean", "mean_ci")}
    row["columns"] = {**_baseline_columns(judge, pair), **columns}
    row["difference"] = {**beats["difference"], "p": beats["p"]}
    row["standing"] = {HOLDS: AHEAD, NOT_HOLD: BEHIND}.get(beats["verdict"], LEVEL)
    row.update(beside_aa(beats["difference"]["value"], aa_entry(judge, name, "final")))
    row[EXPLORATORY] = is_exploratory(pair, method)
    ppo_steps = _ppo_steps(pair)
    entry = pair.methods[method]
    reach = entry.get("steps_to_ppo_final")
    row["ppo_steps"] = ppo_steps
    row["steps_to_ppo_final"] = reach
    # A PPO that ended at or below its start learned nothing: any curve reaches its final
    # at its first evaluation, and the protocol records no step count (curves.py).
    row["ppo_improved"] = entry.get("ppo_improved", True) is not False
    row["fraction_of_ppo_steps"] = (
        reach / ppo_steps if isinstance(reach, int | float) and ppo_steps else None
    )
    fraction = row["fraction_of_ppo_steps"]
    row["fast"] = not row["ppo_improved"] or (fraction is not None and fraction <= SPEED_FRACTION)
    return row


def scoreboard(method: str, dirs: Sequence[str | Path]) -> dict[str, Any]:
    """The method's row on every pair of ``dirs`` (:func:`load_merged`; in the paper's
    order) and the goal's
    verdict. Raises PvedError (one line) for bad inputs (:func:`load_merged`), a method
    that is a baseline, or a method without runs on any pair."""
    if method in BASELINES:
        raise PvedError(f"--method {method}: give a transfer method, not a column beside it")
    pairs = load_merged(dirs)
    order = [p for p in FOUR if p in pairs] + sorted(set(pairs) - set(FOUR))
    rows = [pair_row(pairs, name, method) for name in order]
    if all("reason" in r for r in rows):
        raise PvedError(
            f"no runs of {method} with PPO's on any pair of {', '.join(map(str, dirs))}"
        )
    judged = [r for r in rows if "reason" not in r]
    ahead = [r["pair"] for r in judged if r["standing"] == AHEAD]
    behind = [r["pair"] for r in judged if r["standing"] == BEHIND]
    ahead_fast = [r["pair"] for r in judged if r["standing"] == AHEAD and r["fast"]]
    absent = [p for p in FOUR if p not in [r["pair"] for r in judged]]
    goal: dict[str, Any] = {
        "ahead": ahead,
        "behind": behind,
        "ahead_and_fast": ahead_fast,
        "missing_pairs": absent,
        "needs": f"ahead of ppo on >= {AHEAD_NEEDED} of {len(FOUR)} pairs, behind on none, "
        f"reaching ppo's final within {SPEED_FRACTION:.0%} of its steps on those",
    }
    counts = (
        f"ahead on {len(ahead)} of {len(FOUR)} (needs {AHEAD_NEEDED}), fast on "
        f"{len(ahead_fast)} of those, behind on {len(behind)} (needs 0)"
    )
    # A missing pair can only add to the pairs ahead: where even all of them ahead and
    # fast would not make the count, or a pair is already behind, the goal is missed now.
    out_of_reach = bool(behind) or len(ahead_fast) + len(absent) < AHEAD_NEEDED
    if absent and not out_of_reach:
        goal["verdict"] = "not judged"
        goal["why"] = f"no runs on {', '.join(absent)}"
    elif absent:
        goal["verdict"] = "not reached"
        goal["why"] = f"{counts}, whatever {', '.join(absent)} show(s)"
    else:
        reached = len(ahead_fast) >= AHEAD_NEEDED and not behind
        goal["verdict"] = "reached" if reached else "not reached"
        goal["why"] = counts
    budgets = sorted({r["budget"] for r in rows})
    measures = method_measures(pairs, method)
    return {
        "method": method,
        "budgets": budgets,
        "rows": rows,
        "goal": goal,
        "transfer_measures": measures,
        "transfer_goal": transfer_goal(pairs, method, measures),
    }


def _num(x: float) -> str:
    return f"{x:.3f}"


def _cell(column: dict[str, Any] | None) -> str:
    if column is None:
        return "–"
    lo, hi = column["mean_ci"]
    return f"{_num(column['mean'])} [{_num(lo)}, {_num(hi)}] ({column['runs']})"


def scoreboard_markdown(result: dict[str, Any]) -> str:
    """The table (one row a pair) and the goal's verdict, as markdown."""
    method = result["method"]
    lines = [
        f"# {method} against plain PPO ({', '.join(result['budgets'])} budget)",
        "",
        "Final score: mean [95% CI] (runs); CIs from a two-level bootstrap over source "
        "policies and PPO seeds. Steps: where the method's mean curve reaches PPO's final "
        "mean, and the fraction of PPO's steps.",
        "",
        f"| pair | metric | ppo | pved | {method} | oracle | {method} − ppo [95% CI], p "
        "| steps to ppo's final | standing | A/A: ppo-aa − ppo [95% CI] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        if "reason" in r and "columns" in r:  # the method did not run here; PPO did
            cols = r["columns"]
            lines.append(
                f"| {r['pair']} | {r['metric']} | {_cell(cols.get('ppo'))} | "
                f"{_cell(cols.get('pved'))} | not run | {_cell(cols.get('oracle'))} | – | – "
                f"| {r['reason']} | – |"
            )
            continue
        if "reason" in r:
            lines.append(f"| {r['pair']} | {r['metric']} | {r['reason']} ||||||||")
            continue
        cols, d = r["columns"], r["difference"]
        lo, hi = d["ci"]
        reach = r["steps_to_ppo_final"]
        if not r["ppo_improved"]:
            steps = "first evaluation (ppo did not improve)"
        elif reach is None:
            steps = "not reached"
        else:
            steps = f"{reach:,} ({r['fraction_of_ppo_steps']:.2f} of {r['ppo_steps']:,})"
        mine = _cell(cols.get(method)) + (f" **{EXPLORATORY}**" if r.get(EXPLORATORY) else "")
        lines.append(
            f"| {r['pair']} | {r['metric']} | {_cell(cols.get('ppo'))} | "
            f"{_cell(cols.get('pved'))} | {mine} | "
            f"{_cell(cols.get('oracle'))} | {d['value']:+.3f} [{lo:+.3f}, {hi:+.3f}], "
            f"p {d['p']:.2g} | {steps} | {r['standing']}{', fast' if r['fast'] else ''} | "
            f"{aa_cell('final', r['aa'], r['inside_aa'])} |"
        )
    goal = result["goal"]
    lines += ["", f"Goal ({goal['needs']}): **{goal['verdict']}**: {goal['why']}."]
    if "transfer_goal" in result:  # absent from scoreboards written before it
        lines += ["", transfer_goal_markdown(result["method"], result["transfer_goal"])]
    if "transfer_measures" in result:  # absent from scoreboards written before them
        lines += ["", DEFINITIONS, "", measures_markdown(result["transfer_measures"])]
    return "\n".join(lines) + "\n"


def write_scoreboard(method: str, dirs: Sequence[str | Path], out: Path | None = None) -> str:
    """The scoreboard's markdown; with ``out``, also ``OUT/scoreboard.json`` and
    ``OUT/scoreboard.md``, written atomically after every check has passed."""
    from pved.checks import check_writable

    if out is not None:
        out = check_writable("--out", out)
    result = scoreboard(method, dirs)
    md = scoreboard_markdown(result)
    if out is not None:
        # Imported here: pved.runs imports torch, which the scoreboard does not need.
        from pved.runs import atomic_write_bytes, atomic_write_json

        atomic_write_json(Path(out) / "scoreboard.json", result)
        atomic_write_bytes(Path(out) / "scoreboard.md", md.encode())
    return md
