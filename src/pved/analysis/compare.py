"""Two groups of finished transfer runs, compared the way ``pved claims`` compares two
methods of a protocol, for runs made outside one: an option of ``pved transfer`` (say
``--shaping-form log1p``) against the protocol's own runs of the same pair, or any two
sets of seeds a researcher has trained.

Per run, as in :mod:`pved.analysis.judge`: the final score (the pair's metric in
``result.json``, the run's final evaluation), the early score (the mean of its evaluation
points at steps <= 25% of its last) and the drop (its best evaluation point minus its
last). For each, the difference of the two groups' means, A − B, with its 95% percentile
bootstrap interval and the bootstrap p-value of 0, from the bootstrap ``pved claims`` uses
(:func:`pved.analysis.bootstrap.bootstrap_difference`, the project's resamples and seed):
two levels, the source policies (a run's source bank, ``bank`` in its config; one draw for both
groups where they ran with the same banks) and the PPO seeds (each group its own draw),
every run of a drawn (source, seed) cell taken; a group without banks (plain PPO, the
oracle) draws its seeds only, the runs of one seed together. Each group's own mean and
interval are the same bootstrap of its runs alone (:func:`pved.analysis.bootstrap.bootstrap_mean`).
And the steps each group's
mean curve takes to reach B's final mean (:func:`pved.analysis.curves.steps_to_reach`),
the paper's "steps to reach the baseline's final performance" with B as the baseline.

Then A against B by Taylor & Stone's transfer measures (AUC, jumpstart, steps to B's
final mean per run; :mod:`pved.analysis.transfer_measures`; one pair, so Holm leaves the
p-values as they are) and, with ``--aa`` runs (a second set of B made by the same code on
other seeds), the A/A check beside every difference: AA − B with its interval, and
"inside A/A noise" where |A − B| is no larger than the largest |difference| that interval
admits; "no A/A set" without them.

A group may pool the runs of several protocol directories (issue 64's "pooled PPO runs"):
a run that one of them copied from another is counted once (:func:`distinct_runs`).

Only files are read: each run's ``config.json``, ``result.json`` and ``metrics.jsonl``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pved.analysis.bootstrap import REPS, SEED, bootstrap_difference, bootstrap_mean
from pved.analysis.curves import Curve, steps_to_baseline_finals
from pved.analysis.judge import drop, early_score, eval_curve
from pved.analysis.run_curves import curve_score, steps_to_threshold
from pved.analysis.transfer_measures import INSIDE_AA, MEASURE_NAMES, NO_AA, aa_noise
from pved.errors import PvedError
from pved.provenance import count_fingerprints, fingerprint_mismatch, run_fingerprint
from pved.record_paths import record_path
from pved.runs import RESTORED_FROM, read_json
from pved.spec import get_preset

SCORES = ("final", "early", "drop")
MEASURES = ("auc", "jumpstart", "reach")
"""Taylor & Stone's measures beside the scores (the final one is among the scores)."""


def find_transfer_runs(paths: Sequence[Path]) -> list[Path]:
    """The finished transfer run directories among ``paths``: each one a run directory
    itself, or a folder searched (recursively) for run directories. A run directory holds
    ``config.json`` and ``result.json``; only transfer runs (``stage: transfer``) count.

    Raises PvedError (one line) for a path that does not exist, a run directory that is
    not a transfer run or not finished, a run given twice, or no run at all."""
    found: list[Path] = []
    seen: set[Path] = set()
    for path in map(Path, paths):
        if not path.exists():
            raise PvedError(f"{path}: no such file or directory")
        if (path / "config.json").is_file():
            candidates = [path]
        else:
            candidates = sorted(p.parent for p in path.rglob("config.json"))
            candidates = [c for c in candidates if _stage(c) == "transfer"]
        for run_dir in candidates:
            stage = _stage(run_dir)
            if stage != "transfer":
                raise PvedError(f"{run_dir}: not a transfer run (stage {stage!r})")
            if not (run_dir / "result.json").is_file():
                raise PvedError(f"{run_dir}: transfer run not finished (no result.json)")
            if run_dir.resolve() in seen:
                raise PvedError(f"{run_dir} is given twice: give each run once")
            seen.add(run_dir.resolve())
            found.append(run_dir)
    if not found:
        raise PvedError(f"no finished transfer run under {', '.join(map(str, paths))}")
    return found


