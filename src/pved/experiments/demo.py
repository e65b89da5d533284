"""``make demo``: the Reacher pair end to end on defaults, within minutes on 2 cores.

Shipped pretrained policies (Reach for both arms, Push for the 3-link source) → paired
rollouts → PVED → source bank → transfer with PVED (the paper's Eq. 10, and ``pved-align``,
a method beyond the paper) against plain PPO on the same budget and seeds, run side by
side (one process per core) → a report folder that ends by saying, plainly, for each
method whether the transfer shows on these seeds (:func:`transfer_verdict`).
"""

from __future__ import annotations

import multiprocessing as mp
import time
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from pved.analysis.compare import compare_runs, format_comparison
from pved.analysis.report import transfer_report
from pved.checks import check_int, check_number, check_seed, check_writable
from pved.config import EVALUATION_SEEDS
from pved.errors import OptionError
from pved.experiments.stages import build_bank, collect_pairs, train_model, transfer
from pved.pair import resolve_pair
from pved.runs import atomic_write_bytes, atomic_write_json, last_logged_step, run_path
from pved.transfer.methods import NO_TRANSFER, get_method


@dataclass(frozen=True)
class DemoConfig:
    """The demo's budget (kept small enough for ~15 minutes on 2 cores)."""

    pair: str = "reacher"
    methods: tuple[str, ...] = ("pved-align", "pved", "ppo")
    # β per method where it is not the pair's default: pved-align's is the one reacher's
    # quick protocol chose on its tuning seeds (docs/protocol/reacher-quick-align)
    betas: tuple[tuple[str, float], ...] = (("pved-align", 1.0),)
    seeds: tuple[int, ...] = EVALUATION_SEEDS  # the paper's five evaluation seeds (IV.A)
    pair_episodes: int = 400
    model_epochs: int = 40
    bank_episodes: int = 100
    transfer_steps: int = 300_000
    eval_every: int = 30_000
    eval_episodes: int = 48
    final_eval_episodes: int = 500
    jobs: int = 2

    def __post_init__(self) -> None:
        # checked before any stage: a budget refused at transfer came after the pairs,
        # the model and the bank had been made
        resolve_pair(self.pair)  # an unknown pair fails here
        counts = (
            "pair_episodes",
            "model_epochs",
            "bank_episodes",
            "transfer_steps",
            "eval_every",
            "eval_episodes",
            "final_eval_episodes",
            "jobs",
        )
        for name in counts:
            check_int(name, getattr(self, name), low=1)
        if not self.seeds:
            raise OptionError("seeds", list(self.seeds), "one or more seeds")
        for method in self.methods:
            get_method(method)  # an unknown method fails here
        for method, beta in self.betas:
            check_number(f"beta of {method}", beta, low=0.0)
        for seed in self.seeds:
            check_seed("seeds", seed)


def _transfer_job(
    pair: str,
    method: str,
    seed: int,
    steps: int,
    eval_every: int,
    eval_episodes: int,
    final_eval_episodes: int,
    runs_root: str,
    beta: float | None,
) -> dict:
    import torch

    torch.set_num_threads(1)
    return transfer(
        pair,
        method,
        seed=seed,
        steps=steps,
        eval_every=eval_every,
        eval_episodes=eval_episodes,
        final_eval_episodes=final_eval_episodes,
        runs_root=Path(runs_root),
        progress=False,
        beta=beta,
    )


def run_transfers(cfg: DemoConfig, runs_root: Path) -> None:
    """All (method, seed) transfer runs, ``cfg.jobs`` at a time, one progress bar over
    their environment steps (read from each run's metrics.jsonl)."""
    jobs = [(m, s) for m in cfg.methods for s in cfg.seeds]
    total = cfg.transfer_steps * len(jobs)
    betas = dict(cfg.betas)
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=cfg.jobs, mp_context=ctx) as pool:
        futures: list[Future[dict]] = [
            pool.submit(
                _transfer_job,
                cfg.pair,
                m,
                s,
                cfg.transfer_steps,
                cfg.eval_every,
                cfg.eval_episodes,
                cfg.final_eval_episodes,
                str(runs_root),
                betas.get(m),
            )
            for m, s in jobs
        ]
        run_dirs = [run_path(runs_root, cfg.pair, "transfer", m, s) for m, s in jobs]
        with tqdm(
            total=total, desc=f"transfer {len(jobs)} runs", unit="step", unit_scale=True
        ) as bar:
            while not all(f.done() for f in futures):
                done_steps = sum(
                    cfg.transfer_steps if f.done() else last_logged_step(run_dir)
                    for f, run_dir in zip(futures, run_dirs, strict=True)
                )
                bar.update(done_steps - bar.n)
                time.sleep(1.0)
            bar.update(total - bar.n)
        for f in futures:
            f.result()  # re-raise a worker's error


