"""Where on the table a Peg policy succeeds: its success rate hole position by hole position.

A Fetch4 (or Jaco) policy on the Peg task is run with its mean action on a square grid of
hole positions over the task's hole distribution (``HOLE_CENTER_XY`` +- ``HOLE_RANGE``),
each position in ``--copies`` episodes that differ only in the arm's initial joint noise.
For every position it reports the success rate at the episode's last step, and for the
whole grid how far the peg's tip ends from the hole's axis, how widely its end points
spread, and how much the tip's end point moves with the hole (the slope of a least-squares fit of
the end xy on the hole xy: 1 for a policy that follows the hole, 0 for one that goes to
the same place whatever the hole).

A failed episode whose tip ends resting on the table top (within ``ON_TABLE_TOL`` of its
height) has pushed the peg down beside the hole, where friction holds it.

A policy that ignores the hole and pushes its peg down at one place succeeds where the
hole happens to lie under it; its success rate over the uniform hole distribution is
then the share of the box within reach of that place, whatever PPO's budget. This
separates that failure from an arm that follows the hole but cannot insert the peg.

Given a shaping model and a source bank (``--shaping-model``, ``--bank``), it also
measures Eq. 10's distance D along the policy's own trajectories: at each step, between
the policy's state-action and the source's at the same step of the bank episode matched
to the hole, as a transfer run computes it (``LatentShaping`` with beta = 1), averaged
over the steps, and over the successful and the failed episodes apart, and by where the
peg's tip was when the step's action was taken (below the table top, in the hole; at
it; above it): the median D of each height band and its share of the steps. Run for a
policy that inserts the peg and for one that does not, it says which of the two the
term charges more, and whether it charges a tip in the hole more than one on the table.
It also measures D along the same steps against the source's episode at the hole
reflected through the box's centre: a term that knows where the hole is charges a
policy that follows the hole less at its own hole than at one 6 cm or more away.

    pved analyze peg-success RUN_DIR_OR_POLICY [--agent fetch4] [--grid 11] [--copies 8]
        [--seed 0] [--json OUT.json] [--shaping-model MODEL_RUN_DIR --bank BANK_RUN_DIR]

Prints the map (rows: hole y from high to low; columns: hole x from low to high) and the
summary; ``--json`` also writes them, atomically. Given a jaco-fetch ``pved protocol``
directory instead, it maps every evaluation run that kept its policy (about 10 s a run)
and prints one row per method, D measured under PVED's selected model and the source-0
bank for every method's runs alike (where ``selection.json`` has chosen it); the runs
and the table go to ``PROTOCOL_DIR/subspaces/peg_success.json`` (or ``--json``).
:func:`peg_success` does either.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pved.envs.arms import HOLE_CENTER_XY, HOLE_RANGE, TABLE_TOP_Z
from pved.envs.registry import make_batched
from pved.errors import PvedError
from pved.models.registry import load_model
from pved.record_paths import record_path
from pved.rl.policy import load_policy
from pved.run_layout import transfer_run_method
from pved.runs import atomic_write_json, run_file, run_path
from pved.transfer.shaping import LatentShaping
from pved.transfer.source_bank import load_bank

PEG_ENV_IDS = {"fetch4": "pved/Fetch4Peg-v0", "jaco": "pved/JacoPeg-v0"}
ON_TABLE_TOL = 0.005  # m: a tip this close to the table top's height rests on it
# where the tip is, by its height against the table top (m): in the hole, resting on the
# table (within ON_TABLE_TOL), above it
HEIGHT_BANDS = ("in_hole", "at_table_top", "above_table_top")
# holes at least this far from the box's centre (m) are compared with their reflection
# through it, at least twice as far away
REFLECTED_MIN_OFFSET = 0.03


def height_band(z: np.ndarray) -> np.ndarray:
    """The index into ``HEIGHT_BANDS`` of each tip height ``z`` (m)."""
    return np.where(
        z < TABLE_TOP_Z - ON_TABLE_TOL, 0, np.where(z < TABLE_TOP_Z + ON_TABLE_TOL, 1, 2)
    )


def load_shaping(model_path: Path, bank_path: Path) -> LatentShaping:
    """Eq. 10's distance as a transfer run computes it, with beta = 1 (so its term is −D),
    for the Fetch4 target of the jaco-fetch pair."""
    model = load_model(run_file(model_path, "model.pt", "shaping model"))
    bank = load_bank(run_file(bank_path, "bank.npz", "source bank"))
    env = make_batched(PEG_ENV_IDS["fetch4"], 1)
    return LatentShaping(model, bank, 1.0, env.robot_state_indices)


def success_map(
    policy_path: Path,
    agent: str,
    grid: int,
    copies: int,
    seed: int,
    shaping: LatentShaping | None = None,
) -> dict[str, Any]:
    """Run the policy at ``grid`` x ``grid`` hole positions, ``copies`` episodes each, and
    return the per-position success rates and the tip's end-point statistics (and, with
    ``shaping``, Eq. 10's distance D along the trajectories)."""
    if shaping is not None and agent != "fetch4":
        raise PvedError("Eq. 10's distance is the target's: --shaping-model needs --agent fetch4")
    if agent not in PEG_ENV_IDS:
        raise PvedError(f"unknown agent {agent!r}; known: {', '.join(PEG_ENV_IDS)}")
    if grid < 2 or copies < 1:
        raise PvedError("the grid needs at least 2 points a side and 1 copy a point")
    policy = load_policy(policy_path)
    offsets = np.linspace(-HOLE_RANGE, HOLE_RANGE, grid)
    xs = HOLE_CENTER_XY[0] + offsets
    ys = HOLE_CENTER_XY[1] + offsets
    holes = np.array([(x, y) for y in ys for x in xs for _ in range(copies)])
    env = make_batched(PEG_ENV_IDS[agent], len(holes))
    obs_dim = env.single_observation_space.shape[0]
    if obs_dim != policy.obs_dim:
        raise PvedError(
            f"{policy_path} takes {policy.obs_dim} observations, {agent}'s Peg env gives {obs_dim}"
        )
    obs, info = env.reset(seed=seed, options={"hole": holes})
    # the source's episode each copy is compared with: the bank's nearest to its hole, and
    # the one nearest to the hole reflected through the box's centre
    episode = shaping.bank.match(holes, None) if shaping is not None else None
    reflected = (
        shaping.bank.match(2 * np.asarray(HOLE_CENTER_XY) - holes, None)
        if shaping is not None
        else None
    )
    distance = np.zeros(len(holes))
    distance_reflected = np.zeros(len(holes))
    success = np.zeros(len(holes), dtype=bool)
    tip = np.asarray(info["peg_tip"], dtype=np.float64)
    step_d: list[np.ndarray] = []  # D of each step, and the band of the tip it acted from
    step_band: list[np.ndarray] = []
    for t in range(int(env.max_episode_steps)):
        action = policy.act(obs, deterministic=True)
        if shaping is not None and episode is not None and reflected is not None:
            steps = np.full(len(holes), t)
            d = -shaping.reward(obs, action, episode, steps)  # beta = 1: the term is −D
            distance += d
            distance_reflected -= shaping.reward(obs, action, reflected, steps)
            step_d.append(d)
            step_band.append(height_band(tip[:, 2]))
        obs, _, _, _, info = env.step(action)
        # the step that ends an episode reports its last state; the env resets after it
        success = np.asarray(info["is_success"], dtype=bool)
        tip = np.asarray(info["peg_tip"], dtype=np.float64)
    rate = success.reshape(grid, grid, copies).mean(axis=2)  # [y index, x index]
    # a failed peg that rests on the table top beside its hole has stopped looking for it
    on_table = np.abs(tip[:, 2] - TABLE_TOP_Z) < ON_TABLE_TOL
    end_xy = tip[:, :2]
    # end xy = a + B hole xy: B's diagonal says how far the tip follows the hole
    design = np.column_stack([np.ones(len(holes)), holes])
    coef, *_ = np.linalg.lstsq(design, end_xy, rcond=None)
    shaping_stats: dict[str, Any] = {}
    if shaping is not None:
        per_step = distance / int(env.max_episode_steps)
        shaping_stats = {
            "shaping_D_mean": float(per_step.mean()),
            "shaping_D_mean_success": float(per_step[success].mean()) if success.any() else None,
            "shaping_D_mean_failure": float(per_step[~success].mean())
            if (~success).any()
            else None,
        }
        d_all, band_all = np.concatenate(step_d), np.concatenate(step_band)
        shaping_stats["shaping_D_by_tip_height"] = {
            name: {
                "share_of_steps": float(np.mean(band_all == i)),
                "D_median": float(np.median(d_all[band_all == i]))
                if (band_all == i).any()
                else None,
            }
            for i, name in enumerate(HEIGHT_BANDS)
        }
        far = np.linalg.norm(holes - np.asarray(HOLE_CENTER_XY), axis=1) >= REFLECTED_MIN_OFFSET
        if far.any():
            steps_per_episode = int(env.max_episode_steps)
            shaping_stats["shaping_D_own_vs_reflected_hole"] = {
                "episodes": int(far.sum()),
                "own_D_median": float(np.median(distance[far])) / steps_per_episode,
                "reflected_D_median": float(np.median(distance_reflected[far])) / steps_per_episode,
                "own_lower_share": float(np.mean(distance[far] < distance_reflected[far])),
            }
    return {
        "policy": record_path(policy_path),
        "agent": agent,
        "grid": grid,
        "copies": copies,
        "seed": seed,
        "hole_x": xs.tolist(),
        "hole_y": ys.tolist(),
        "success_rate": float(success.mean()),
        "success_by_hole": rate.tolist(),
        "tip_to_hole_axis_m_median": float(np.median(np.linalg.norm(end_xy - holes, axis=1))),
        "tip_end_spread_m": float(np.sqrt(np.mean(np.sum((end_xy - end_xy.mean(0)) ** 2, 1)))),
        "tip_end_mean_xy": end_xy.mean(axis=0).tolist(),
        "failures": int((~success).sum()),
        "failures_resting_on_table": int((on_table & ~success).sum()),
        "follow_slope_x": float(coef[1, 0]),
        "follow_slope_y": float(coef[2, 1]),
        **shaping_stats,
    }