#: What a copy of a run may hold differently in its ``result.json``: the paths of its
#: artefacts (``pved.runs.repoint_result``) and where ``pved archive restore`` took it from.
COPY_FIELDS = ("policy", "model", "dataset", "bank", RESTORED_FROM)


def _run_identity(run_dir: Path) -> str:
    """What makes a finished run the run it is: its config, its results (less
    :data:`COPY_FIELDS`) and its evaluation curve. A copy made by ``--stages-from`` or
    restored by ``pved archive restore`` has all three, elsewhere; runs of one config by
    two versions of the code differ in their numbers."""
    config = _read_json(run_dir / "config.json").get("config")
    result = {k: v for k, v in _read_json(run_dir / "result.json").items() if k not in COPY_FIELDS}
    curve = []
    metrics = run_dir / "metrics.jsonl"
    for line in metrics.read_text().splitlines() if metrics.is_file() else []:
        row = json.loads(line) if line.strip() else {}
        evals = {k: v for k, v in row.items() if k.startswith("eval/")}
        if evals:
            curve.append([row.get("step"), evals])
    return json.dumps([config, result, curve], sort_keys=True, default=str)


def distinct_runs(dirs: Sequence[Path]) -> tuple[list[Path], int]:
    """``dirs`` with every copy of a run already among them left out, and how many were:
    pooling the PPO runs of several protocol directories counts a run that one of them
    copied from another once (:func:`_run_identity`)."""
    kept: list[Path] = []
    seen: set[str] = set()
    for run_dir in dirs:
        identity = _run_identity(run_dir)
        if identity not in seen:
            seen.add(identity)
            kept.append(run_dir)
    return kept, len(dirs) - len(kept)


def _read_json(path: Path) -> dict[str, Any]:
    """A JSON object from ``path``; PvedError (one line) when unreadable or not an object."""
    data = read_json(path)
    if not isinstance(data, dict):
        raise PvedError(f"{path}: not a JSON object")
    return data


def _stage(run_dir: Path) -> object:
    """The ``stage`` a run directory's config.json records (None when it records none)."""
    config = _read_json(run_dir / "config.json").get("config")
    return config.get("stage") if isinstance(config, dict) else None


def _load_run(run_dir: Path) -> dict[str, Any]:
    """A finished transfer run's pair, length, PPO seed, source bank (None: a method
    without one, plain PPO or the oracle), numeric fingerprint and final results."""
    record = _read_json(run_dir / "config.json")
    config = record["config"]
    ppo = config.get("ppo")
    if not isinstance(ppo, dict) or not isinstance(config.get("pair"), str):
        raise PvedError(f"{run_dir / 'config.json'}: no pair or PPO config recorded")
    return {
        "dir": run_dir,
        "pair": config["pair"],
        "steps": ppo.get("total_steps"),
        "seed": ppo.get("seed"),
        "source": config.get("bank"),
        "fingerprint": run_fingerprint(record),
        "result": _read_json(run_dir / "result.json"),
    }


def _group(name: str, runs: list[dict[str, Any]], metric: str) -> dict[str, Any]:
    """One group's per-run scores, PPO seeds and source banks (the bootstrap's two levels;
    sources None for a group without banks) and mean curve. PvedError for a group that
    mixes runs with and without a source bank."""
    final, early, drops, series = [], [], [], []
    for run in runs:
        value = run["result"].get(f"final/{metric}")
        if not isinstance(value, int | float) or not math.isfinite(value):
            raise PvedError(f"{run['dir'] / 'result.json'}: no finite final/{metric}")
        steps, values = eval_curve(run["dir"] / "metrics.jsonl", metric)
        if not steps.size or not np.all(np.isfinite(values)):
            raise PvedError(f"{run['dir'] / 'metrics.jsonl'}: no finite eval/{metric} points")
        final.append(float(value))
        early.append(early_score(steps, values))
        drops.append(drop(values))
        series.append((steps, values))
    steps0 = series[0][0]
    for (steps, _), run in zip(series, runs, strict=True):
        if not np.array_equal(steps, steps0):
            raise PvedError(
                f"{run['dir']} is evaluated at other steps than {runs[0]['dir']}: "
                "compare runs of one evaluation schedule"
            )
    seeds = [r["seed"] if isinstance(r["seed"], int) else f"run{i}" for i, r in enumerate(runs)]
    banks = [r["source"] for r in runs]
    if any(bank is None for bank in banks) and any(bank is not None for bank in banks):
        shaped = next(r for r in runs if r["source"] is not None)["dir"]
        plain = next(r for r in runs if r["source"] is None)["dir"]
        raise PvedError(
            f"group {name} mixes runs with a source bank ({shaped}) and without one "
            f"({plain}): compare runs of one method in a group"
        )
    return {
        "name": name,
        "runs": runs,
        "scores": {
            "final": np.asarray(final),
            "early": np.asarray(early),
            "drop": np.asarray(drops),
        },
        "seeds": seeds,
        "sources": banks if banks and banks[0] is not None else None,
        "curve": Curve(name, steps0, np.stack([v for _, v in series]), list(range(len(runs)))),
    }