def transfer_verdict(comparison: dict[str, Any]) -> str:
    """One plain sentence from :func:`pved.analysis.compare.compare_runs`' result (shaped
    method first, PPO second): whether the transfer shows on these seeds, by the 95%
    intervals of the differences in final and early score (the early score: the mean of
    the evaluation points in the first quarter of training, how fast it learns)."""
    a, b = list(comparison["groups"])
    final, early = comparison["diff"]["final"], comparison["diff"]["early"]

    def said(d: dict[str, Any]) -> str:
        lo, hi = d["diff_ci"]
        return f"{d['diff']:+.3f} [{lo:+.3f}, {hi:+.3f}]"

    gaps = f"final {said(final)}, early {said(early)}"
    if final["diff_ci"][0] > 0 or early["diff_ci"][0] > 0:
        return f"Transfer shows at this budget: {a} is ahead of {b} on the same seeds ({gaps})."
    if final["diff_ci"][1] < 0 or early["diff_ci"][1] < 0:
        return f"Transfer does not pay here: {a} is behind {b} on the same seeds ({gaps})."
    return (
        f"Transfer does not show at this budget: {a} - {b} on the same seeds is {gaps}, "
        "intervals that hold 0. Where it shows, at the paper's budget: docs/results.md."
    )


def run_demo(
    runs_root: Path = Path("runs/demo"),
    report_dir: Path = Path("reports/reacher-demo"),
    cfg: DemoConfig | None = None,
) -> Path:
    """Run the whole Reacher pipeline on the demo budget; return the report folder."""
    cfg = cfg or DemoConfig()
    pair = resolve_pair(cfg.pair, runs_root)
    preset = pair.preset
    check_writable("--runs", runs_root)
    check_writable("--out", report_dir)
    start = time.time()
    dataset = collect_pairs(pair, episodes=cfg.pair_episodes)
    for model in dict.fromkeys(get_method(m).model for m in cfg.methods):
        if model is not None:  # each model the methods shape with, once
            train_model(pair, model, dataset=dataset, epochs=cfg.model_epochs)
    build_bank(pair, episodes=cfg.bank_episodes)
    run_transfers(cfg, runs_root)
    out = transfer_report(
        cfg.pair,
        list(cfg.methods),
        list(cfg.seeds),
        runs_root,
        report_dir,
        metric=preset.metric,
        title=f"{preset.source_agent} -> {preset.target_agent} on {preset.target_task} (demo)",
        extra={"demo_config": cfg, "wall_seconds": round(time.time() - start, 1)},
    )
    atomic_write_json(out / "demo_config.json", cfg)
    shaped = [m for m in cfg.methods if m != NO_TRANSFER]
    if NO_TRANSFER in cfg.methods and shaped:
        # each shaped method against plain PPO on the same seeds
        def dirs(method: str) -> list[Path]:
            return [run_path(runs_root, cfg.pair, "transfer", method, s) for s in cfg.seeds]

        comparisons = {
            m: compare_runs(dirs(m), dirs(NO_TRANSFER), (m, NO_TRANSFER)) for m in shaped
        }
        atomic_write_json(out / "comparisons.json", comparisons)
        text = (out / "results.md").read_text() + "\n## Does the transfer show?\n"
        for method, comparison in comparisons.items():
            text += (
                f"\n### {method} against {NO_TRANSFER}\n\n"
                + format_comparison(comparison)
                + "\n\n"
                + transfer_verdict(comparison)
                + "\n"
            )
        atomic_write_bytes(out / "results.md", text.encode())
    return out