def render(result: dict[str, Any]) -> str:
    """The map as text: one row per hole y (high to low), one column per hole x."""
    lines = [f"success by hole position, {result['policy']} ({result['copies']} episodes each)"]
    lines.append("y \\ x    " + " ".join(f"{x:5.3f}" for x in result["hole_x"]))
    for y, row in reversed(list(zip(result["hole_y"], result["success_by_hole"], strict=True))):
        lines.append(f"{y:+6.3f}   " + " ".join(f"{r:5.2f}" for r in row))
    lines.append(
        f"success rate {result['success_rate']:.3f}; the tip ends "
        f"{result['tip_to_hole_axis_m_median']:.4f} m from the hole's axis (median); its end "
        f"points spread {result['tip_end_spread_m']:.4f} m about "
        f"{np.round(result['tip_end_mean_xy'], 4).tolist()} and follow the hole with slope "
        f"x {result['follow_slope_x']:.2f}, y {result['follow_slope_y']:.2f}; "
        f"{result['failures_resting_on_table']} of {result['failures']} failed episodes end "
        f"with the tip resting on the table top"
    )
    if "shaping_D_mean" in result:
        lines.append(
            f"Eq. 10's D per step along these trajectories: {result['shaping_D_mean']:.4g} "
            f"(successful episodes {_number(result['shaping_D_mean_success'])}, failed "
            f"{_number(result['shaping_D_mean_failure'])})"
        )
        bands = result["shaping_D_by_tip_height"]
        lines.append(
            "by where the tip acted from, median D per step (share of the steps): "
            + "; ".join(
                f"{name.replace('_', ' ')} {_number(b['D_median'])} ({b['share_of_steps']:.3f})"
                for name, b in bands.items()
            )
        )
        own = result.get("shaping_D_own_vs_reflected_hole")
        if own is not None:
            lines.append(
                f"against the source at the hole reflected through the box's centre "
                f"({own['episodes']} episodes at holes >= {REFLECTED_MIN_OFFSET} m from it): "
                f"median D per step {own['own_D_median']:.4g} at its own hole, "
                f"{own['reflected_D_median']:.4g} at the reflected one; lower at its own in "
                f"{own['own_lower_share']:.3f} of the episodes (0.5: the term does not say "
                f"where the hole is)"
            )
    return "\n".join(lines)