def _resampling(ga: dict[str, Any], gb: dict[str, Any]) -> str:
    """What the intervals resample, for the printed table."""
    with_sources = [g["name"] for g in (ga, gb) if g["sources"] is not None]
    if not with_sources:
        return "bootstrap over PPO seeds, the runs of one seed drawn together"
    if len(with_sources) == 1:
        how = f"{with_sources[0]}'s; the other group has none"
    elif set(ga["sources"]) == set(gb["sources"]):
        how = "one draw of the source banks for both groups"
    else:
        how = "each group's own banks, drawn apart"
    return f"two-level bootstrap over source banks ({how}) and PPO seeds"


def compare_runs(
    a: Sequence[Path],
    b: Sequence[Path],
    names: tuple[str, str] = ("A", "B"),
    *,
    seed: int = SEED,
    aa: Sequence[Path] | None = None,
) -> dict[str, Any]:
    """Compare the finished transfer runs under ``a`` with those under ``b`` (paths as
    :func:`find_transfer_runs` takes them). Every run must be of one pair and one length.

    Returns ``{"pair", "metric", "steps", "resampling": what the intervals resample,
    "groups": {name: {"runs", "dirs", "seeds", "sources" (each run's bank, or None),
    "final": {"mean", "mean_ci"}, "early_mean", "drop_mean", "steps_to_<B>_final"}},
    "<B>_final": B's final mean curve point, "<B>_improved", "fingerprint_warning": None
    or the line saying the groups were not all made under one known numeric fingerprint,
    "diff": {score: {"diff", "diff_ci", "p"}}}`` (each group also lists ``fingerprints``:
    the runs made under each), differences A − B (``p``: the bootstrap p-value of 0). Raises
    PvedError (one line) for bad input.

    ``aa``: runs of B's kind made again on other seeds (:func:`_measures`); the result
    also holds ``measures`` (A − B by AUC, jumpstart and steps to B's final), ``aa``
    (AA − B of every score and measure, or "no A/A set") and, in each difference,
    ``inside_aa``."""
    name_a, name_b = names
    if name_a == name_b:
        raise PvedError(f"the two groups need different names, got {name_a!r} twice")
    dirs_a, copies_a = distinct_runs(find_transfer_runs(a))
    dirs_b, copies_b = distinct_runs(find_transfer_runs(b))
    dirs_aa = distinct_runs(find_transfer_runs(aa))[0] if aa else []
    for one, other in ((dirs_a, dirs_b), (dirs_a, dirs_aa), (dirs_b, dirs_aa)):
        both = {d.resolve() for d in one} & {d.resolve() for d in other}
        if both:
            raise PvedError(f"{sorted(both)[0]} is in both groups")
        theirs = {_run_identity(d): d for d in other}
        copy = next((d for d in one if _run_identity(d) in theirs), None)
        if copy is not None:
            raise PvedError(f"{copy} and {theirs[_run_identity(copy)]} are one run, in both groups")
    runs_a, runs_b = [_load_run(d) for d in dirs_a], [_load_run(d) for d in dirs_b]
    runs_aa = [_load_run(d) for d in dirs_aa]
    first = runs_a[0]
    for run in runs_a + runs_b + runs_aa:
        if run["pair"] != first["pair"]:
            raise PvedError(
                f"{run['dir']} is a run of {run['pair']!r}, {first['dir']} of "
                f"{first['pair']!r}: compare runs of one pair"
            )
        if run["steps"] != first["steps"]:
            raise PvedError(
                f"{run['dir']} ran {run['steps']} steps, {first['dir']} {first['steps']}: "
                "compare runs of one length"
            )
    metric = get_preset(first["pair"]).metric
    ga, gb = _group(name_a, runs_a, metric), _group(name_b, runs_b, metric)
    gaa = _group(f"{name_b} A/A", runs_aa, metric) if runs_aa else None
    if any(not np.array_equal(g["curve"].steps, gb["curve"].steps) for g in (ga, gaa) if g):
        raise PvedError(
            "the two groups are evaluated at different steps: "
            "compare runs of one evaluation schedule"
        )
    made_under = [count_fingerprints([r["fingerprint"] for r in runs]) for runs in (runs_a, runs_b)]
    reach = steps_to_baseline_finals([ga["curve"], gb["curve"]], [name_b])
    b_final = float(gb["curve"].mean[-1])
    b_improved = f"{name_b}_final" in reach[name_b]
    out: dict[str, Any] = {
        "pair": first["pair"],
        "metric": metric,
        "steps": first["steps"],
        "resampling": _resampling(ga, gb),
        "groups": {},
        f"{name_b}_final": b_final,
        f"{name_b}_improved": b_improved,
        # None, or why the difference may be the code's arithmetic too (pved.provenance)
        "fingerprint_warning": fingerprint_mismatch(*made_under),
        "diff": {},
    }
    for score in SCORES:
        d = bootstrap_difference(
            ga["scores"][score],
            gb["scores"][score],
            reps=REPS,
            seed=seed,
            seeds_a=ga["seeds"],
            seeds_b=gb["seeds"],
            sources_a=ga["sources"],
            sources_b=gb["sources"],
            labels=(ga["name"], gb["name"]),
        )
        out["diff"][score] = {"diff": d["diff"], "diff_ci": d["diff_ci"], "p": d["tests"][0]["p"]}
        for g, key in ((ga, "a"), (gb, "b")):
            entry = out["groups"].setdefault(
                g["name"],
                {
                    "runs": len(g["runs"]),
                    "dirs": [record_path(r["dir"]) for r in g["runs"]],
                    "seeds": [r["seed"] for r in g["runs"]],
                    "sources": g["sources"],
                    "fingerprints": made_under[0 if key == "a" else 1],
                    # copies of a run given elsewhere in the group, left out
                    "copies": copies_a if key == "a" else copies_b,
                },
            )
            if score == "final":
                own = bootstrap_mean(
                    g["scores"]["final"],
                    g["seeds"],
                    g["sources"],
                    reps=REPS,
                    seed=seed,
                    label=g["name"],
                )
                entry["final"] = {"mean": own["mean"], "mean_ci": own["mean_ci"]}
            else:
                entry[f"{score}_mean"] = d[key]["mean"]
    for g in (ga, gb):
        # None where B's mean curve ends where it began: it learned nothing to reach
        key = f"steps_to_{name_b}_final"
        out["groups"][g["name"]][key] = reach[g["name"]].get(key)
    _measures(out, ga, gb, gaa, seed)
    return out


