"""How large Eq. 10's distance is on the training pairs, the scale to read a transfer run's
shaping term against.

For each shaped method of a finished ``pved protocol`` directory, this loads the model the
protocol selected (its chosen initialisation) and the pair's paired dataset, and computes
the distance D of Eq. 10 (the KL between the shared posteriors, or a point-code model's
squared distance) on

* the matched pairs the model was trained on (source step with its own target step), and
* the same rows with the target side shuffled (a source step against an unrelated target
  step of the training data): what D is between codes that have nothing to do with each
  other.

A transfer run whose D on the target task stays near the shuffled level has not brought
the target's shared codes any closer to the source's than chance. The rows are a seeded
sample, so the numbers are reproducible.

The same rows again, with only one part of the target step replaced by that of the
shuffled row: its action (its robot state kept), then its robot state (its action kept).
This says what the target's shared code is about, and so how the target can move D: a
policy sets its action at once but its state only over the following steps. Where
swapping the action leaves D at the matched level, the code ignores the action and the
term rewards where the target is, not what it does.

The same rows once more, each target step against the source step at the same step of
another training episode (another task draw: another reach target, another slope):
how often D is lower against its own source step than against that one. Near 1, the
code tells this episode's task from another's at the same moment; near 0.5, the term
could only say when to move, not where (compare :mod:`pved.diagnostics.peg_success`'s own
hole against the reflected one, on the target task).

A second table asks whether D tells a good target from a bad one: for each shaped
method's evaluation runs, D at the run's last PPO rollout (its logged shaping term over
−β) against the run's final score, with Spearman's rank correlation over the runs. If
Eq. 10 rewards what the task needs, the runs that end nearer the source's codes should
score higher (a negative ρ). Its 95% interval is drawn by PPO seed, as `pved claims`
draws its differences: a shaped method's runs of one seed (its three source policies)
are not independent, so the interval is wide with five seeds. Runs restored from an
archive keep no rollout rows and are left out.

A third table asks whether the target can be brought nearer the source's codes at all:
for each β the protocol's search tried (model initialisation 0, source policy 0, the
tuning seeds), D at the first and at the last rollout, medians over the seeds, beside the
candidate's tuning score. Where a larger β buys a smaller D by the end, the target can
reach the codes the source bank asks for, and the term steers it; where D ends at the
same level whatever β (ρ(β, D last) near 0 while the score falls), the target cannot get
nearer, and a larger weight only makes the term a larger cost.

    pved analyze shaping-scale reports/jaco-fetch-quick

Prints Markdown tables and writes ``PROTOCOL_DIR/subspaces/shaping_scale.json``
(:func:`protocol_shaping_scale`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.stats import spearmanr

from pved.analysis.curves import SHAPING_KEY, read_eval_points
from pved.analysis.judge import load_summary
from pved.diagnostics.shaping_audit import distance_stats, matched_and_shuffled
from pved.errors import PvedError
from pved.models.base import SharedSpaceModel
from pved.models.registry import load_model
from pved.pair import resolve_pair
from pved.pairing.dataset import load_dataset
from pved.run_layout import transfer_run_name
from pved.runs import atomic_write_json


def shaping_scale(model_path: Path, dataset_path: Path, rows: int, seed: int) -> dict[str, Any]:
    """D of Eq. 10 on ``rows`` sampled training pairs of the dataset at ``dataset_path``,
    matched and with the target side shuffled (:func:`matched_and_shuffled`), and with
    only the target's action or robot state shuffled (:func:`target_part_swapped`), and
    against another episode's source step at the same step (:func:`other_episode_same_step`)."""
    dataset = load_dataset(dataset_path)
    x_s, x_t = dataset.model_inputs()
    model = load_model(model_path).eval()
    return {
        **matched_and_shuffled(model, x_s, x_t, rows, seed),
        **target_part_swapped(model, x_s, x_t, dataset.state_dims[1], rows, seed),
        **other_episode_same_step(model, x_s, x_t, dataset.episode, dataset.t_target, rows, seed),
    }