def _number(value: float | None) -> str:
    return "–" if value is None else f"{value:.4g}"


def _median(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.median(present)) if present else None


def protocol_shaping(protocol: Path) -> tuple[LatentShaping, str] | None:
    """PVED's selected model (its chosen initialisation, from ``selection.json``) with the
    source-0 bank, or None where the selection has not chosen it yet."""
    try:
        selection = json.loads((protocol / "selection.json").read_text())
    except (OSError, ValueError):
        return None
    init = selection.get("jaco-fetch", {}).get("pved", {}).get("init")
    if init is None:
        return None
    runs = protocol / "runs"
    model = run_path(runs, "jaco-fetch", "model", "pved", int(init))
    bank = run_path(runs, "jaco-fetch", "bank", "Jaco-Peg", 0)
    return load_shaping(model, bank), f"pved init {init}, source-0 bank"


def protocol_summary(protocol: Path, grid: int, copies: int, seed: int) -> dict[str, Any]:
    """The map of every evaluation run of a jaco-fetch protocol that kept its policy,
    summarised by method: how many runs, their mean success over the grid, the share of
    grid holes a run solves in at least half its episodes, the share of failed episodes
    that end resting on the table, and the median slopes with which the tip follows the
    hole; where PVED's model is chosen, the median over runs of Eq. 10's D per step
    under it (all, successful and failed episodes; and of each run's median D with its
    tip in the hole and on the table top, and of the share of its episodes whose D is
    lower at their own hole than at the reflected one). Runs restored from a summary
    kept no policy and are counted apart."""
    try:
        record = json.loads((protocol / "protocol.json").read_text())
    except (OSError, ValueError) as exc:
        raise PvedError(f"{protocol} is not a protocol directory (protocol.json: {exc})") from exc
    if "jaco-fetch" not in record.get("pairs", []):
        raise PvedError(f"{protocol} has no jaco-fetch runs (pairs: {record.get('pairs')})")
    seeds = {int(s) for s in record["budget"]["evaluation_seeds"]}
    chosen = protocol_shaping(protocol)
    shaping, measured_under = chosen if chosen is not None else (None, None)
    runs: dict[str, list[dict[str, Any]]] = {}
    without_policy: dict[str, int] = {}
    for run in sorted((protocol / "runs" / "jaco-fetch" / "transfer").glob("*/seed*")):
        if int(run.name.removeprefix("seed")) not in seeds or not (run / "result.json").is_file():
            continue
        method = transfer_run_method(run.parent.name)
        if not (run / "policy.pt").is_file():
            without_policy[method] = without_policy.get(method, 0) + 1
            continue
        result = success_map(run / "policy.pt", "fetch4", grid, copies, seed, shaping)
        result["run"] = f"{run.parent.name}/{run.name}"
        runs.setdefault(method, []).append(result)
    methods: dict[str, dict[str, Any]] = {}
    for method, results in runs.items():
        failures = sum(r["failures"] for r in results)
        methods[method] = {
            "runs": len(results),
            "runs_without_policy": without_policy.get(method, 0),
            "success_rate_mean": float(np.mean([r["success_rate"] for r in results])),
            "holes_solved_mean": float(
                np.mean([np.mean(np.asarray(r["success_by_hole"]) >= 0.5) for r in results])
            ),
            "failures_resting_on_table": (
                sum(r["failures_resting_on_table"] for r in results) / failures
                if failures
                else None
            ),
            "follow_slope_x_median": float(np.median([r["follow_slope_x"] for r in results])),
            "follow_slope_y_median": float(np.median([r["follow_slope_y"] for r in results])),
            **{
                f"{key}_median": _median([r.get(key) for r in results])
                for key in ("shaping_D_mean", "shaping_D_mean_success", "shaping_D_mean_failure")
            },
            # the median over runs of each run's median D with its tip in that band
            **{
                f"shaping_D_{band}_median": _median(
                    [r["shaping_D_by_tip_height"][band]["D_median"] for r in results]
                    if shaping is not None
                    else []
                )
                for band in ("in_hole", "at_table_top")
            },
            # how often a run's D is lower at its own hole than at the reflected one
            "shaping_own_hole_lower_share_median": _median(
                [
                    r["shaping_D_own_vs_reflected_hole"]["own_lower_share"]
                    for r in results
                    if "shaping_D_own_vs_reflected_hole" in r
                ]
            ),
        }
    for method, count in without_policy.items():
        methods.setdefault(method, {"runs": 0, "runs_without_policy": count})
    return {"protocol": record_path(protocol), "grid": grid, "copies": copies, "seed": seed,
            "shaping_measured_under": measured_under, "methods": methods,
            "runs": {m: rs for m, rs in runs.items()}}  # fmt: skip