def _per_run(g: dict[str, Any], score: str, threshold: float) -> np.ndarray:
    """A group's per-run ``score``: its own (final, early, drop) or off its curves (AUC,
    jumpstart, steps to ``threshold``)."""
    if score in g["scores"]:
        return np.asarray(g["scores"][score])
    c = g["curve"]
    if score == "reach":
        return np.asarray([steps_to_threshold(c.steps, v, threshold) for v in c.values])
    return np.asarray([curve_score(score, c.steps, v) for v in c.values])


def _measures(
    out: dict[str, Any],
    ga: dict[str, Any],
    gb: dict[str, Any],
    gaa: dict[str, Any] | None,
    seed: int,
) -> None:
    """Into ``out``: ``measures``, A − B by :data:`MEASURES` (``reach``: per run, the
    first evaluation step at B's final mean, a run that never gets there one evaluation
    past its last; left out with a reason where B did not improve); ``aa``, AA − B of
    every score and measure with its noise floor
    (:func:`pved.analysis.transfer_measures.aa_noise`), or "no A/A set"; and beside each
    difference ``inside_aa``. The same bootstrap as the scores'."""
    mean_b = gb["curve"].mean
    threshold = float(mean_b[-1])
    improved = threshold > float(mean_b[0])

    def difference(g1: dict[str, Any], score: str) -> dict[str, Any]:
        d = bootstrap_difference(
            _per_run(g1, score, threshold),
            _per_run(gb, score, threshold),
            reps=REPS,
            seed=seed,
            seeds_a=g1["seeds"],
            seeds_b=gb["seeds"],
            sources_a=g1["sources"],
            sources_b=gb["sources"],
            labels=(g1["name"], gb["name"]),
        )
        return {"diff": d["diff"], "diff_ci": d["diff_ci"], "p": d["tests"][0]["p"]}

    out["measures"] = {}
    for measure in MEASURES:
        if measure == "reach" and not improved:
            out["measures"][measure] = {"reason": f"{gb['name']} did not improve"}
        else:
            out["measures"][measure] = difference(ga, measure)
    out["aa"] = NO_AA
    if gaa is not None:
        out["aa"] = {}
        for score in (*SCORES, *MEASURES):
            if score in out["measures"] and "reason" in out["measures"][score]:
                continue
            d = difference(gaa, score)
            out["aa"][score] = {
                "diff": d["diff"],
                "diff_ci": d["diff_ci"],
                "noise": aa_noise(d["diff_ci"]),
            }
    for score, d in [*out["diff"].items(), *out["measures"].items()]:
        if "diff" in d:
            noise = out["aa"].get(score, {}).get("noise") if gaa is not None else None
            d["inside_aa"] = None if noise is None else abs(d["diff"]) <= noise