@torch.no_grad()
def target_part_swapped(
    model: SharedSpaceModel,
    x_s: np.ndarray,
    x_t: np.ndarray,
    state_dim_t: int,
    rows: int,
    seed: int,
) -> dict[str, dict[str, float]]:
    """D of Eq. 10 on :func:`matched_and_shuffled`'s rows (the same ``seed``) with one
    part of each target step x_t = [robot state (``state_dim_t``), action] taken from the
    shuffled row: ``{"action_swapped": stats, "state_swapped": stats}``."""
    if not 0 < state_dim_t < x_t.shape[1]:
        raise ValueError(f"state_dim_t {state_dim_t} does not split x_T of width {x_t.shape[1]}")
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(x_s), size=min(rows, len(x_s)), replace=False)
    shuffled = rng.permutation(pick)
    source = torch.as_tensor(x_s[pick], dtype=torch.float32)
    out = {}
    for name, part in (
        ("action_swapped", slice(state_dim_t, None)),
        ("state_swapped", slice(0, state_dim_t)),
    ):
        target = x_t[pick].copy()
        target[:, part] = x_t[shuffled][:, part]
        d = model.shaping(source, torch.as_tensor(target, dtype=torch.float32))
        out[name] = distance_stats(d.double().numpy())
    return out


@torch.no_grad()
def other_episode_same_step(
    model: SharedSpaceModel,
    x_s: np.ndarray,
    x_t: np.ndarray,
    episode: np.ndarray,
    t_target: np.ndarray,
    rows: int,
    seed: int,
) -> dict[str, Any]:
    """D of Eq. 10 on :func:`matched_and_shuffled`'s rows (the same ``seed``), each target
    step x_t against the source step of a row of another episode (``episode`` (M,)) at
    the same target step (``t_target`` (M,)), drawn with the seed; rows without such a
    partner are left out. ``{"other_episode_same_step": stats, "own_lower_share": share
    of the rows whose matched D is lower, "other_episode_rows": rows compared}``."""
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(x_s), size=min(rows, len(x_s)), replace=False)
    rng.permutation(pick)  # matched_and_shuffled's draw, so the next ones differ from it
    by_step: dict[int, np.ndarray] = {}
    for t in np.unique(t_target[pick]):
        by_step[int(t)] = np.flatnonzero(t_target == t)
    own, other = [], []
    for i in pick:
        partners = by_step[int(t_target[i])]
        partners = partners[episode[partners] != episode[i]]
        if len(partners):
            own.append(i)
            other.append(int(rng.choice(partners)))
    if not own:
        raise ValueError("no row has a partner of another episode at the same step")
    target = torch.as_tensor(x_t[own], dtype=torch.float32)
    d_own = model.shaping(torch.as_tensor(x_s[own], dtype=torch.float32), target)
    d_other = model.shaping(torch.as_tensor(x_s[other], dtype=torch.float32), target)
    d_own_np, d_other_np = d_own.double().numpy(), d_other.double().numpy()
    return {
        "other_episode_same_step": distance_stats(d_other_np),
        "own_lower_share": float(np.mean(d_own_np < d_other_np)),
        "other_episode_rows": len(own),
    }


def end_distance_against_score(
    runs_root: Path, runs: list[dict[str, Any]], metric: str, beta: float
) -> dict[str, Any]:
    """Each evaluation run's D at its last rollout (``-shaping / beta``) beside its final
    ``metric``, and Spearman's rho between the two over the runs that logged rollouts,
    with its by-seed interval (:func:`spearman_by_seed`; None when fewer than three runs
    logged rollouts, or when either column is constant)."""
    points, seeds = [], []
    for run in runs:
        metrics = runs_root / run["key"] / "metrics.jsonl"
        score = run.get(metric)
        if score is None or not metrics.exists():
            continue
        shaping = read_eval_points(metrics, SHAPING_KEY)[1]
        if len(shaping):
            points.append({"run": run["key"], "d_end": -shaping[-1] / beta, metric: score})
            seeds.append(run["seed"])
    d_end = np.array([p["d_end"] for p in points])
    scores = np.array([float(p[metric]) for p in points])
    rho, ci = spearman_by_seed(d_end, scores, seeds)
    return {"runs": points, "spearman_rho": rho, "spearman_rho_ci": ci}