def render_summary(summary: dict[str, Any]) -> str:
    """The protocol summary as a Markdown table, one row per method."""
    lines = [
        "| method | runs (without policy) | success over the grid | holes solved | failures "
        "resting on the table | tip follows the hole, slope x / y | Eq. 10's D per step "
        "under PVED's model: all / successful / failed episodes | its median with the tip "
        "in the hole / on the table top | share of episodes whose D is lower at their own "
        "hole than at the reflected one |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for method, m in sorted(summary["methods"].items()):
        if not m["runs"]:
            lines.append(f"| {method} | 0 ({m['runs_without_policy']}) | | | | | | | |")
            continue
        resting = m["failures_resting_on_table"]
        lines.append(
            f"| {method} | {m['runs']} ({m['runs_without_policy']}) | "
            f"{m['success_rate_mean']:.3f} | {m['holes_solved_mean']:.3f} | "
            f"{'–' if resting is None else f'{resting:.3f}'} | "
            f"{m['follow_slope_x_median']:.2f} / {m['follow_slope_y_median']:.2f} | "
            f"{_number(m['shaping_D_mean_median'])} / "
            f"{_number(m['shaping_D_mean_success_median'])} / "
            f"{_number(m['shaping_D_mean_failure_median'])} | "
            f"{_number(m['shaping_D_in_hole_median'])} / "
            f"{_number(m['shaping_D_at_table_top_median'])} | "
            f"{_number(m['shaping_own_hole_lower_share_median'])} |"
        )
    return "\n".join(lines)


def peg_success(
    path: Path,
    agent: str = "fetch4",
    grid: int = 11,
    copies: int = 8,
    seed: int = 0,
    json_out: Path | None = None,
    shaping_model: Path | None = None,
    bank: Path | None = None,
) -> tuple[dict[str, Any], str]:
    """The success map of a policy (``path``: ``policy.pt`` or its run directory), or of
    every evaluation run of a jaco-fetch protocol directory (``path`` holding
    ``protocol.json``), and its text (:func:`render`, :func:`render_summary`).

    A protocol's summary is written to ``json_out`` (default
    ``path/subspaces/peg_success.json``); a policy's map only where ``json_out`` is given.
    ``shaping_model`` and ``bank`` (together, a policy only) add Eq. 10's distance."""
    if (path / "protocol.json").is_file():
        summary = protocol_summary(path, grid, copies, seed)
        atomic_write_json(json_out or path / "subspaces" / "peg_success.json", summary)
        return summary, render_summary(summary)
    policy = run_file(path, "policy.pt", "policy")
    if (shaping_model is None) != (bank is None):
        raise PvedError("--shaping-model and --bank go together")
    shaping = None
    if shaping_model is not None and bank is not None:
        shaping = load_shaping(shaping_model, bank)
    result = success_map(policy, agent, grid, copies, seed, shaping)
    if json_out is not None:
        atomic_write_json(json_out, result)
    return result, render(result)