def _measure_lines(result: dict[str, Any]) -> list[str]:
    """The measures' lines of :func:`format_comparison`, and the A/A check's."""
    names = list(result["groups"])
    lines = []
    for measure in MEASURES:
        d = result["measures"][measure]
        if "reason" in d:
            lines.append(f"{MEASURE_NAMES[measure]}: – ({d['reason']})")
            continue
        fmt = "{:+,.0f}" if measure == "reach" else "{:+.3f}"
        lo, hi = (fmt.format(x) for x in d["diff_ci"])
        lines.append(
            f"{MEASURE_NAMES[measure]}: {names[0]} − {names[1]} = {fmt.format(d['diff'])} "
            f"[{lo}, {hi}], p = {d['p']:.3g}"
        )
    aa = result["aa"]
    if isinstance(aa, str):
        return [*lines, f"A/A: {aa} (give --aa runs of {names[1]} made on other seeds)"]
    lines.append(f"A/A ({names[1]} again on other seeds − {names[1]}):")
    for score, d in aa.items():
        fmt = "{:+,.0f}" if score == "reach" else "{:+.3f}"
        lo, hi = (fmt.format(x) for x in d["diff_ci"])
        flagged = result["diff"].get(score) or result["measures"].get(score) or {}
        flag = f": {names[0]} − {names[1]} is {INSIDE_AA}" if flagged.get("inside_aa") else ""
        lines.append(
            f"- {MEASURE_NAMES.get(score, score)}: {fmt.format(d['diff'])} [{lo}, {hi}]{flag}"
        )
    return lines


def format_comparison(result: dict[str, Any]) -> str:
    """A Markdown table of :func:`compare_runs`' result."""
    names = list(result["groups"])
    name_b = names[1]

    def interval(ci: list[float]) -> str:
        return f"[{ci[0]:.3f}, {ci[1]:.3f}]"

    def reach(steps: int | None) -> str:
        if not result[f"{name_b}_improved"]:
            return f"– ({name_b} did not improve)"
        return "not reached" if steps is None else f"{steps:,}"

    lines = [
        f"{result['pair']}, {result['metric']} after {result['steps']:,} steps "
        f"(95% CIs: {result['resampling']}; p: bootstrap p-value of no difference)",
        "",
        f"| group | runs | final mean [95% CI] | early mean | drop mean | steps to "
        f"{name_b}'s final ({result[f'{name_b}_final']:.3f}) |",
        "|---|---|---|---|---|---|",
    ]
    copies = [
        f"{n}: {result['groups'][n]['copies']}" for n in names if result["groups"][n].get("copies")
    ]
    for name in names:
        g = result["groups"][name]
        lines.append(
            f"| {name} | {g['runs']} | {g['final']['mean']:.3f} {interval(g['final']['mean_ci'])}"
            f" | {g['early_mean']:.3f} | {g['drop_mean']:.3f} "
            f"| {reach(g[f'steps_to_{name_b}_final'])} |"
        )
    if copies:
        lines.append(f"\nCopies of a run given twice, counted once ({', '.join(copies)}).")
    lines.append("")
    for score in SCORES:
        d = result["diff"][score]
        lines.append(
            f"{score}: {names[0]} − {name_b} = {d['diff']:+.3f} {interval(d['diff_ci'])}, "
            f"p = {d['p']:.3g}"
        )
    if "measures" in result:  # absent from a comparison written before them
        lines += ["", *_measure_lines(result)]
    if result.get("fingerprint_warning"):
        lines += ["", f"Warning: {names[0]} and {name_b} were {result['fingerprint_warning']}"]
    return "\n".join(lines)
