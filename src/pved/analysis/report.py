"""A report folder for a set of transfer runs: learning curves (PNG), a results table
(Markdown + JSON) and the configs that produced them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from pved.analysis.bootstrap import REPS, SEED
from pved.analysis.curves import (
    ONE_LEVEL_REPS,
    Curve,
    bootstrap_summary,
    load_curve,
    plot_curves,
)
from pved.checks import check_seed, check_writable
from pved.errors import PvedError
from pved.runs import atomic_write_bytes, atomic_write_json, run_path


def _mean_ci(mean: float, ci: list[float], digits: int) -> str:
    """Table cell ``mean [lo, hi]`` with ``digits`` decimals."""
    return f"{mean:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def transfer_report(
    pair: str,
    methods: list[str],
    seeds: list[int],
    runs_root: Path,
    out: Path,
    *,
    metric: str = "success_rate",
    title: str | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``out/`` with ``curves_<metric>.png``, ``curves_return.png``, ``results.md``,
    ``results.json`` and ``configs/<method>-seed<k>.json``; return ``out``."""
    rows: list[dict[str, Any]] = []
    curves: dict[str, list[Curve]] = {metric: [], "return_mean": []}
    if not seeds:
        raise PvedError("--seeds must name one or more transfer seeds, got none")
    for seed in seeds:
        check_seed("--seeds", seed)
    # every run finished and the folder writable before a file of the report is written
    for method in methods:
        for s in seeds:
            d = run_path(runs_root, pair, "transfer", method, s)
            if not (d / "result.json").exists():
                raise PvedError(f"transfer run {d} has no result.json (not finished)")
    check_writable("--out", out)
    (out / "configs").mkdir(parents=True, exist_ok=True)
    for method in methods:
        dirs = [run_path(runs_root, pair, "transfer", method, s) for s in seeds]
        results = []
        for d, s in zip(dirs, seeds, strict=True):
            results.append(json.loads((d / "result.json").read_text()))
            shutil.copyfile(d / "config.json", out / "configs" / f"{method}-seed{s}.json")
        for key in curves:
            curves[key].append(load_curve(method, dirs, seeds, f"eval/{key}"))
        final = np.array([r[f"final/{metric}"] for r in results], dtype=np.float64)
        final_ret = np.array([r["final/return_mean"] for r in results], dtype=np.float64)
        auc = curves[metric][-1].values.mean(1)  # mean over the curve's points, per seed
        fin, cur, ret = (bootstrap_summary(x) for x in (final, auc, final_ret))
        rows.append(
            {
                "method": method,
                "seeds": seeds,
                f"final_{metric}": final.tolist(),
                "final_mean": fin["mean"],
                "final_ci95": fin["mean_ci"],  # [lo, hi]
                "final_iqm": fin["iqm"],
                "final_iqm_ci95": fin["iqm_ci"],
                "curve_mean": cur["mean"],
                "curve_ci95": cur["mean_ci"],
                "final_return_mean": ret["mean"],
                "final_return_ci95": ret["mean_ci"],
                "steps": int(results[0]["steps"]),
            }
        )
    plot_curves(
        curves[metric],
        out / f"curves_{metric}.png",
        metric.replace("_", " "),
        title or f"{pair}: target agent on the target task",
        bounds=(0.0, 1.0) if metric == "success_rate" else None,
    )
    plot_curves(
        curves["return_mean"],
        out / "curves_return.png",
        "return (env reward)",
        title or f"{pair}: target agent on the target task",
    )
    lines = [
        f"# {title or pair}",
        "",
        f"Final {metric} is measured on fresh episodes after training; 'curve mean' is the "
        "mean of the evaluation points along training (a sample-efficiency summary). "
        "[lo, hi] is the 95% percentile bootstrap interval of the mean over seeds "
        f"(the project's bootstrap, here of seeds only: {REPS:,} resamples, seed {SEED}; "
        "[x, x] for one seed).",
        "",
        f"| method | seeds | env steps | final {metric}: mean [95% CI] | per seed "
        "| curve mean [95% CI] | final return: mean [95% CI] |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        per_seed = " ".join(f"{v:.2f}" for v in row[f"final_{metric}"])
        lines.append(
            f"| {row['method']} | {len(row['seeds'])} | {row['steps']} | "
            f"{_mean_ci(row['final_mean'], row['final_ci95'], 3)} | {per_seed} | "
            f"{_mean_ci(row['curve_mean'], row['curve_ci95'], 3)} | "
            f"{_mean_ci(row['final_return_mean'], row['final_return_ci95'], 2)} |"
        )
    atomic_write_bytes(out / "results.md", ("\n".join(lines) + "\n").encode())
    atomic_write_json(
        out / "results.json",
        {
            "pair": pair,
            "metric": metric,
            # *_ci95 used to be t-interval half-widths; say what they are now.
            "ci95": f"[lo, hi], 95% percentile bootstrap over seeds ({REPS} reps, seed {SEED}); "
            f"final_iqm_ci95: one-level (rliable, {ONE_LEVEL_REPS} reps)",
            "rows": rows,
            **(extra or {}),
        },
    )
    return out