def distance_by_beta(
    transfer_root: Path,
    method: str,
    candidates: list[dict[str, Any]],
    tuning_seeds: list[int],
) -> dict[str, Any]:
    """D at the first and last rollout of the β search's tuning runs of ``method``.

    Args:
        transfer_root: ``<protocol>/runs/<pair>/transfer``.
        candidates: the method's ``selection.json`` candidates (``beta``, ``init``,
            ``scores``); those of initialisation 0 are the β search.
        tuning_seeds: the protocol's tuning seeds.

    Returns:
        ``betas``: per β tried (ascending) the runs that logged rollouts, the medians over
        them of D at the first and the last rollout (``-shaping / β``), the median of each
        run's first / last, and the candidate's mean score; ``rho_beta_d_last``: Spearman's
        ρ between β and the median last D over the βs (None with fewer than three, or a
        constant column): negative where a larger weight brings the target nearer.
    """
    rows = []
    for candidate in sorted(candidates, key=lambda c: c["beta"]):
        if candidate["init"] != 0:
            continue
        beta = float(candidate["beta"])
        name = transfer_run_name(method, beta, 0, 0)
        first, last = [], []
        for seed in tuning_seeds:
            metrics = transfer_root / name / f"seed{seed}" / "metrics.jsonl"
            if not metrics.exists():
                continue
            shaping = read_eval_points(metrics, SHAPING_KEY)[1]
            if len(shaping):
                first.append(-shaping[0] / beta)
                last.append(-shaping[-1] / beta)
        if not first:
            continue
        rows.append(
            {
                "beta": beta,
                "runs": len(first),
                "d_first": float(np.median(first)),
                "d_last": float(np.median(last)),
                "fall": float(np.median(np.array(first) / np.array(last))),
                "score": float(np.mean(candidate["scores"])),
            }
        )
    rho = _spearman(np.array([r["beta"] for r in rows]), np.array([r["d_last"] for r in rows]))
    return {"betas": rows, "rho_beta_d_last": rho}


def _spearman(x: np.ndarray, y: np.ndarray) -> float | None:
    """Spearman's rho of (n,) and (n,), or None when it is undefined (n < 3, or a constant
    column: e.g. every run scored 0)."""
    if x.size < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return None
    return float(spearmanr(x, y).statistic)


def spearman_by_seed(
    x: np.ndarray, y: np.ndarray, seeds: list[int], reps: int = 2000, seed: int = 0
) -> tuple[float | None, list[float] | None]:
    """Spearman's rho of (n,) and (n,) with its 95% percentile bootstrap interval, the runs
    of one PPO seed drawn together (as :func:`pved.analysis.curves.bootstrap_difference`
    draws a group's seeds; the source policies are not drawn here). A resample whose rho
    is undefined (its runs all scored alike) counts as 0, no association: skipping it
    would keep only the resamples that drew the few scoring seeds, and narrow the
    interval beyond the evidence. Both are None when the point estimate is undefined."""
    rho = _spearman(x, y)
    if rho is None:
        return None, None
    labels = sorted(set(seeds))
    members = {label: np.flatnonzero(np.asarray(seeds) == label) for label in labels}
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(reps):
        picked = rng.choice(len(labels), size=len(labels), replace=True)
        rows = np.concatenate([members[labels[i]] for i in picked])
        value = _spearman(x[rows], y[rows])
        draws.append(0.0 if value is None else value)
    return rho, [float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5))]


def protocol_shaping_scale(
    protocol: Path, rows: int = 20_000, seed: int = 0
) -> tuple[dict[str, Any], str]:
    """The three tables of the module docstring for every shaped method of the finished
    protocol directory ``protocol``, on ``rows`` training pairs drawn with ``seed``.

    Writes ``protocol/subspaces/shaping_scale.json`` and returns its content with the
    tables as Markdown; a directory that is no finished protocol, or lacks the paired
    dataset or a selected model, raises :class:`PvedError`."""
    summary = load_summary(protocol)
    runs_root = protocol / "runs"
    result: dict[str, Any] = {"rows": rows, "seed": seed, "pairs": {}}
    lines = [
        "| pair | method | init | D matched: median / mean | D shuffled: median / mean "
        "| D, target action swapped: median | D, target state swapped: median "
        "| D, another episode's source step at the same step: median (own lower in) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for pair, entry in summary["pairs"].items():
        layout = resolve_pair(pair, runs_root)
        dataset = layout.runs.dataset(layout.preset.pairing.align)
        if not dataset.is_file():
            raise PvedError(f"{dataset}: the pair's paired dataset is not in this directory")
        for method, state in entry["methods"].items():
            init = state.get("init")
            if init is None:  # plain PPO and the oracle have no model
                continue
            model = layout.runs.model(method, init)
            if not model.is_file():
                raise PvedError(f"{model}: the selected model is not in this directory")
            scale = shaping_scale(model, dataset, rows, seed)
            result["pairs"].setdefault(pair, {})[method] = {"init": init, **scale}
            m, s = scale["matched"], scale["shuffled"]
            lines.append(
                f"| {pair} | {method} | {init} | {m['q50']:.3g} / {m['mean']:.3g} | "
                f"{s['q50']:.3g} / {s['mean']:.3g} | {scale['action_swapped']['q50']:.3g} | "
                f"{scale['state_swapped']['q50']:.3g} | "
                f"{scale['other_episode_same_step']['q50']:.3g} "
                f"({scale['own_lower_share']:.3f}) |"
            )
    lines += [
        "",
        "| pair | method | runs | D at the last rollout: min / median / max "
        "| best run's D | ρ(D, score) |",
        "|---|---|---|---|---|---|",
    ]
    for pair, entry in summary["pairs"].items():
        metric = entry["metric"]
        for method, state in entry["methods"].items():
            if state.get("beta") is None:  # no shaping term
                continue
            ends = end_distance_against_score(runs_root, state["runs"], metric, state["beta"])
            result["pairs"][pair][method]["end_of_runs"] = ends
            if not ends["runs"]:
                continue
            d_end = np.array([p["d_end"] for p in ends["runs"]])
            best = max(ends["runs"], key=lambda p: float(p[metric]))
            rho = "–" if ends["spearman_rho"] is None else f"{ends['spearman_rho']:.2f}"
            if ends["spearman_rho_ci"] is not None:
                lo, hi = ends["spearman_rho_ci"]
                rho += f" [{lo:.2f}, {hi:.2f}]"
            lines.append(
                f"| {pair} | {method} | {len(d_end)} | {d_end.min():.3g} / "
                f"{np.median(d_end):.3g} / {d_end.max():.3g} | {best['d_end']:.3g} "
                f"({metric} {best[metric]:.3g}) | {rho} |"
            )
    lines += [
        "",
        "| pair | method | β | runs | D first → last rollout (medians) | fall | score |",
        "|---|---|---|---|---|---|---|",
    ]
    selection = json.loads((protocol / "selection.json").read_text())
    tuning_seeds = json.loads((protocol / "protocol.json").read_text())["budget"]["tuning_seeds"]
    for pair, methods in result["pairs"].items():
        for method, scale in methods.items():
            search = distance_by_beta(
                runs_root / pair / "transfer",
                method,
                selection[pair][method]["candidates"],
                tuning_seeds,
            )
            scale["by_beta"] = search
            for row in search["betas"]:
                lines.append(
                    f"| {pair} | {method} | {row['beta']:g} | {row['runs']} | "
                    f"{row['d_first']:.3g} → {row['d_last']:.3g} | {row['fall']:.3g}x | "
                    f"{row['score']:.3g} |"
                )
            if search["rho_beta_d_last"] is not None:
                lines.append(
                    f"| {pair} | {method} | ρ(β, D last) | | {search['rho_beta_d_last']:.2f} | | |"
                )
    out = protocol / "subspaces" / "shaping_scale.json"
    out.parent.mkdir(exist_ok=True)
    atomic_write_json(out, result)
    return result, "\n".join(lines)
